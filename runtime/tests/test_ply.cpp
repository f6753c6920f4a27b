// The PLY reader (runtime/src/ply.cpp): formats, declared sizes checked
// against the bytes present, degenerate faces dropped, and a bounded
// mutation fuzz of PLY and OBJ bytes run under ASan/UBSan: every input ends
// in a mesh or a gammart::Error, never a crash, a hang or a huge allocation.

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <random>
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
    s.replace(s.find("element face 4"), 14, "element face 6");
    s += "3 0 0 1\n2 0 1\n";
    Mesh m = Mesh::parse_ply(s, "d.ply");
    EXPECT_EQ(m.num_triangles(), 4u);
    EXPECT_EQ(m.degenerate_dropped, 2u);
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

TEST(Ply, MutationFuzz) {
    const std::string seeds[] = {kAsciiTetra, binary_tetra(false), binary_tetra(true, "int"),
                                 "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\ng a\no b\n"
                                 "usemtl c\nf 1/1 2/2 3/3\nf 1/1 2/2 4/3\nf -1 -2 -3\n"};
    const char* tokens[] = {"\n", " ", "-1", "4294967295", "99999999999", "nan", "1e39", "end_header\n",
                            "element face 3\n", "property list uchar int vertex_indices\n", "\xff", "/", "f ",
                            "v ", "vt "};
    std::mt19937_64 rng(13);
    int meshes = 0, errors = 0;
    for (int n = 0; n < 4000; ++n) {
        const size_t which = rng() % 4;
        std::string s = seeds[which];
        const int edits = 1 + int(rng() % 4);
        for (int e = 0; e < edits; ++e) {
            const size_t at = rng() % (s.size() + 1);
            switch (rng() % 4) {
                case 0: s.erase(at, rng() % 16); break;
                case 1: s.insert(at, tokens[rng() % (sizeof(tokens) / sizeof(*tokens))]); break;
                case 2: if (at < s.size()) s[at] = char(rng() % 256); break;
                default: s.resize(at); break;
            }
        }
        try {
            Mesh m = which == 3 ? Mesh::parse_obj(s, "f.obj") : Mesh::parse_ply(s, "f.ply");
            EXPECT_GT(m.num_triangles(), 0u);
            ++meshes;
        } catch (const gammart::Error& err) {
            EXPECT_EQ(std::string(err.what()).find('\n'), std::string::npos);
            ++errors;
        }
    }
    EXPECT_GT(meshes, 100);
    EXPECT_GT(errors, 100);
}
