// The scene index's triangle lookup (nearest_on_triangle): for every point on
// a triangle it finds the surfel the per-surface kd-tree finds, also on
// triangles far larger than the surfel spacing (cut into cells); it falls
// back to the kd-tree off the triangle, and is refreshed when either half of
// the index is rebuilt.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>

#include "gamma/scene_index.h"
#include "gamma/surfel_state.h"
#include "helpers.h"

using namespace gammart;

namespace {

double d2(const SurfelState& st, uint32_t i, const float p[3]) {
    double s = 0;
    for (int c = 0; c < 3; ++c) s += std::pow(double(st.surf.position[3 * i + c]) - p[c], 2);
    return s;
}

// Points on triangle t: its vertices, edge midpoints and random barycentric
// points (rng).
std::vector<std::array<float, 3>> points_on(const Mesh& m, size_t t, std::mt19937& rng, int random_points) {
    const float* v[3];
    for (int k = 0; k < 3; ++k) v[k] = &m.vertices[3 * size_t(m.triangles[3 * t + k])];
    std::vector<std::array<float, 3>> pts;
    auto at = [&](float a, float b) {
        const float c = 1.0f - a - b;
        pts.push_back({a * v[0][0] + b * v[1][0] + c * v[2][0], a * v[0][1] + b * v[1][1] + c * v[2][1],
                       a * v[0][2] + b * v[1][2] + c * v[2][2]});
    };
    at(1, 0), at(0, 1), at(0, 0), at(0.5f, 0.5f), at(0.5f, 0), at(0, 0.5f);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int k = 0; k < random_points; ++k) {
        float a = u(rng), b = u(rng);
        if (a + b > 1) a = 1 - a, b = 1 - b;
        at(a, b);
    }
    return pts;
}

// Every point of every triangle: the lookup's surfel is as near as the
// kd-tree's (and the same one unless two are exactly equidistant), and on
// the triangle's surface.
void expect_lookup_matches_kdtree(const Mesh& m, const std::vector<int32_t>& ts, const SurfelState& st,
                                  const SceneIndex& index, int random_points) {
    std::mt19937 rng(7);
    int64_t checked = 0, same = 0;
    for (size_t t = 0; t < m.num_triangles(); ++t) {
        for (const auto& q : points_on(m, t, rng, random_points)) {
            const float p[3] = {q[0], q[1], q[2]};
            const uint32_t a = index.nearest_on_triangle(uint32_t(t), p);
            const uint32_t b = index.nearest_of(ts[t], p);
            ASSERT_EQ(st.surface[a], ts[t]) << "triangle " << t;
            ASSERT_EQ(d2(st, a, p), d2(st, b, p)) << "triangle " << t;
            ++checked;
            same += a == b;
        }
    }
    EXPECT_GT(checked, 0);
    EXPECT_GE(double(same), 0.999 * double(checked));
}

}  // namespace

TEST(TriangleLookup, FindsTheKdTreesSurfelOnEveryTriangle) {
    // A sphere split into two surfaces by the sign of z (a seam where the
    // nearest surfel overall is often on the other surface).
    const Mesh m = gamma_test::icosphere(4);
    std::vector<int32_t> ts(m.num_triangles());
    for (size_t t = 0; t < ts.size(); ++t) ts[t] = m.vertices[3 * size_t(m.triangles[3 * t]) + 2] > 0 ? 1 : 0;
    const SurfelState st = SurfelState::sample(m, ts, 8000, 5, {{0, 0, 0}, {0, 0, 0}});
    SceneIndex index;
    index.build_geometry(m, ts, 2);
    index.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.02f, 2);
    EXPECT_EQ(index.lookup_fallback_triangles(), 0u);  // triangles about the surfel spacing: all precomputed
    EXPECT_GT(index.lookup_candidates(), m.num_triangles());
    EXPECT_LE(index.lookup_candidates(), size_t(SceneIndex::kMaxCandidates) * m.num_triangles());
    expect_lookup_matches_kdtree(m, ts, st, index, 20);
}

