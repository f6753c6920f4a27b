// The column index's radius queries give exactly the set a nanoflann kd-tree's
// radius search gives (its float metric and strict `<`), which is what lets
// the triangle lookup and the splat kernel use either with the same result;
// append_within gives what within does, in the same order.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>
#include <vector>

#include "gamma/float_points.h"
#include "gamma/point_columns.h"

using namespace gammart;

namespace {

using Found = std::vector<std::pair<uint32_t, float>>;

Found sorted(Found f) {
    std::sort(f.begin(), f.end());
    return f;
}

// Every query against the kd-tree: the same indices with the same distances.
// Returns the number of points found in all (so a test can check it looked
// at something).
size_t expect_same_sets(const std::vector<float>& pts, const std::vector<float>& queries,
                        const std::vector<float>& radii, double side) {
    FloatPoints cloud{pts.data(), pts.size() / 3};
    FloatPointsKdTree kd(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
    kd.buildIndex();
    PointColumns cols;
    cols.build(pts.data(), pts.size() / 3, side);
    size_t total = 0;
    for (size_t q = 0; q < queries.size() / 3; ++q)
        for (float r : radii) {
            const float r2 = r * r;
            Found a, b;
            kd.radiusSearch(&queries[3 * q], r2, a, nanoflann::SearchParams(32, 0.0f, false));
            cols.within(&queries[3 * q], r2, [&](uint32_t i, float d2) { b.emplace_back(i, d2); });
            // append_within: the same entries in the same order, after what
            // the vector held
            Found appended = {{123456u, -1.0f}};
            cols.append_within(&queries[3 * q], r2, appended,
                               [](uint32_t i, float d2) { return std::pair<uint32_t, float>(i, d2); });
            Found expected = {{123456u, -1.0f}};
            expected.insert(expected.end(), b.begin(), b.end());
            EXPECT_EQ(appended, expected) << "query " << q << " radius " << r;
            a = sorted(a);
            b = sorted(b);
            EXPECT_EQ(a, b) << "query " << q << " radius " << r;
            if (a != b) return total;
            total += a.size();
        }
    return total;
}
}  // namespace

TEST(PointColumns, SameSetsAsKdTreeOnRandomSurfaceAndVolume) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::vector<float> pts, queries;
    // points on a unit sphere (a surface, like surfels) and in a slab
    for (int i = 0; i < 4000; ++i) {
        float x = u(rng), y = u(rng), z = u(rng);
        const float l = std::sqrt(x * x + y * y + z * z);
        if (l < 1e-3f) continue;
        pts.insert(pts.end(), {x / l, y / l, z / l});
    }
    for (int i = 0; i < 2000; ++i) pts.insert(pts.end(), {u(rng), 0.05f * u(rng), u(rng)});
    for (int i = 0; i < 300; ++i) queries.insert(queries.end(), {1.2f * u(rng), 1.2f * u(rng), 1.2f * u(rng)});
    // queries exactly at points (distance 0 included)
    for (int i = 0; i < 50; ++i) queries.insert(queries.end(), pts.begin() + 3 * i * 7, pts.begin() + 3 * i * 7 + 3);
    const size_t found = expect_same_sets(pts, queries, {0.01f, 0.05f, 0.13f, 0.4f, 3.0f}, 0.1);
    EXPECT_GT(found, 10000u);
    // a column side far from the radius changes nothing
    EXPECT_EQ(expect_same_sets(pts, queries, {0.05f, 0.4f}, 0.01), expect_same_sets(pts, queries, {0.05f, 0.4f}, 2.0));
}

TEST(PointColumns, PointsExactlyAtTheRadiusAreLeftOutLikeTheKdTree) {
    // An integer lattice: many points at exactly the query radius (d2 == r2
    // in float), which the strict `<` leaves out; duplicates too.
    std::vector<float> pts, queries;
    for (int i = -6; i <= 6; ++i)
        for (int j = -6; j <= 6; ++j)
            for (int k = -2; k <= 2; ++k) pts.insert(pts.end(), {float(i), float(j), float(k)});
    pts.insert(pts.end(), {1, 1, 1, 1, 1, 1});
    for (int i = -3; i <= 3; ++i)
        for (int j = -3; j <= 3; ++j) queries.insert(queries.end(), {float(i), float(j), 0.0f});
    queries.insert(queries.end(), {0.5f, 0.5f, 0.5f});
    // radii whose squares are integers (exactly representable): boundary points
    const size_t found = expect_same_sets(pts, queries, {1.0f, std::sqrt(2.0f), 2.0f, std::sqrt(5.0f), 3.0f}, 1.0);
    EXPECT_GT(found, 1000u);
    // the boundary matters: r = 1 from a lattice point finds only the point itself
    PointColumns cols;
    cols.build(pts.data(), pts.size() / 3, 1.0);
    size_t n = 0;
    const float q[3] = {0, 0, 0};
    cols.within(q, 1.0f, [&](uint32_t, float d2) { n += d2 == 0.0f; });
    EXPECT_EQ(n, 1u);
}

TEST(PointColumns, DegenerateSets) {
    // all on one point, a single line, and an empty set
    std::vector<float> same(300, 0.25f), line;
    for (int i = 0; i < 100; ++i) line.insert(line.end(), {0.0f, 0.0f, 0.01f * float(i)});
    const std::vector<float> queries = {0.25f, 0.25f, 0.25f, 0, 0, 0.5f, 1, 1, 1};
    EXPECT_EQ(expect_same_sets(same, queries, {0.001f, 1.0f}, 0.1), 3 * 100u);
    EXPECT_GT(expect_same_sets(line, queries, {0.05f, 0.3f, 2.0f}, 0.1), 100u);
    PointColumns empty;
    empty.build(nullptr, 0, 1.0);
    size_t n = 0;
    empty.within(queries.data(), 1.0f, [&](uint32_t, float) { ++n; });
    EXPECT_EQ(n, 0u);
    std::vector<uint32_t> none;
    empty.append_within(queries.data(), 1.0f, none, [](uint32_t i, float) { return i; });
    EXPECT_TRUE(none.empty());
}
