// The splat kernel (SPEC §13.2): it conserves amounts, stays on its own
// surface and tangent plane, and is bit-identical at any thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gamma/gmath.h"
#include "gamma/splat.h"
#include "gamma/threads.h"

using namespace gammart;

namespace {
// A grid of surfels at spacing h on the plane y = 0 (surface 0), and the same
// grid raised by 0.6 h (surface 0 too, as a tile top over a joint floor),
// and a third copy at y = 0 on surface 1 shifted by h/2.
struct Grid {
    std::vector<float> pos, nrm;
    std::vector<int32_t> surf;
    void add(float x, float y, float z, int s) {
        pos.insert(pos.end(), {x, y, z});
        nrm.insert(nrm.end(), {0, 1, 0});
        surf.push_back(s);
    }
};
Grid make_grid(int k, float h) {
    Grid g;
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) {
            g.add(i * h, 0, j * h, 0);
            g.add(i * h, 0.6f * h, j * h + 100 * h, 0);  // far away: its own patch
            g.add(i * h + 0.5f * h, 0.0f, j * h, 1);
        }
    return g;
}
}  // namespace

TEST(Splat, ConservesAmountsAndStaysOnItsSurfaceAndPlane) {
    const float h = 0.01f;
    Grid g = make_grid(12, h);
    // the raised copy placed right above the first: a parallel face 0.6 h up
    for (size_t i = 0; i < g.surf.size(); i += 3) g.pos[3 * (i + 1) + 2] -= 100 * h;
    const size_t n = g.surf.size();
    const SplatKernel k = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, h);
    ASSERT_EQ(k.offset.size(), n + 1);
    std::vector<double> out_weight(n, 0.0);
    for (size_t j = 0; j < n; ++j)
        for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) {
            const uint32_t s = k.source[e];
            out_weight[s] += k.weight[e];
            EXPECT_EQ(g.surf[s], g.surf[j]);                                 // same surface
            EXPECT_LE(std::fabs(g.pos[3 * s + 1] - g.pos[3 * j + 1]), 0.5f * h);  // same plane
        }
    for (size_t s = 0; s < n; ++s) EXPECT_NEAR(out_weight[s], 1.0, 1e-5);   // every amount conserved
    EXPECT_GT(k.mean_neighbours, 6.0);
    EXPECT_LT(k.mean_neighbours, 20.0);
}

TEST(Splat, BitIdenticalAcrossThreads) {
    Grid g = make_grid(30, 0.01f);
    const size_t n = g.surf.size();
    std::vector<float> in(n * 2);
    for (size_t i = 0; i < in.size(); ++i) in[i] = float((i * 7919) % 101) * 0.37f;
    std::vector<float> a(n * 2), b(n * 2);
    run_with_threads(1, [&] {
        const SplatKernel k = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, 0.01f);
        apply_splat(k, in.data(), a.data(), n, 2);
    });
    run_with_threads(2, [&] {
        const SplatKernel k = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, 0.01f);
        apply_splat(k, in.data(), b.data(), n, 2);
    });
    EXPECT_EQ(a, b);
    double sa = 0, si = 0;
    for (size_t i = 0; i < a.size(); ++i) { sa += a[i]; si += in[i]; }
    EXPECT_NEAR(sa, si, 1e-3 * si);
}