TEST(TriangleLookup, TheSameAtAnyThreadCount) {
    const Mesh m = gamma_test::icosphere(3);
    const std::vector<int32_t> ts(m.num_triangles(), 0);
    const SurfelState st = SurfelState::sample(m, ts, 3000, 9, {{0, 0, 0}});
    SceneIndex one, two;
    one.build_geometry(m, ts, 1);
    two.build_geometry(m, ts, 1);
    one.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.05f, 1);
    two.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.05f, 2);
    EXPECT_EQ(one.lookup_candidates(), two.lookup_candidates());
    std::mt19937 rng(3);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (const auto& q : points_on(m, t, rng, 3)) {
            const float p[3] = {q[0], q[1], q[2]};
            ASSERT_EQ(one.nearest_on_triangle(uint32_t(t), p), two.nearest_on_triangle(uint32_t(t), p));
        }
}

TEST(TriangleLookup, PackedEntryForEntryTheSameAtAnyThreadCount) {
    // A sphere of 20,480 triangles (many blocks of triangles, packed in
    // parallel) and a floor of two triangles far larger than the spacing
    // (cut into cells) on a second surface: the whole lookup -- heads,
    // packed entries, cells, grids, balls -- must not depend on how the
    // blocks were scheduled.
    gamma_test::Builder b;
    b.add(gamma_test::icosphere(5));
    gamma_test::floor_quad(b, 2, 4, -1, 1, -1);
    const Mesh m = b.mesh("sphere and floor");
    std::vector<int32_t> ts(m.num_triangles(), 0);
    ts[ts.size() - 1] = ts[ts.size() - 2] = 1;
    const SurfelState st = SurfelState::sample(m, ts, 20000, 11, {{0, 0, 0}, {0, 0, 0}});
    const float sigma = float(std::sqrt(m.area() / double(st.size())));
    SceneIndex one, two, four;
    for (auto [index, threads] : {std::pair{&one, 1}, std::pair{&two, 2}, std::pair{&four, 4}}) {
        index->build_geometry(m, ts, 2);
        index->build_surfels(st.surf.position.data(), st.surface.data(), st.size(), sigma, threads);
    }
    EXPECT_EQ(one.lookup_grid_triangles(), 2u);
    EXPECT_GT(one.lookup_candidates(), m.num_triangles());
    EXPECT_TRUE(one.same_lookup(two));
    EXPECT_TRUE(one.same_lookup(four));
    expect_lookup_matches_kdtree(m, ts, st, two, 2);
}

