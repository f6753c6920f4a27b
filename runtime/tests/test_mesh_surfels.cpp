#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <limits>

#include "gamma/error.h"
#include "gamma/mesh.h"
#include "gamma/surfels.h"
#include "helpers.h"

using namespace gammart;


TEST(Mesh, FileNotFound) {
    std::string msg = gamma_test::expect_error([] { Mesh::load("/nonexistent/x.obj"); });
    EXPECT_EQ(msg, "cannot read mesh '/nonexistent/x.obj': file not found");
}

TEST(Mesh, Garbage) {
    const char* path = "gamma_test_garbage.ply";
    { std::ofstream f(path); f << "this is not a mesh\x01\x02\n"; }
    std::string msg = gamma_test::expect_error([&] { Mesh::load(path); });
    EXPECT_EQ(msg.find('\n'), std::string::npos);
    EXPECT_NE(msg.find("gamma_test_garbage.ply"), std::string::npos) << msg;
    std::remove(path);
}

TEST(Mesh, ObjLoadAndNoTriangles) {
    const char* path = "gamma_test_tri.obj";
    { std::ofstream f(path); f << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n"; }
    Mesh m = Mesh::load(path);
    EXPECT_EQ(m.num_vertices(), 4u);
    EXPECT_EQ(m.num_triangles(), 2u);  // quad triangulated
    EXPECT_NEAR(m.area(), 1.0, 1e-6);
    { std::ofstream f(path); f << "v 0 0 0\nv 1 0 0\n"; }
    std::string msg = gamma_test::expect_error([&] { Mesh::load(path); });
    EXPECT_EQ(msg, "mesh 'gamma_test_tri.obj' has no triangles");
    std::remove(path);
}

TEST(Mesh, FromArraysValidation) {
    std::vector<float> v = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::vector<int32_t> bad = {0, 1, 3};
    std::string msg = gamma_test::expect_error([&] { Mesh::from_arrays(v.data(), 3, bad.data(), 1); });
    EXPECT_NE(msg.find("out of range"), std::string::npos) << msg;
    std::vector<float> nanv = {0, 0, 0, 1, 0, 0, 0, std::numeric_limits<float>::quiet_NaN(), 0};
    std::vector<int32_t> ok = {0, 1, 2};
    msg = gamma_test::expect_error([&] { Mesh::from_arrays(nanv.data(), 3, ok.data(), 1, "x.obj"); });
    EXPECT_EQ(msg, "mesh 'x.obj': vertex 2 has a non-finite coordinate");
    std::vector<float> line = {0, 0, 0, 1, 0, 0, 2, 0, 0};
    msg = gamma_test::expect_error([&] { Mesh::from_arrays(line.data(), 3, ok.data(), 1, "x.obj"); });
    EXPECT_EQ(msg, "mesh 'x.obj' has only degenerate triangles");
}

TEST(Mesh, DegenerateDropped) {
    std::vector<float> v = {0, 0, 0, 1, 0, 0, 0, 1, 0, 2, 0, 0};
    std::vector<int32_t> t = {0, 1, 2, 0, 1, 3, 1, 1, 2};
    Mesh m = Mesh::from_arrays(v.data(), 4, t.data(), 3);
    EXPECT_EQ(m.num_triangles(), 1u);
    EXPECT_EQ(m.degenerate_dropped, 2u);
    EXPECT_EQ(m.original_triangle[0], 0);
}

TEST(Surfels, ExactCountAndUniformDensity) {
    Mesh m = gamma_test::unit_square();
    const size_t n = 20000;
    SurfelSet s = sample_surfels(m, n, 7);
    ASSERT_EQ(s.triangle.size(), n);
    ASSERT_EQ(s.position.size(), 3 * n);
    size_t per_tri[3] = {0, 0, 0}, left = 0;
    for (size_t i = 0; i < n; ++i) {
        per_tri[s.triangle[i]]++;
        if (s.position[3 * i] < 0.5f) ++left;
        EXPECT_NEAR(s.normal[3 * i + 2], 1.0f, 1e-6);
    }
    const double area[3] = {0.15, 0.35, 0.5};
    for (int t = 0; t < 3; ++t) EXPECT_NEAR(double(per_tri[t]) / n / area[t], 1.0, 0.05) << "triangle " << t;
    EXPECT_NEAR(double(left) / n, 0.5, 0.5 * 0.05);
}

TEST(Surfels, Deterministic) {
    Mesh m = gamma_test::icosphere(2);
    SurfelSet a = sample_surfels(m, 3000, 11), b = sample_surfels(m, 3000, 11), c = sample_surfels(m, 3000, 12);
    EXPECT_EQ(a.position, b.position);
    EXPECT_EQ(a.triangle, b.triangle);
    EXPECT_NE(a.position, c.position);
}

TEST(Surfels, BlueNoiseMinimumDistance) {
    Mesh m = gamma_test::unit_square();
    const size_t n = 4000;
    SurfelSet s = sample_surfels(m, n, 3);
    double min_d2 = 1e30;
    for (size_t i = 0; i < n; ++i)
        for (size_t j = i + 1; j < n; ++j) {
            double d2 = 0;
            for (int k = 0; k < 3; ++k) {
                double d = double(s.position[3 * i + k]) - s.position[3 * j + k];
                d2 += d * d;
            }
            min_d2 = std::min(min_d2, d2);
        }
    const double ratio = std::sqrt(min_d2) / s.r_max;
    std::printf("[ info ] min distance / r_max = %.3f\n", ratio);
    // r_max is half the hexagonal-packing spacing; sample elimination typically
    // reaches ~0.65 of that spacing (Yuksel 2015), i.e. ~1.3 r_max.
    EXPECT_GE(ratio, 1.0);
    // Uniform random sampling would give a minimum distance orders of
    // magnitude smaller (~0.01 r_max for this N).
}

TEST(Surfels, EliminationKeepsExactly) {
    std::vector<float> pts;
    for (int i = 0; i < 1000; ++i) { pts.push_back(float(i % 37) * 0.01f); pts.push_back(float(i / 37) * 0.01f); pts.push_back(0); }
    auto kept = eliminate_samples(pts, 200, 0.02);
    EXPECT_EQ(kept.size(), 200u);
}

TEST(Mesh, ObjNonFiniteCoordinate) {
    const char* path = "gamma_test_nan.obj";
    { std::ofstream f(path); f << "# c\nv 0 0 0\nv 1 0 0\nv 0 1e39 0\nf 1 2 3\n"; }
    std::string msg = gamma_test::expect_error([&] { Mesh::load(path); });
    EXPECT_EQ(msg, "mesh 'gamma_test_nan.obj': vertex 2 has a non-finite coordinate");
    std::remove(path);
}

TEST(Mesh, ObjParts) {
    const std::string text =
        "# parts\n"
        "mtllib x.mtl\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvn 0 0 1\n"
        "o chain\n"
        "usemtl Iron\n"
        "f 1/1/1 2/1/1 3/1/1 4/1/1\n"   // quad -> 2 triangles
        "o stairs\ng step1\n"
        "usemtl Cement\n"
        "f -4//1 -3//1 -2//1\n"          // negative indices
        "g\n"
        "s off\n"
        "f 1 3 4 # trailing comment\n";
    Mesh m = Mesh::parse_obj(text, "parts.obj");
    ASSERT_EQ(m.num_triangles(), 4u);
    const std::vector<std::string> names = {"chain", "Iron", "stairs", "step1", "Cement"};
    EXPECT_EQ(m.part_names, names);
    EXPECT_EQ(m.object_id, (std::vector<int32_t>{0, 0, 2, 2}));
    EXPECT_EQ(m.group_id, (std::vector<int32_t>{-1, -1, 3, -1}));
    EXPECT_EQ(m.material_id, (std::vector<int32_t>{1, 1, 4, 4}));
    EXPECT_EQ(m.triangles, (std::vector<int32_t>{0, 1, 2, 0, 2, 3, 0, 1, 2, 0, 2, 3}));
}

TEST(Mesh, ObjIndexOutOfRange) {
    std::string msg = gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 7\n", "p.obj"); });
    EXPECT_EQ(msg, "mesh 'p.obj': face on line 5 has vertex index 7 out of range (3 vertices)");
    msg = gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n", "p.obj"); });
    EXPECT_EQ(msg, "mesh 'p.obj': face on line 4 has vertex index -4 out of range (3 vertices)");
    msg = gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "p.obj"); });
    EXPECT_EQ(msg, "mesh 'p.obj': face on line 4 has vertex index 0 out of range (3 vertices)");
    msg = gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "p.obj"); });
    EXPECT_EQ(msg.find('\n'), std::string::npos);
    EXPECT_NE(msg.find("line 4"), std::string::npos) << msg;
}

