// Shading normals (shading.h): smooth on curved surfaces, sharp at creases,
// flat where asked, the same whether or not triangles share vertex indices.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <vector>

#include "gamma/shading.h"
#include "helpers.h"

using gammart::V3;

namespace {

V3 corner(const std::vector<float>& c, size_t t, int k) {
    return V3{c[9 * t + 3 * size_t(k)], c[9 * t + 3 * size_t(k) + 1], c[9 * t + 3 * size_t(k) + 2]};
}

V3 face_normal(const gammart::Mesh& m, size_t t) {
    auto p = [&](int k) {
        const float* v = m.vertices.data() + 3 * size_t(m.triangles[3 * t + size_t(k)]);
        return V3{v[0], v[1], v[2]};
    };
    return gammart::normalize(gammart::cross(p(1) - p(0), p(2) - p(0)));
}

// A tread (y = 0, normal +y) meeting a riser (x = 1, normal +x) at a 90-degree
// convex edge; the two quads do not share vertex indices.
gammart::Mesh step_edge() {
    gamma_test::Builder b;
    gamma_test::floor_quad(b, 0, 1, 0, 1);
    b.quad({1, 0, 0}, {1, 0, 1}, {1, -1, 1}, {1, -1, 0});
    return b.mesh("step");
}

}  // namespace

TEST(Shading, SphereCornersPointOutwardAlongTheRadius) {
    const gammart::Mesh m = gamma_test::icosphere(3);
    const std::vector<float> c = gammart::corner_normals(m, {}, gammart::kDefaultCreaseDeg);
    ASSERT_EQ(c.size(), 9 * m.num_triangles());
    double worst = 1.0;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const float* v = m.vertices.data() + 3 * size_t(m.triangles[3 * t + size_t(k)]);
            const V3 radial = gammart::normalize(V3{v[0], v[1], v[2]});
            worst = std::min(worst, double(gammart::dot(corner(c, t, k), radial)));
            EXPECT_NEAR(gammart::length(corner(c, t, k)), 1.0f, 1e-5f);
        }
    EXPECT_GT(worst, 0.999);  // the flat faces' normals are up to ~8 degrees off at 3 subdivisions
    // A shared vertex gets one normal, whichever triangle asks.
    double face_worst = 1.0;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        face_worst = std::min(face_worst, double(gammart::dot(corner(c, t, 0), face_normal(m, t))));
    EXPECT_LT(face_worst, 0.999);
}

TEST(Shading, EdgesSharperThanTheCreaseStaySharp) {
    const gammart::Mesh m = step_edge();
    const std::vector<float> sharp = gammart::corner_normals(m, {}, 60.0f);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) EXPECT_GT(gammart::dot(corner(sharp, t, k), face_normal(m, t)), 0.99999f);
    // Above 90 degrees the edge is smoothed: its corners lean toward the other face.
    const std::vector<float> soft = gammart::corner_normals(m, {}, 100.0f);
    int on_edge = 0;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const float* v = m.vertices.data() + 3 * size_t(m.triangles[3 * t + size_t(k)]);
            if (v[0] == 1.0f && v[1] == 0.0f) {
                ++on_edge;
                const V3 n = corner(soft, t, k);
                EXPECT_GT(n.x, 0.3f);
                EXPECT_GT(n.y, 0.3f);
            } else {
                EXPECT_GT(gammart::dot(corner(soft, t, k), face_normal(m, t)), 0.99999f);
            }
        }
    EXPECT_GT(on_edge, 0);
}

TEST(Shading, FlatTrianglesAndZeroCreaseKeepTheirOwnNormal) {
    const gammart::Mesh m = gamma_test::icosphere(2);
    const std::vector<float> all_flat = gammart::corner_normals(m, {}, 0.0f);
    std::vector<uint8_t> flags(m.num_triangles(), 0);
    flags[7] = 1;
    const std::vector<float> one_flat = gammart::corner_normals(m, flags, 60.0f);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            EXPECT_GT(gammart::dot(corner(all_flat, t, k), face_normal(m, t)), 0.99999f);
            if (t == 7) {
                EXPECT_GT(gammart::dot(corner(one_flat, t, k), face_normal(m, t)), 0.99999f);
            }
        }
}