TEST(TriangleLookup, LargeTrianglesAreCutIntoCellsAndPointsOffTheTriangleUseTheKdTree) {
    // Two unit squares (four triangles) under 2,000 surfels: far more
    // candidates per triangle than kMaxCandidates, so each is cut into cells.
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    b.quad({1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0});
    const Mesh m = b.mesh("two squares");
    const std::vector<int32_t> ts = {0, 0, 1, 1};
    const SurfelState st = SurfelState::sample(m, ts, 2000, 3, {{0, 0, 0}, {0, 0, 0}});
    SceneIndex index;
    index.build_geometry(m, ts, 2);
    index.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.02f);
    EXPECT_EQ(index.lookup_grid_triangles(), m.num_triangles());
    EXPECT_EQ(index.lookup_fallback_triangles(), 0u);
    expect_lookup_matches_kdtree(m, ts, st, index, 2000);
    // On the cells' borders and corners too (a 1/64 lattice of the squares).
    int64_t checked = 0, scanned = 0;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int i = 0; i <= 64; ++i)
            for (int j = 0; j <= 64 - i; ++j) {
                const float* v[3];
                for (int k = 0; k < 3; ++k) v[k] = &m.vertices[3 * size_t(m.triangles[3 * t + k])];
                const float a = float(i) / 64, c = float(j) / 64;
                float p[3];
                for (int d = 0; d < 3; ++d) p[d] = v[0][d] + a * (v[1][d] - v[0][d]) + c * (v[2][d] - v[0][d]);
                const uint32_t x = index.nearest_on_triangle(uint32_t(t), p), y = index.nearest_of(ts[t], p);
                ASSERT_EQ(d2(st, x, p), d2(st, y, p)) << "triangle " << t << " at " << i << "," << j;
                ++checked;
                scanned += index.lookup_scan(uint32_t(t), p) == x;
            }
    EXPECT_GT(checked, 8000);
    // and the cells answer (the kd-tree only where a cell has too many)
    EXPECT_GE(double(scanned), 0.95 * double(checked));

    // The same cells and answers at 1 and 2 threads.
    SceneIndex serial;
    serial.build_geometry(m, ts, 2);
    serial.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.02f, 1);
    EXPECT_EQ(serial.lookup_candidates(), index.lookup_candidates());
    std::mt19937 rng(5);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (const auto& q : points_on(m, t, rng, 200)) {
            const float p[3] = {q[0], q[1], q[2]};
            ASSERT_EQ(serial.nearest_on_triangle(uint32_t(t), p), index.nearest_on_triangle(uint32_t(t), p));
        }

    // A fine sphere: a point far from triangle 0 still gets its surface's
    // nearest surfel (the kd-tree answers).
    const Mesh s = gamma_test::icosphere(3);
    const std::vector<int32_t> one(s.num_triangles(), 0);
    const SurfelState sst = SurfelState::sample(s, one, 3000, 4, {{0, 0, 0}});
    SceneIndex sphere;
    sphere.build_geometry(s, one, 1);
    sphere.build_surfels(sst.surf.position.data(), sst.surface.data(), sst.size(), 0.05f);
    const float far[3] = {0.0f, 0.0f, -1.0f};
    EXPECT_EQ(sphere.nearest_on_triangle(0, far), sphere.nearest_of(0, far));
}

TEST(TriangleLookup, FollowsARebuildOfEitherHalf) {
    const Mesh m = gamma_test::icosphere(3);
    const std::vector<int32_t> ts(m.num_triangles(), 0);
    const SurfelState a = SurfelState::sample(m, ts, 3000, 1, {{0, 0, 0}});
    const SurfelState c = SurfelState::sample(m, ts, 2000, 2, {{0, 0, 0}});
    SceneIndex index;
    index.build_geometry(m, ts, 1);
    index.build_surfels(a.surf.position.data(), a.surface.data(), a.size(), 0.05f);
    index.build_surfels(c.surf.position.data(), c.surface.data(), c.size(), 0.05f);  // new surfels
    expect_lookup_matches_kdtree(m, ts, c, index, 5);
    // The same surfels on a larger sphere's triangles: the geometry rebuild
    // refreshes the triangles' candidates (the points are off the old ones).
    const Mesh big = gamma_test::icosphere(3, 1.001f);
    index.build_geometry(big, ts, 1);
    expect_lookup_matches_kdtree(big, ts, c, index, 5);
}

