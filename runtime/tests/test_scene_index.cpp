// The scene index on its own: rays against the BVH, per-surface nearest
// surfels, smoothing weights, and rebuilding each half separately.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "gamma/scene_index.h"
#include "gamma/surfel_state.h"
#include "helpers.h"

using namespace gammart;

namespace {

// Two unit squares side by side in z = 0: x in [0,1] is surface 0, [1,2] surface 1.
Mesh two_squares(float z = 0) {
    gamma_test::Builder b;
    b.quad({0, 0, z}, {1, 0, z}, {1, 1, z}, {0, 1, z});
    b.quad({1, 0, z}, {2, 0, z}, {2, 1, z}, {1, 1, z});
    return b.mesh("two squares");
}

}  // namespace

TEST(SceneIndex, RaysHitTheTrianglesAndReportTheirSurface) {
    const Mesh m = two_squares();
    SceneIndex index;
    index.build_geometry(m, {0, 0, 1, 1}, 2);
    RTCRayHit rh;
    index.cast(rh, V3{1.5f, 0.5f, 1.0f}, V3{0, 0, -1}, 0.0f);
    ASSERT_NE(rh.hit.geomID, RTC_INVALID_GEOMETRY_ID);
    EXPECT_FLOAT_EQ(rh.ray.tfar, 1.0f);
    EXPECT_EQ(index.tri_surface()[rh.hit.primID], 1);
    index.cast(rh, V3{3.0f, 0.5f, 1.0f}, V3{0, 0, -1}, 0.0f);
    EXPECT_EQ(rh.hit.geomID, RTC_INVALID_GEOMETRY_ID);
    EXPECT_TRUE(index.occluded(V3{0.5f, 0.5f, 1.0f}, V3{0, 0, -1}, 0.0f, 2.0f));
    EXPECT_FALSE(index.occluded(V3{0.5f, 0.5f, 1.0f}, V3{0, 0, -1}, 0.0f, 0.5f));
    EXPECT_EQ(index.geometry_builds(), 1);
}

TEST(SceneIndex, NearestSurfelStaysOnTheAskedSurface) {
    const Mesh m = two_squares();
    const std::vector<int32_t> ts = {0, 0, 1, 1};
    const SurfelState st = SurfelState::sample(m, ts, 400, 3, {{0, 0, 0}, {0, 0, 0}});
    SceneIndex index;
    index.build_geometry(m, ts, 2);
    index.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.05f);
    const std::vector<size_t> per = index.surfels_per_surface();
    ASSERT_EQ(per.size(), 2u);
    EXPECT_EQ(per[0] + per[1], st.size());
    // Just left of the seam the nearest surfel overall may be on surface 1,
    // but the nearest of surface 0 is always on surface 0.
    for (int k = 0; k < 50; ++k) {
        const float p[3] = {0.999f, 0.02f * float(k), 0.0f};
        EXPECT_EQ(st.surface[index.nearest_of(0, p)], 0);
        EXPECT_EQ(st.surface[index.nearest_of(1, p)], 1);
        // The global nearest is the closest of the two per-surface answers.
        const uint32_t a = index.nearest_of(0, p), b = index.nearest_of(1, p), g = index.nearest(p);
        auto d2 = [&](uint32_t i) {
            double s = 0;
            for (int c = 0; c < 3; ++c) s += std::pow(double(st.surf.position[3 * i + c]) - p[c], 2);
            return s;
        };
        EXPECT_DOUBLE_EQ(d2(g), std::min(d2(a), d2(b)));
    }
    uint32_t idx[kSmoothingNeighbours];
    double w[kSmoothingNeighbours];
    const float p[3] = {1.5f, 0.5f, 0.0f};
    const size_t k = index.smooth(1, p, idx, w);
    ASSERT_EQ(k, size_t(kSmoothingNeighbours));
    double sum = 0;
    for (size_t j = 0; j < k; ++j) {
        EXPECT_EQ(st.surface[idx[j]], 1);
        sum += w[j];
    }
    EXPECT_NEAR(sum, 1.0, 1e-12);
}