// Only corners whose index was not yet in range when their face was read are
// recorded for the out-of-range message (mesh.cpp, parse_obj): faces before
// their vertices still load, and the message names the first bad corner in
// the file's order, with its line and its index as written, also inside a fan.
TEST(Mesh, ObjForwardReferencesAndTheFirstBadCornersLine) {
    Mesh m = Mesh::parse_obj("f 1 2 3 4\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -2 -1\n", "fwd.obj");
    EXPECT_EQ(m.triangles, (std::vector<int32_t>{0, 1, 2, 0, 2, 3, 0, 2, 3}));
    const std::string four = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";
    // the fifth corner of a pentagon's fan (its third triangle), after a good face
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(four + "f 1 2 3\nf 1 2 3 4 9\nf 1 2 12\n", "p.obj"); }),
              "mesh 'p.obj': face on line 6 has vertex index 9 out of range (4 vertices)");
    // the fan's first corner, shared by every triangle of the face; a forward
    // reference that comes into range later is not an error
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj("f 5 1 2 3\n" + four + "f 0 1 2\n", "p.obj"); }),
              "mesh 'p.obj': face on line 1 has vertex index 5 out of range (4 vertices)");
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj("f 5 1 2\n" + four + "v 0 0 1\nf 1 2 0\n", "p.obj"); }),
              "mesh 'p.obj': face on line 7 has vertex index 0 out of range (5 vertices)");
    // texture indices alike: forward ones resolved at the end, the first bad one named
    m = Mesh::parse_obj(four + "f 1/2 2/1 3/2\nvt 0 0\nvt 1 1\n", "uv.obj");
    EXPECT_EQ(m.uvs, (std::vector<float>{1, 1, 0, 0, 1, 1}));
    EXPECT_EQ(gamma_test::expect_error([&] {
                  Mesh::parse_obj(four + "vt 0 0\nf 1/1 2/1 3/1 4/3\nf 1/4 2/1 3/1\nvt 1 1\n", "uv.obj"); }),
              "mesh 'uv.obj': face on line 6 has texture index 3 out of range (2 texture coordinates)");
    // a face without texture indices after some with bad ones: no UVs, so no error
    m = Mesh::parse_obj(four + "vt 0 0\nf 1/7 2/1 3/1\nf 1 3 4\n", "uv.obj");
    EXPECT_FALSE(m.has_uvs());
    EXPECT_EQ(m.triangles, (std::vector<int32_t>{0, 1, 2, 0, 2, 3}));
}