// The kernel is the rule of splat.h computed pair by pair, bit for bit, with
// the sources of every target in ascending order, at 1 and 3 threads: on
// 10,800 surfels in shuffled order, so every source's targets fall in
// several of the transposition's ranges of targets.
namespace {
// The kernel of g's n surfels (spacing h) against a reference that tests
// every pair in the float arithmetic splat.cpp does and transposes serially;
// at 1 and 3 threads.  Returns the largest neighbourhood.
size_t expect_kernel_is_every_neighbourhood_transposed(const Grid& g, size_t n, float h) {
    const float r = 2.0f * h, r2 = r * r;
    const double inv2s2 = 1.0 / (2.0 * double(h) * double(h));
    std::vector<std::vector<std::pair<uint32_t, float>>> into(n);   // per target: (source, weight)
    size_t largest = 0;
    for (size_t s = 0; s < n; ++s) {
        const float* ps = &g.pos[3 * s];
        const float* ns = &g.nrm[3 * s];
        std::vector<std::pair<uint32_t, double>> hood;   // ascending target
        for (size_t j = 0; j < n; ++j) {
            const float* pj = &g.pos[3 * j];
            float d2 = 0.0f;
            for (int c = 0; c < 3; ++c) {
                const float d = ps[c] - pj[c];
                d2 += d * d;
            }
            if (j != s) {
                if (!(d2 < r2) || g.surf[j] != g.surf[s]) continue;
                const float* nj = &g.nrm[3 * j];
                if (ns[0] * nj[0] + ns[1] * nj[1] + ns[2] * nj[2] < 0.5f) continue;
                const float off = (pj[0] - ps[0]) * ns[0] + (pj[1] - ps[1]) * ns[1] + (pj[2] - ps[2]) * ns[2];
                if (std::fabs(off) > 0.5f * h) continue;
            } else {
                d2 = 0.0f;
            }
            // The kernel weighs with the project's own single-precision exp, as the runtime does.
            hood.emplace_back(uint32_t(j), double(gm::exp(float(-double(d2) * inv2s2))));
        }
        largest = std::max(largest, hood.size());
        double sum = 0;
        for (const auto& e : hood) sum += e.second;
        for (const auto& e : hood) into[e.first].emplace_back(uint32_t(s), float(e.second / sum));
    }
    for (int threads : {1, 3}) {
        SplatKernel k;
        run_with_threads(threads, [&] { k = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, h); });
        EXPECT_EQ(k.offset.size(), n + 1) << threads;
        if (k.offset.size() != n + 1) return largest;
        EXPECT_EQ(k.offset[0], 0u);
        size_t entries = 0;
        for (size_t j = 0; j < n; ++j) {
            EXPECT_EQ(k.offset[j + 1] - k.offset[j], into[j].size()) << "target " << j << ", " << threads << " thread(s)";
            if (k.offset[j + 1] - k.offset[j] != into[j].size()) return largest;
            for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) {
                const auto& want = into[j][e - k.offset[j]];
                EXPECT_EQ(k.source[e], want.first);
                EXPECT_EQ(k.weight[e], want.second);
            }
            entries += into[j].size();
        }
        EXPECT_EQ(k.source.size(), entries);
    }
    return largest;
}
}  // namespace

TEST(Splat, GatherFormIsEveryNeighbourhoodTransposedAtAnyThreadCount) {
    const float h = 0.01f;
    const Grid g0 = make_grid(60, h);
    const size_t n = g0.surf.size();
    ASSERT_GT(n, size_t(2 * 4096));
    // the surfels shuffled: a source's neighbours lie far apart in index order
    std::vector<size_t> order(n);
    for (size_t i = 0; i < n; ++i) order[i] = (i * 7919) % n;   // 7919 is prime, n = 10,800 is not its multiple
    Grid g;
    for (size_t i : order) g.add(g0.pos[3 * i], g0.pos[3 * i + 1], g0.pos[3 * i + 2], g0.surf[i]);
    ASSERT_EQ(g.surf.size(), n);
    EXPECT_LE(expect_kernel_is_every_neighbourhood_transposed(g, n, h), 64u);
}

// Coincident sheets (the same grid ten times over on one surface): every
// neighbourhood holds ~130 surfels, more than the build orders by ranking
// (it sorts those), and the kernel is still every neighbourhood transposed.
TEST(Splat, CrowdedNeighbourhoodsAreOrderedLikeSparseOnes) {
    const float h = 0.01f;
    Grid g;
    for (int layer = 0; layer < 10; ++layer)
        for (int i = 0; i < 14; ++i)
            for (int j = 0; j < 14; ++j) g.add(float(i) * h, 0.0f, float(j) * h, 0);
    EXPECT_GT(expect_kernel_is_every_neighbourhood_transposed(g, g.surf.size(), h), 100u);
}