TEST(SceneIndex, ASurfaceHoldingEverySurfelAnswersAsItsOwnTreeWould) {
    // Surface 0 holds every surfel (surface 1 has no triangle): build_surfels
    // serves it with the tree over all surfels, build_lookup_ahead (no tree
    // over all surfels) builds it a tree of its own.  The answers must be
    // the same, bit for bit.
    const Mesh m = gamma_test::icosphere(3);
    const std::vector<int32_t> ts(m.num_triangles(), 0);
    const SurfelState st = SurfelState::sample(m, ts, 3000, 6, {{0, 0, 0}, {0, 0, 0}});
    SceneIndex shared, own;
    shared.build_geometry(m, ts, 2);
    shared.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.05f);
    own.build_lookup_ahead(m, ts, 2, st.surf.position.data(), st.surface.data(), st.size(), 0.05f,
                           std::vector<uint8_t>(m.num_triangles(), 0));
    EXPECT_EQ(shared.surfels_per_surface(), (std::vector<size_t>{st.size(), 0}));
    EXPECT_EQ(own.surfels_per_surface(), shared.surfels_per_surface());
    EXPECT_TRUE(shared.has_surfels(0));
    EXPECT_FALSE(shared.has_surfels(1));
    EXPECT_TRUE(own.has_surfels(0));
    std::mt19937 rng(8);
    std::uniform_real_distribution<float> u(-1.3f, 1.3f);
    for (int k = 0; k < 2000; ++k) {
        const float p[3] = {u(rng), u(rng), u(rng)};
        ASSERT_EQ(shared.nearest_of(0, p), own.nearest_of(0, p));
        ASSERT_EQ(shared.nearest_of(0, p), shared.nearest(p));
        uint32_t ia[kSmoothingNeighbours], ib[kSmoothingNeighbours];
        double wa[kSmoothingNeighbours], wb[kSmoothingNeighbours];
        const size_t na = shared.smooth(0, p, ia, wa), nb = own.smooth(0, p, ib, wb);
        ASSERT_EQ(na, nb);
        for (size_t j = 0; j < na; ++j) {
            ASSERT_EQ(ia[j], ib[j]);
            ASSERT_EQ(wa[j], wb[j]);
        }
    }
}

TEST(SceneIndex, GeometryAndSurfelsRebuildSeparately) {
    SceneIndex index;
    index.build_geometry(two_squares(0), {0, 0, 1, 1}, 2);
    const float pos[6] = {0.5f, 0.5f, 0, 1.5f, 0.5f, 0};
    const int32_t surf[2] = {0, 1};
    index.build_surfels(pos, surf, 2, 0.5f);
    // Move the geometry up by 0.25: the same ray now hits earlier.
    index.build_geometry(two_squares(0.25f), {0, 0, 1, 1}, 2);
    RTCRayHit rh;
    index.cast(rh, V3{0.5f, 0.5f, 1.0f}, V3{0, 0, -1}, 0.0f);
    ASSERT_NE(rh.hit.geomID, RTC_INVALID_GEOMETRY_ID);
    EXPECT_FLOAT_EQ(rh.ray.tfar, 0.75f);
    EXPECT_EQ(index.geometry_builds(), 2);
    EXPECT_EQ(index.surfel_builds(), 1);  // surfels untouched by a geometry rebuild
    const float q[3] = {1.6f, 0.5f, 0};
    EXPECT_EQ(index.nearest(q), 1u);
    // New surfels: only the kd-trees change.
    const float pos2[6] = {1.5f, 0.5f, 0, 0.5f, 0.5f, 0};
    const int32_t surf2[2] = {1, 0};
    index.build_surfels(pos2, surf2, 2, 0.5f);
    EXPECT_EQ(index.nearest(q), 0u);
    EXPECT_EQ(index.nearest_of(0, q), 1u);
    EXPECT_EQ(index.surfel_builds(), 2);
    EXPECT_EQ(index.geometry_builds(), 2);
}

TEST(SceneIndex, FrameFromBoundsAndGravity) {
    const Mesh m = two_squares(0);
    const SceneFrame f = SceneFrame::of(m, {0, 0, -2});
    EXPECT_EQ(f.up.z, 1.0f);
    EXPECT_EQ(f.down.z, -1.0f);
    EXPECT_FLOAT_EQ(f.diag, std::sqrt(5.0f));
    EXPECT_FLOAT_EQ(f.eps, 1e-5f * f.diag);
    EXPECT_FLOAT_EQ(f.centre.x, 1.0f);
    EXPECT_FLOAT_EQ(f.min_up, 0.0f);
}