// The reader takes plain decimal numbers without copying the line (mesh.cpp,
// read_double / read_whole_integer); what strtod and strtoll accept besides
// (a leading '+', hex, out of range, text after a number) reads as it did.
TEST(Mesh, ObjNumbersReadAsStrtodAndStrtollReadThem) {
    auto f = [](const char* text) { return float(std::strtod(text, nullptr)); };
    Mesh m = Mesh::parse_obj(
        "v +1 0x1p3 -.5e1\n"
        "v 1e-400 4.9e-324 .5\r\n"
        "v 0.1 0.30000000000000004 3.4028234e38x\n"   // text right after the last number: ignored, as ever
        "v\t7\t 8  9 # comment\n"
        "vt +0.25 0x1p-1\nvt 1\nvt 0 1\n"
        "f +1/+1 2/2 -1/-1\n",
        "numbers.obj");
    const std::vector<float> vertices = {1.0f, 8.0f, -5.0f, 0.0f, 0.0f, 0.5f, f("0.1"), f("0.30000000000000004"),
                                         f("3.4028234e38"), 7.0f, 8.0f, 9.0f};
    EXPECT_EQ(m.vertices, vertices);
    EXPECT_EQ(m.triangles, (std::vector<int32_t>{0, 1, 3}));
    ASSERT_TRUE(m.has_uvs());
    EXPECT_EQ(m.uvs, (std::vector<float>{0.25f, 0.5f, 1.0f, 0.0f, 0.0f, 1.0f}));
    const std::string three = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(three + "v 1,2,3\n", "p.obj"); }),
              "mesh 'p.obj': line 4: cannot read vertex coordinates");
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(three + "f 1 2 3a\n", "p.obj"); }),
              "mesh 'p.obj': face on line 4: cannot read '3a'");
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(three + "f 1 2/x 3\n", "p.obj"); }),
              "mesh 'p.obj': face on line 4: cannot read '2/x'");
    // strtoll's clamp of a huge index, reported as written then
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(three + "f 1 2 99999999999999999999\n", "p.obj"); }),
              "mesh 'p.obj': face on line 4 has vertex index 9223372036854775807 out of range (3 vertices)");
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::parse_obj(three + "v 0 1e39 0\n", "p.obj"); }),
              "mesh 'p.obj': vertex 3 has a non-finite coordinate");
}