// The shape step's riding surfels (SPEC §13.12): vertices and surfels move,
// the index is updated in place (move_vertices + move_surfels): it must
// still agree with the kd-tree everywhere, and with a freshly built index.
TEST(TriangleLookup, StaysExactWhenVerticesAndSurfelsMoveInPlace) {
    Mesh m = gamma_test::icosphere(4);
    std::vector<int32_t> ts(m.num_triangles());
    for (size_t t = 0; t < ts.size(); ++t) ts[t] = m.vertices[3 * size_t(m.triangles[3 * t]) + 2] > 0 ? 1 : 0;
    SurfelState st = SurfelState::sample(m, ts, 8000, 5, {{0, 0, 0}, {0, 0, 0}});
    const float sigma = float(std::sqrt(m.area() / double(st.size())));
    SceneIndex index;
    index.build_geometry(m, ts, 2);
    index.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), sigma, 2);
    // Radial moves, large on the x > 0.3 cap, none elsewhere.
    auto push = [&](float* p, float amount) {
        const float r = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        const float f = p[0] > 0.3f ? 1.0f - amount * (p[0] - 0.3f) / r : 1.0f;
        for (int c = 0; c < 3; ++c) p[c] *= f;
    };
    for (int step = 1; step <= 3; ++step) {
        const float amount = 1.5f * sigma * float(step);
        for (size_t v = 0; v < m.num_vertices(); ++v) push(&m.vertices[3 * v], amount);
        for (size_t i = 0; i < st.size(); ++i) push(&st.surf.position[3 * i], amount);
        index.move_vertices(m);
        index.move_surfels(st.surf.position.data(), sigma, 2);
        expect_lookup_matches_kdtree(m, ts, st, index, 4);
        SceneIndex fresh;
        fresh.build_geometry(m, ts, 2);
        fresh.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), sigma, 2);
        EXPECT_TRUE(index.same_lookup(fresh)) << "step " << step;
        std::mt19937 rng(3);
        for (size_t t = 0; t < m.num_triangles(); t += 7)
            for (const auto& q : points_on(m, t, rng, 2)) {
                const float p[3] = {q[0], q[1], q[2]};
                ASSERT_EQ(index.nearest_on_triangle(uint32_t(t), p), fresh.nearest_on_triangle(uint32_t(t), p))
                    << "step " << step << " triangle " << t;
            }
        // Rays see the moved triangles.
        RTCRayHit a, b;
        index.cast(a, V3{2, 0.01f, 0.02f}, V3{-1, 0, 0}, 0.0f);
        fresh.cast(b, V3{2, 0.01f, 0.02f}, V3{-1, 0, 0}, 0.0f);
        ASSERT_NE(a.hit.geomID, RTC_INVALID_GEOMETRY_ID);
        EXPECT_EQ(a.ray.tfar, b.ray.tfar);
        EXPECT_EQ(a.hit.primID, b.hit.primID);
    }
}

