// Shading normals (shading.h): smooth on curved surfaces, sharp at creases,
// flat where asked, the same whether or not triangles share vertex indices.
#include <gtest/gtest.h>

#include <cmath>

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