// Riding surfels keep their neighbourhoods (SPEC §13.12): reweighting at the
// positions the kernel was built with reproduces it bit for bit, and after a
// move every source's weights still sum to 1 with the Gaussian of the new
// distances.
TEST(Splat, ReweightingKeepsNeighbourhoodsAndConserves) {
    const float h = 0.1f;
    Grid g = make_grid(12, h);
    const size_t n = g.surf.size();
    SplatKernel k = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, h);
    SplatKernel same = k;
    reweight_splat_kernel(same, g.pos.data(), n, h);
    ASSERT_EQ(same.weight.size(), k.weight.size());
    for (size_t e = 0; e < k.weight.size(); ++e) ASSERT_EQ(same.weight[e], k.weight[e]) << e;
    // Stretch along x by 10 %: same neighbours, new weights.
    for (size_t i = 0; i < n; ++i) g.pos[3 * i] *= 1.1f;
    SplatKernel moved = k;
    reweight_splat_kernel(moved, g.pos.data(), n, h);
    EXPECT_EQ(moved.source, k.source);
    EXPECT_EQ(moved.offset, k.offset);
    std::vector<double> sum(n, 0.0);
    bool changed = false;
    for (size_t j = 0; j < n; ++j)
        for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) {
            sum[k.source[e]] += moved.weight[e];
            changed = changed || moved.weight[e] != k.weight[e];
        }
    EXPECT_TRUE(changed);
    for (size_t s = 0; s < n; ++s) EXPECT_NEAR(sum[s], 1.0, 1e-5) << s;
}

// After a local re-tiling (SPEC §13.12) only the neighbourhoods near the
// replaced surfels are computed afresh: where the kept surfels did not move,
// that is exactly the kernel built from scratch; with nothing replaced it is
// exactly the riding kernel (reweighting); and the same at 1 and 2 threads.
TEST(Splat, LocalUpdateMatchesAFreshBuildWhereNothingElseMoved) {
    const float h = 0.1f;
    Grid g = make_grid(14, h);
    const size_t n = g.surf.size();
    for (size_t i = 0; i < n; ++i) {   // a little jitter: distinct distances
        g.pos[3 * i] += 0.13f * h * float((i * 7919) % 17) / 17.0f;
        g.pos[3 * i + 2] += 0.11f * h * float((i * 104729) % 13) / 13.0f;
    }
    const SplatKernel before = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, h);
    // Replace the surfels of a patch (x in [4h, 7h]) by others at new places,
    // one of them on the other surface and tilted.
    std::vector<uint32_t> replaced;
    for (size_t i = 0; i < n; ++i)
        if (g.pos[3 * i] >= 4 * h && g.pos[3 * i] <= 7 * h && g.pos[3 * i + 2] < 20 * h) replaced.push_back(uint32_t(i));
    ASSERT_GT(replaced.size(), 10u);
    ASSERT_LT(replaced.size(), n / 4);
    for (size_t k = 0; k < replaced.size(); ++k) {
        const size_t i = replaced[k];
        g.pos[3 * i] += 0.37f * h;
        g.pos[3 * i + 2] -= 0.29f * h;
    }
    g.surf[replaced[0]] = 1 - g.surf[replaced[0]];
    g.nrm[3 * replaced[1]] = 0.6f, g.nrm[3 * replaced[1] + 1] = 0.8f;
    const SplatKernel fresh = build_splat_kernel(g.pos.data(), g.nrm.data(), g.surf.data(), n, h);
    SplatKernel local[2];
    for (int t = 0; t < 2; ++t)
        run_with_threads(t + 1, [&] {
            local[t] = update_splat_kernel(before, g.pos.data(), g.nrm.data(), g.surf.data(), n, h, replaced);
        });
    EXPECT_NE(fresh.source, before.source);   // the replacement changed neighbourhoods
    for (int t = 0; t < 2; ++t) {
        EXPECT_EQ(local[t].offset, fresh.offset);
        EXPECT_EQ(local[t].source, fresh.source);
        EXPECT_EQ(local[t].weight, fresh.weight);
    }
    // Nothing replaced, every surfel moved: the riding kernel.
    for (size_t i = 0; i < n; ++i) g.pos[3 * i] *= 1.05f;
    SplatKernel riding = fresh;
    reweight_splat_kernel(riding, g.pos.data(), n, h);
    const SplatKernel kept = update_splat_kernel(fresh, g.pos.data(), g.nrm.data(), g.surf.data(), n, h, {});
    EXPECT_EQ(kept.offset, riding.offset);
    EXPECT_EQ(kept.source, riding.source);
    EXPECT_EQ(kept.weight, riding.weight);
}