TEST(Mesh, ExtentErrors) {
    std::vector<float> huge = {0, 0, 0, 3e38f, 0, 0, 0, 3e38f, 0};
    std::vector<int32_t> t = {0, 1, 2};
    std::string msg = gamma_test::expect_error([&] { Mesh::from_arrays(huge.data(), 3, t.data(), 1, "P"); });
    EXPECT_EQ(msg, "mesh 'P' has a non-finite or zero extent");
    std::vector<float> point = {1, 2, 3, 1, 2, 3, 1, 2, 3};
    msg = gamma_test::expect_error([&] { Mesh::from_arrays(point.data(), 3, t.data(), 1, "P"); });
    EXPECT_EQ(msg, "mesh 'P' has a non-finite or zero extent");
    // Large but representable: the diagonal (computed in double) is fine.
    std::vector<float> big = {0, 0, 0, 1e25f, 0, 0, 0, 1e25f, 0};
    Mesh m = Mesh::from_arrays(big.data(), 3, t.data(), 1, "P");
    EXPECT_NEAR(m.diag / 1e25, std::sqrt(2.0), 1e-6);
}

TEST(Mesh, PlyOutOfRangeAndNonFinite) {
    const char* path = "gamma_test_nm.ply";
    // A face with an out-of-range vertex index is an error (never dropped silently).
    {
        std::ofstream f(path);
        f << "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 3\nproperty list uchar int vertex_indices\nend_header\n"
             "0 0 0\n1 0 0\n0 1 0\n0 -1 0\n0 0 1\n3 0 1 2\n3 1 0 3\n3 0 1 9\n";
    }
    std::string msg = gamma_test::expect_error([&] { Mesh::load(path); });
    EXPECT_EQ(msg, "mesh 'gamma_test_nm.ply': face 2 has vertex index 9 out of range (5 vertices)");
    {
        std::ofstream f(path);
        f << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
             "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n";
    }
    msg = gamma_test::expect_error([&] { Mesh::load(path); });
    EXPECT_EQ(msg, "mesh 'gamma_test_nm.ply': vertex 1 has a non-finite coordinate");
    {
        std::ofstream f(path);
        f << "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
             "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
    }
    Mesh m = Mesh::load(path);
    EXPECT_EQ(m.num_triangles(), 2u);
    EXPECT_TRUE(m.part_names.empty());
    std::remove(path);
}