TEST(Shading, ShadingNormalInterpolatesAndFacesTheViewer) {
    const gammart::Mesh m = gamma_test::icosphere(2);
    const std::vector<float> c = gammart::corner_normals(m, {}, 60.0f);
    const V3 ng = face_normal(m, 3);
    const V3 at_corner = gammart::shading_normal(c, 3, 1.0f, 0.0f, ng);   // corner 1
    EXPECT_GT(gammart::dot(at_corner, corner(c, 3, 1)), 0.99999f);
    const V3 back = gammart::shading_normal(c, 3, 0.3f, 0.3f, ng * -1.0f);
    EXPECT_LT(gammart::dot(back, ng), 0.0f);
    EXPECT_EQ(gammart::shading_normal({}, 3, 0.3f, 0.3f, ng), ng);
}

namespace {

// corner_normals as the plain rule says, serially: each corner's normal sums
// the area-weighted normals of the corners at its position (bit for bit, -0
// as +0) whose face is within the crease angle, in corner order.
std::vector<float> reference_corner_normals(const gammart::Mesh& mesh, const std::vector<uint8_t>& flat,
                                            float crease_deg) {
    using gammart::V3;
    const size_t m = mesh.num_triangles();
    auto position = [&](size_t corner) {
        std::array<uint32_t, 3> bits{};
        const float* p = mesh.vertices.data() + 3 * size_t(mesh.triangles[corner]);
        for (int c = 0; c < 3; ++c) {
            const float x = p[c] == 0.0f ? 0.0f : p[c];
            std::memcpy(&bits[size_t(c)], &x, sizeof x);
        }
        return bits;
    };
    std::map<std::array<uint32_t, 3>, std::vector<size_t>> at;
    for (size_t i = 0; i < 3 * m; ++i) at[position(i)].push_back(i);
    std::vector<V3> weighted(m), unit(m);
    for (size_t t = 0; t < m; ++t) {
        auto p = [&](int k) {
            const float* v = mesh.vertices.data() + 3 * size_t(mesh.triangles[3 * t + size_t(k)]);
            return V3{v[0], v[1], v[2]};
        };
        weighted[t] = gammart::cross(p(1) - p(0), p(2) - p(0));
        unit[t] = gammart::normalize(weighted[t]);
    }
    const float cos_crease = std::cos(crease_deg * 3.14159265358979f / 180.0f);
    auto own = [&](size_t t) { return !flat.empty() && flat[t]; };
    std::vector<float> out(9 * m);
    for (size_t i = 0; i < 3 * m; ++i) {
        const size_t t = i / 3;
        V3 n = unit[t];
        if (!own(t)) {
            V3 sum{0, 0, 0};
            for (size_t q : at[position(i)]) {
                const size_t o = q / 3;
                if (o == t || (!own(o) && gammart::dot(unit[o], unit[t]) >= cos_crease)) sum += weighted[o];
            }
            const V3 s = gammart::normalize(sum);
            n = gammart::dot(s, s) > 0.0f ? s : unit[t];
        }
        out[3 * i] = n.x, out[3 * i + 1] = n.y, out[3 * i + 2] = n.z;
    }
    return out;
}

}  // namespace

TEST(Shading, CornerNormalsAreThePlainRuleBitForBit) {
    // a sphere whose vertices are shared, the step whose quads share none
    // (equal positions, different vertices), with and without flat parts
    const gammart::Mesh meshes[] = {gamma_test::icosphere(3), step_edge()};
    for (const gammart::Mesh& mesh : meshes) {
        std::vector<uint8_t> flat(mesh.num_triangles(), 0);
        for (size_t t = 0; t < flat.size(); t += 3) flat[t] = 1;
        for (const auto& f : {std::vector<uint8_t>{}, flat})
            for (float crease : {60.0f, 10.0f, 180.0f}) {
                const std::vector<float> got = gammart::corner_normals(mesh, f, crease);
                const std::vector<float> want = reference_corner_normals(mesh, f, crease);
                ASSERT_EQ(got.size(), want.size());
                EXPECT_EQ(0, std::memcmp(got.data(), want.data(), got.size() * sizeof(float)))
                    << mesh.num_triangles() << " triangles, crease " << crease << ", flat " << f.size();
            }
    }
}
