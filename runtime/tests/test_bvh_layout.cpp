// The Embree BVH gives the same hits in every build, at any thread count.
//
// Which triangle a ray reports where it meets two or more at the same t (a
// shared edge or vertex: the scene is robust, so both count as hit) is the
// one the traversal reaches first, so it depends on the BVH's layout.
// Embree's high-quality builder runs in parallel (spatial splits placed with
// atomic counters): if its layout followed the scheduling, such rays, and
// with them a run's output, could differ between runs or thread counts.
// This aims rays at every vertex and edge midpoint of the bunny and checks
// that the BVH built at one thread, in an arena of two, and on a thread of
// its own beside busy TBB work (as Simulation builds it while sampling)
// reports the same triangle and t for each, bit for bit.  The rays are
// sensitive to the layout: a BVH of RTC_BUILD_QUALITY_LOW over the same
// bunny (another layout) reports another triangle for ~1 % of them (4,029 of
// 420,705 when this was written; Embree 3.13.5).
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <set>
#include <utility>
#include <vector>

#include <tbb/parallel_for.h>

#include "gamma/mesh.h"
#include "gamma/scene_index.h"
#include "gamma/threads.h"

using namespace gammart;

namespace {

struct Hits {
    std::vector<uint64_t> prim_and_t;   // primID << 32 | bits of t
    size_t at_target = 0;               // rays whose hit is the point aimed at
};

std::vector<V3> targets_of(const Mesh& m) {
    std::vector<V3> out;
    const float* v = m.vertices.data();
    for (size_t i = 0; i < m.vertices.size() / 3; ++i) out.push_back(V3{v[3 * i], v[3 * i + 1], v[3 * i + 2]});
    std::set<std::pair<int32_t, int32_t>> edges;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int e = 0; e < 3; ++e) {
            const int32_t a = m.triangles[3 * t + e], b = m.triangles[3 * t + (e + 1) % 3];
            edges.insert({std::min(a, b), std::max(a, b)});
        }
    for (const auto& [a, b] : edges)
        out.push_back(V3{(v[3 * a] + v[3 * b]) * 0.5f, (v[3 * a + 1] + v[3 * b + 1]) * 0.5f,
                         (v[3 * a + 2] + v[3 * b + 2]) * 0.5f});
    return out;
}

Hits cast_all(const SceneIndex& index, const std::vector<V3>& targets) {
    // Two origins outside the bunny (its box is about [-0.1, 0.06] x [0.03, 0.19] x [-0.06, 0.06]).
    const V3 origins[2] = {V3{0.4f, 0.3f, 0.5f}, V3{-0.5f, 0.1f, -0.4f}};
    Hits h;
    for (const V3& o : origins)
        for (const V3& p : targets) {
            const V3 d{p.x - o.x, p.y - o.y, p.z - o.z};
            RTCRayHit rh;
            index.cast(rh, o, d, 0.0f);
            uint32_t bits = 0;
            std::memcpy(&bits, &rh.ray.tfar, sizeof bits);
            h.prim_and_t.push_back((uint64_t(rh.hit.primID) << 32) | bits);
            // d runs from the origin to the target: t = 1 there
            h.at_target += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID && std::fabs(rh.ray.tfar - 1.0f) < 1e-5f;
        }
    return h;
}

}  // namespace

TEST(BvhLayout, RaysThroughVerticesAndEdgesHitTheSameTriangleInEveryBuild) {
    const Mesh bunny = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    const std::vector<int32_t> one_surface(bunny.num_triangles(), 0);
    const std::vector<V3> targets = targets_of(bunny);

    auto build_at = [&](int threads) {
        SceneIndex index;
        run_with_threads(threads, [&] { index.build_geometry(bunny, one_surface, 1); });
        return cast_all(index, targets);
    };
    auto build_beside_busy_work = [&] {
        SceneIndex index;
        std::atomic<bool> built{false};
        run_with_threads(2, [&] {
            ThreadBeside bvh([&] {
                index.build_geometry(bunny, one_surface, 1);
                built = true;
            });
            // TBB work in the caller's arena while the BVH is built (the sampling's place)
            while (!built) {
                std::atomic<uint64_t> sink{0};
                tbb::parallel_for(0, 64, [&](int i) {
                    uint64_t x = uint64_t(i);
                    for (int k = 0; k < 20000; ++k) x = x * 6364136223846793005ull + 1442695040888963407ull;
                    sink += x;
                });
            }
            bvh.wait();
        });
        return cast_all(index, targets);
    };

    const Hits first = build_at(1);
    // The rays go where they are aimed: most reach their vertex or edge first.
    EXPECT_GT(first.at_target, first.prim_and_t.size() / 3);
    for (int round = 0; round < 2; ++round) {
        for (const Hits& again : {build_at(1), build_at(2), build_beside_busy_work()}) {
            ASSERT_EQ(again.prim_and_t.size(), first.prim_and_t.size());
            size_t differ = 0;
            for (size_t k = 0; k < first.prim_and_t.size(); ++k) differ += again.prim_and_t[k] != first.prim_and_t[k];
            EXPECT_EQ(differ, 0u) << "round " << round;
        }
    }
}
