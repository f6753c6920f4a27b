// The PLY reader (runtime/src/ply.cpp): formats, declared sizes checked
// against the bytes present, degenerate faces dropped.  The mutation fuzz of
// the PLY and OBJ readers is test_mesh_fuzz.cpp.

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>

#include "helpers.h"

using gammart::Mesh;

namespace {

const char* kAsciiTetra =
    "ply\nformat ascii 1.0\ncomment a tetrahedron\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nproperty float u\nproperty float v\nelement face 4\n"
    "property list uchar int vertex_indices\nend_header\n"
    "0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n0 0 1 1 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";

template <typename T>
void put(std::string& out, T value, bool big_endian) {
    char b[sizeof(T)];
    std::memcpy(b, &value, sizeof(T));
    if (big_endian) std::reverse(b, b + sizeof(T));
    out.append(b, sizeof(T));
}

std::string binary_tetra(bool big_endian, const std::string& count_type = "uchar") {
    std::string s = std::string("ply\nformat ") + (big_endian ? "binary_big_endian" : "binary_little_endian") +
                    " 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty double z\n"
                    "element face 4\nproperty list " + count_type + " int vertex_indices\n"
                    "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n";
    const float v[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (auto& p : v) {
        put(s, p[0], big_endian);
        put(s, p[1], big_endian);
        put(s, double(p[2]), big_endian);
    }
    const int f[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    for (auto& t : f) {
        if (count_type == "uchar") put(s, uint8_t(3), big_endian);
        else put(s, int32_t(3), big_endian);
        for (int i : t) put(s, int32_t(i), big_endian);
    }
    put(s, int32_t(0), big_endian);
    put(s, int32_t(1), big_endian);
    return s;
}

}  // namespace

TEST(Ply, AsciiWithTextureCoordinates) {
    Mesh m = Mesh::parse_ply(kAsciiTetra, "t.ply");
    EXPECT_EQ(m.num_vertices(), 4u);
    EXPECT_EQ(m.num_triangles(), 4u);
    ASSERT_TRUE(m.has_uvs());
    // first triangle 0 2 1: corners' (u, v)
    EXPECT_EQ(m.uvs[0], 0.0f);
    EXPECT_EQ(m.uvs[2], 0.0f);
    EXPECT_EQ(m.uvs[3], 1.0f);
    EXPECT_EQ(m.uvs[4], 1.0f);
}

TEST(Ply, BinaryBothEndiansAgree) {
    for (const char* ct : {"uchar", "int"}) {
        Mesh le = Mesh::parse_ply(binary_tetra(false, ct), "le.ply");
        Mesh be = Mesh::parse_ply(binary_tetra(true, ct), "be.ply");
        EXPECT_EQ(le.vertices, be.vertices);
        EXPECT_EQ(le.triangles, be.triangles);
        EXPECT_EQ(le.num_triangles(), 4u);
        EXPECT_FALSE(le.has_uvs());
    }
}

TEST(Ply, DegenerateFacesAreDroppedAndCounted) {
    std::string s = kAsciiTetra;
    s.replace(s.find("element face 4"), 14, "element face 5");
    s += "3 0 0 1\n";
    Mesh m = Mesh::parse_ply(s, "d.ply");
    EXPECT_EQ(m.num_triangles(), 4u);
    EXPECT_EQ(m.degenerate_dropped, 1u);
}

// A face of two corners is a broken file, not a degenerate triangle (as in OBJ): an error naming it.
TEST(Ply, AFaceOfFewerThanThreeVerticesIsAnErrorNamingIt) {
    std::string s = kAsciiTetra;
    s.replace(s.find("element face 4"), 14, "element face 5");
    s += "2 0 1\n";
    std::string msg = gamma_test::expect_error([&] { Mesh::parse_ply(s, "d.ply"); });
    EXPECT_EQ(msg, "mesh 'd.ply': face 4 has fewer than 3 vertices (2)");
}

TEST(Ply, DeclaredSizesAreCheckedBeforeReading) {
    std::string s = binary_tetra(false);
    s.replace(s.find("element vertex 4"), 16, "element vertex 100000000000");
    std::string msg = gamma_test::expect_error([&] { Mesh::parse_ply(s, "h.ply"); });
    EXPECT_NE(msg.find("declares 100000000000 vertices, more than its"), std::string::npos) << msg;
}

TEST(Ply, TruncatedHeaderEnds) {
    std::string msg = gamma_test::expect_error(
        [] { Mesh::parse_ply("ply\nformat ascii 1.0\nelement vertex 3\n", "t.ply"); });
    EXPECT_EQ(msg, "mesh 't.ply' has no 'end_header': the header is truncated");
}