// The shape step's lookup built ahead (SceneIndex::build_lookup_ahead, made
// beside a local re-tiling): a build that takes its entries is the build
// from scratch, entry for entry, whatever moved, came, left or changed
// surface, with triangles renumbered, new, moved or left out ahead; and it
// does take the entries nothing changed.
TEST(TriangleLookup, EntriesBuiltAheadAreTakenOnlyWhereTheyHold) {
    const Mesh m0 = gamma_test::icosphere(4);
    const size_t m = m0.num_triangles();
    std::vector<int32_t> ts0(m);
    for (size_t t = 0; t < m; ++t) ts0[t] = m0.vertices[3 * size_t(m0.triangles[3 * t]) + 2] > 0 ? 1 : 0;
    const SurfelState st0 = SurfelState::sample(m0, ts0, 8000, 5, {{0, 0, 0}, {0, 0, 0}});
    const float sigma = float(std::sqrt(m0.area() / double(st0.size())));
    // Ahead: the triangles with a corner above z = 0.8 left out.
    std::vector<uint8_t> skip(m, 0);
    size_t skipped = 0;
    for (size_t t = 0; t < m; ++t)
        for (int k = 0; k < 3; ++k)
            if (m0.vertices[3 * size_t(m0.triangles[3 * t + size_t(k)]) + 2] > 0.8f) skip[t] = 1;
    for (uint8_t f : skip) skipped += f;
    SceneIndex ahead;
    ahead.build_lookup_ahead(m0, ts0, 2, st0.surf.position.data(), st0.surface.data(), st0.size(), sigma, skip);

    // After: the triangles in reverse order (every 50th new), the vertices
    // of the band 0.3 < x < 0.5 and the surfels there pushed in by 1e-3;
    // the surfels of -0.5 < x < -0.4 replaced (moved along y by a quarter
    // spacing), those of -0.1 < x < -0.05 moved to the other surface.
    std::vector<float> v1 = m0.vertices;
    auto in_band = [](const float* p) { return p[0] > 0.3f && p[0] < 0.5f; };
    for (size_t v = 0; v < m0.num_vertices(); ++v)
        if (in_band(&v1[3 * v]))
            for (int c = 0; c < 3; ++c) v1[3 * v + size_t(c)] *= 0.999f;
    std::vector<int32_t> tris1(3 * m), ts1(m), ahead_triangle(m);
    for (size_t t = 0; t < m; ++t) {
        const size_t d = m - 1 - t;
        for (int k = 0; k < 3; ++k) tris1[3 * t + size_t(k)] = m0.triangles[3 * d + size_t(k)];
        ts1[t] = ts0[d];
        ahead_triangle[t] = t % 50 == 0 ? -1 : int32_t(d);
    }
    const Mesh m1 = Mesh::from_arrays(v1.data(), m0.num_vertices(), tris1.data(), m, "after");
    ASSERT_EQ(m1.num_triangles(), m);
    ASSERT_EQ(m1.diagonal(), m0.diagonal());   // the spheres' pad as ahead (the band holds no extreme)
    SurfelState st1 = st0;
    for (size_t i = 0; i < st1.size(); ++i) {
        float* p = &st1.surf.position[3 * i];
        if (in_band(p)) {
            for (int c = 0; c < 3; ++c) p[c] *= 0.999f;
        } else if (p[0] > -0.5f && p[0] < -0.4f) {
            p[1] += 0.25f * sigma;
        } else if (p[0] > -0.1f && p[0] < -0.05f) {
            st1.surface[i] = 1 - st1.surface[i];
        }
    }
    auto build = [&](SceneIndex& x, const float* pos, int threads, const SceneIndex* from) {
        x.build_geometry(m1, ts1, 2, false);
        x.build_surfels(pos, st1.surface.data(), st1.size(), sigma, threads, from, from ? &ahead_triangle : nullptr);
    };
    SceneIndex scratch, taking, taking_serial, other;
    build(scratch, st1.surf.position.data(), 2, nullptr);
    build(taking, st1.surf.position.data(), 2, &ahead);
    build(taking_serial, st1.surf.position.data(), 1, &ahead);
    EXPECT_EQ(scratch.lookup_reused_triangles(), 0u);
    EXPECT_TRUE(taking.same_lookup(scratch));
    EXPECT_TRUE(taking_serial.same_lookup(scratch));
    // Most entries taken; not those left out ahead, new or near a change.
    EXPECT_GT(taking.lookup_reused_triangles(), m / 2);
    EXPECT_LT(taking.lookup_reused_triangles(), m - skipped - m / 50 - 500);
    expect_lookup_matches_kdtree(m1, ts1, st1, taking, 5);
    // same_lookup tells a different lookup apart: the surfels before the changes.
    build(other, st0.surf.position.data(), 2, nullptr);
    EXPECT_FALSE(other.same_lookup(scratch));
    // Ahead for other surfels (a count of its own): nothing taken, the same lookup.
    const SurfelState fewer = SurfelState::sample(m0, ts0, 7000, 6, {{0, 0, 0}, {0, 0, 0}});
    SceneIndex ahead_fewer, from_fewer;
    ahead_fewer.build_lookup_ahead(m0, ts0, 2, fewer.surf.position.data(), fewer.surface.data(), fewer.size(), sigma,
                                   skip);
    build(from_fewer, st1.surf.position.data(), 2, &ahead_fewer);
    EXPECT_EQ(from_fewer.lookup_reused_triangles(), 0u);
    EXPECT_TRUE(from_fewer.same_lookup(scratch));
}
