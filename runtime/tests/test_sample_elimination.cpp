// The mesh sampler and the tiled sample elimination (surfels.cpp): exactly the requested count,
// the same candidates at every thread count (also with exact ties and
// duplicates), and blue-noise quality measured against the serial algorithm
// it replaced (Yuksel's elimination, one candidate at a time in weight order),
// kept here as the reference.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <string>
#include <unordered_map>

#include "gamma/philox.h"
#include "gamma/surfels.h"
#include "gamma/threads.h"
#include "helpers.h"

using namespace gammart;

namespace {

// The serial elimination as it was before it was tiled: grid of cells of side
// 2 r_max, points ranked by (x, y, z) cell key, full neighbour lists in rank
// order, an indexed binary max-heap on (weight, rank).
std::vector<uint32_t> reference_eliminate(const std::vector<float>& pts, size_t keep, double r_max) {
    const size_t m = pts.size() / 3;
    std::vector<uint32_t> kept;
    if (keep >= m) {
        for (size_t i = 0; i < m; ++i) kept.push_back(uint32_t(i));
        return kept;
    }
    const double r2 = 2.0 * r_max;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < m; ++i)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], double(pts[3 * i + k]));
            hi[k] = std::max(hi[k], double(pts[3 * i + k]));
        }
    double cell = r2;
    for (int k = 0; k < 3; ++k) cell = std::max(cell, (hi[k] - lo[k]) / 1.0e6);
    if (!(cell > 0)) cell = 1.0;
    auto cell_of = [&](size_t i, int k) { return int64_t((pts[3 * i + k] - lo[k]) / cell); };
    auto key_of = [](int64_t x, int64_t y, int64_t z) {
        return (uint64_t(x) << 42) | (uint64_t(y) << 21) | uint64_t(z);
    };
    std::vector<std::pair<uint64_t, uint32_t>> order(m);
    for (size_t i = 0; i < m; ++i) order[i] = {key_of(cell_of(i, 0), cell_of(i, 1), cell_of(i, 2)), uint32_t(i)};
    std::sort(order.begin(), order.end());
    std::vector<float> sp(3 * m);
    for (size_t a = 0; a < m; ++a)
        for (int k = 0; k < 3; ++k) sp[3 * a + k] = pts[3 * size_t(order[a].second) + k];
    std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> cells;
    for (size_t a = 0; a < m;) {
        size_t b = a;
        while (b < m && order[b].first == order[a].first) ++b;
        cells[order[a].first] = {uint32_t(a), uint32_t(b)};
        a = b;
    }
    auto weight = [&](size_t i, size_t j) {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) {
            double d = double(sp[3 * i + k]) - sp[3 * j + k];
            d2 += d * d;
        }
        double t = 1.0 - std::sqrt(d2) * (1.0 / r2);
        t = t * t;
        t = t * t;
        return t * t;
    };
    std::vector<std::vector<uint32_t>> nbr(m);
    std::vector<double> w(m, 0.0);
    for (size_t i = 0; i < m; ++i) {
        const uint64_t key = order[i].first;
        const int64_t cx = int64_t(key >> 42), cy = int64_t((key >> 21) & 0x1fffff), cz = int64_t(key & 0x1fffff);
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy)
                for (int64_t dz = -1; dz <= 1; ++dz) {
                    if (cx + dx < 0 || cy + dy < 0 || cz + dz < 0) continue;
                    auto it = cells.find(key_of(cx + dx, cy + dy, cz + dz));
                    if (it == cells.end()) continue;
                    for (uint32_t j = it->second.first; j < it->second.second; ++j) {
                        if (j == i) continue;
                        double d2 = 0;
                        for (int k = 0; k < 3; ++k) {
                            const double d = double(sp[3 * i + k]) - sp[3 * size_t(j) + k];
                            d2 += d * d;
                        }
                        if (d2 < r2 * r2) nbr[i].push_back(j);
                    }
                }
        for (uint32_t j : nbr[i]) w[i] += weight(i, j);
    }
    // Indexed binary max-heap on (weight, rank).
    std::vector<uint32_t> heap(m), pos(m);
    auto less = [&](uint32_t a, uint32_t b) { return w[a] < w[b] || (w[a] == w[b] && a < b); };
    size_t n = m;
    auto down = [&](size_t i) {
        const uint32_t item = heap[i];
        for (;;) {
            size_t c = 2 * i + 1;
            if (c >= n) break;
            if (c + 1 < n && less(heap[c], heap[c + 1])) ++c;
            if (!less(item, heap[c])) break;
            heap[i] = heap[c];
            pos[heap[i]] = uint32_t(i);
            i = c;
        }
        heap[i] = item;
        pos[item] = uint32_t(i);
    };
    for (size_t i = 0; i < m; ++i) heap[i] = pos[i] = uint32_t(i);
    for (size_t i = m / 2; i-- > 0;) down(i);
    std::vector<bool> gone(m, false);
    for (size_t left = m; left > keep; --left) {
        const uint32_t i = heap[0];
        gone[i] = true;
        heap[0] = heap[--n];
        if (n) down(0);
        for (uint32_t j : nbr[i])
            if (!gone[j]) {
                w[j] -= weight(j, i);
                down(pos[j]);
            }
    }
    for (size_t a = 0; a < m; ++a)
        if (!gone[a]) kept.push_back(order[a].second);
    return kept;
}

std::vector<uint32_t> sorted(std::vector<uint32_t> v) {
    std::sort(v.begin(), v.end());
    return v;
}

std::vector<uint32_t> eliminate_at(int threads, const std::vector<float>& pts, size_t keep, double r_max) {
    std::vector<uint32_t> kept;
    run_with_threads(threads, [&] { kept = eliminate_samples(pts, keep, r_max); });
    return sorted(kept);
}

// Exactly `keep` distinct candidates, the same at 1, 2 and 4 threads.
std::vector<uint32_t> expect_exact_and_thread_count_free(const std::vector<float>& pts, size_t keep, double r_max) {
    const std::vector<uint32_t> one = eliminate_at(1, pts, keep, r_max);
    EXPECT_EQ(one.size(), keep);
    EXPECT_TRUE(std::adjacent_find(one.begin(), one.end()) == one.end()) << "a candidate kept twice";
    if (!one.empty()) {
        EXPECT_LT(one.back(), pts.size() / 3);
    }
    for (int threads : {2, 4}) EXPECT_EQ(eliminate_at(threads, pts, keep, r_max), one) << threads << " threads";
    return one;
}

// Blue-noise figures of a kept set, in units of r_max (Yuksel's maximal
// Poisson-disk radius for that many points on that area: hexagonal packing
// has every nearest neighbour at 2 r_max): the smallest and the mean
// distance from a kept point to its nearest kept neighbour, and coverage,
// the largest distance from any candidate (the candidates cover the surface
// densely) to its nearest kept point, i.e. the largest hole.
struct BlueNoise {
    double min_nn, mean_nn, max_hole;
};

BlueNoise blue_noise(const std::vector<float>& pts, const std::vector<uint32_t>& kept, double r_max) {
    const double cell = 2.0 * r_max;
    auto key = [&](int64_t x, int64_t y, int64_t z) {
        return (uint64_t(x + (1 << 20)) << 42) | (uint64_t(y + (1 << 20)) << 21) | uint64_t(z + (1 << 20));
    };
    auto coord = [&](const float* p, int k) { return int64_t(std::floor(double(p[k]) / cell)); };
    std::unordered_map<uint64_t, std::vector<uint32_t>> grid;
    for (const uint32_t i : kept) grid[key(coord(&pts[3 * i], 0), coord(&pts[3 * i], 1), coord(&pts[3 * i], 2))].push_back(i);
    // Nearest kept point to p (other than `self`): rings of cells until the
    // best found is closer than the ring's inner distance.
    auto nearest = [&](const float* p, uint32_t self) {
        double best = INFINITY;
        const int64_t c[3] = {coord(p, 0), coord(p, 1), coord(p, 2)};
        for (int64_t ring = 0; ring < 64 && !(std::sqrt(best) <= double(ring - 1) * cell); ++ring)
            for (int64_t dx = -ring; dx <= ring; ++dx)
                for (int64_t dy = -ring; dy <= ring; ++dy)
                    for (int64_t dz = -ring; dz <= ring; ++dz) {
                        if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != ring) continue;
                        auto it = grid.find(key(c[0] + dx, c[1] + dy, c[2] + dz));
                        if (it == grid.end()) continue;
                        for (const uint32_t j : it->second) {
                            if (j == self) continue;
                            double d2 = 0;
                            for (int k = 0; k < 3; ++k) {
                                const double d = double(p[k]) - pts[3 * size_t(j) + k];
                                d2 += d * d;
                            }
                            best = std::min(best, d2);
                        }
                    }
        return std::sqrt(best) / r_max;
    };
    BlueNoise b{INFINITY, 0.0, 0.0};
    for (const uint32_t i : kept) {
        const double d = nearest(&pts[3 * i], i);
        b.min_nn = std::min(b.min_nn, d);
        b.mean_nn += d / double(kept.size());
    }
    for (size_t i = 0; i < pts.size() / 3; ++i) b.max_hole = std::max(b.max_hole, nearest(&pts[3 * i], UINT32_MAX));
    return b;
}

// The tiled elimination's blue noise against the serial algorithm's on the
// same candidates: the closest pair no more than 3 % closer, the mean
// nearest-neighbour distance within 1 %, the largest hole no more than 5 %
// larger.  (Keeping a random subset instead gives a closest pair more than
// 100 times closer; the serial algorithm itself reaches ~1.27 r_max, ~1.5
// r_max and ~1.9 r_max on these sets; cutting the passes' bands 4 times
// coarser already misses the 1 % on the mean.)
void expect_blue_noise_like_serial(const std::vector<float>& pts, size_t keep, double r_max) {
    const std::vector<uint32_t> ref = sorted(reference_eliminate(pts, keep, r_max));
    const std::vector<uint32_t> got = expect_exact_and_thread_count_free(pts, keep, r_max);
    const BlueNoise r = blue_noise(pts, ref, r_max), g = blue_noise(pts, got, r_max);
    std::printf("[ info ] in r_max, serial / tiled: closest pair %.4f / %.4f, mean nearest %.4f / %.4f, "
                "largest hole %.4f / %.4f\n", r.min_nn, g.min_nn, r.mean_nn, g.mean_nn, r.max_hole, g.max_hole);
    EXPECT_GE(g.min_nn, 0.97 * r.min_nn);
    EXPECT_GE(g.mean_nn, 0.99 * r.mean_nn);
    EXPECT_LE(g.max_hole, 1.05 * r.max_hole);
}

std::vector<float> sphere_candidates(uint32_t count, uint32_t stream) {
    std::vector<float> pts;
    const std::array<uint32_t, 2> key{7, 8};
    for (uint32_t i = 0; i < count; ++i) {
        const Philox4 r = philox4x32_10({i, stream, 0, 0}, key);
        const double z = 2.0 * u01(r[0]) - 1.0, phi = 6.283185307179586 * u01(r[1]);
        const double s = std::sqrt(std::max(0.0, 1.0 - z * z));
        pts.push_back(float(s * std::cos(phi)));
        pts.push_back(float(s * std::sin(phi)));
        pts.push_back(float(z));
    }
    return pts;
}

double r_max_for(double area, size_t keep) { return std::sqrt(area / (2.0 * std::sqrt(3.0) * double(keep))); }

}  // namespace

TEST(SampleElimination, RandomPointsInAVolumeAreThreadCountFree) {
    std::vector<float> pts;
    const std::array<uint32_t, 2> key{5, 6};
    for (uint32_t i = 0; i < 20000; ++i) {
        const Philox4 r = philox4x32_10({i, 0, 0, 0}, key);
        for (int k = 0; k < 3; ++k) pts.push_back(u01(r[size_t(k)]));
    }
    expect_exact_and_thread_count_free(pts, 4000, 0.02);
}

TEST(SampleElimination, SphereKeepsTheSerialBlueNoise) {
    // Candidates on a sphere (a surface crossing cells at every angle), 5 per
    // point kept, as the mesh sampling uses.
    const size_t keep = 12000;
    expect_blue_noise_like_serial(sphere_candidates(5 * keep, 1), keep, r_max_for(4.0 * 3.141592653589793, keep));
}

TEST(SampleElimination, FlatSquareKeepsTheSerialBlueNoise) {
    // A unit square with 5 candidates per point kept.
    const size_t keep = 8000;
    std::vector<float> pts;
    const std::array<uint32_t, 2> key{9, 10};
    for (uint32_t i = 0; i < 5 * keep; ++i) {
        const Philox4 r = philox4x32_10({i, 2, 0, 0}, key);
        pts.push_back(u01(r[0]));
        pts.push_back(u01(r[1]));
        pts.push_back(0.0f);
    }
    expect_blue_noise_like_serial(pts, keep, r_max_for(1.0, keep));
}

TEST(SampleElimination, GridTiesAndDuplicatesAreThreadCountFree) {
    // A regular grid: equal weights everywhere, decided by the rank; every
    // tenth point doubled (a neighbour at distance 0).
    std::vector<float> pts;
    for (int i = 0; i < 3000; ++i) {
        const float p[3] = {float(i % 50) * 0.01f, float((i / 50) % 60) * 0.01f, 0.0f};
        pts.insert(pts.end(), p, p + 3);
        if (i % 10 == 0) pts.insert(pts.end(), p, p + 3);
    }
    const std::vector<uint32_t> kept = expect_exact_and_thread_count_free(pts, 700, 0.012);
    // No duplicate pair survives while a single point is left to remove.
    size_t doubled = 0;
    for (size_t a = 0; a + 1 < kept.size(); ++a)
        for (size_t b = a + 1; b < kept.size(); ++b)
            if (std::equal(&pts[3 * size_t(kept[a])], &pts[3 * size_t(kept[a])] + 3, &pts[3 * size_t(kept[b])])) ++doubled;
    EXPECT_EQ(doubled, 0u);
}

TEST(SampleElimination, FewCandidatesAndFewRemovals) {
    // Below the tiled passes' range: the serial rule does every removal, and
    // the result is the serial algorithm's bit for bit.
    const std::vector<float> pts = sphere_candidates(2000, 3);
    const size_t keep = 1960;
    const double r_max = r_max_for(4.0 * 3.141592653589793, keep);
    EXPECT_EQ(expect_exact_and_thread_count_free(pts, keep, r_max), sorted(reference_eliminate(pts, keep, r_max)));
    EXPECT_EQ(eliminate_at(2, pts, 2000, r_max).size(), 2000u);
    EXPECT_EQ(eliminate_at(2, pts, 5000, r_max).size(), 2000u);
    EXPECT_EQ(eliminate_at(2, pts, 1, r_max).size(), 1u);
}

TEST(SampleElimination, MeshSamplingIsThreadCountFree) {
    const Mesh m = gamma_test::icosphere(3);
    SurfelSet one, two;
    run_with_threads(1, [&] { one = sample_surfels(m, 8000, 21); });
    run_with_threads(2, [&] { two = sample_surfels(m, 8000, 21); });
    EXPECT_EQ(one.position, two.position);
    EXPECT_EQ(one.normal, two.normal);
    EXPECT_EQ(one.triangle, two.triangle);
}

namespace {

// sample_surfels (two greedy Poisson-disk passes over its candidates) against
// the serial weighted elimination of the same candidates, which it replaced
// as the mesh sampler, with the bounds the tiled elimination is held to
// above: the closest pair no more than 3 % closer, the mean nearest-neighbour
// distance within 1 %, the largest hole no more than 5 % larger (holes
// measured from every candidate).  Also: exactly n surfels, each one of the
// candidates and on that candidate's triangle, the same at 1, 2 and 4
// threads.
void expect_surfels_like_serial(const Mesh& mesh, size_t n, uint64_t seed) {
    const SurfelCandidates cand = surfel_candidates(mesh, n, seed);
    ASSERT_EQ(cand.position.size(), 3 * 5 * n);
    SurfelSet s;
    run_with_threads(1, [&] { s = sample_surfels(mesh, n, seed); });
    ASSERT_EQ(s.triangle.size(), n);
    ASSERT_EQ(s.position.size(), 3 * n);
    for (int threads : {2, 4}) {
        SurfelSet other;
        run_with_threads(threads, [&] { other = sample_surfels(mesh, n, seed); });
        EXPECT_EQ(other.position, s.position) << threads << " threads";
        EXPECT_EQ(other.triangle, s.triangle) << threads << " threads";
    }
    const double r_max = r_max_for(cand.area, n);
    EXPECT_DOUBLE_EQ(s.r_max, r_max);
    std::map<std::array<float, 3>, std::vector<int32_t>> triangles_at;
    for (size_t i = 0; i < cand.triangle.size(); ++i)
        triangles_at[{cand.position[3 * i], cand.position[3 * i + 1], cand.position[3 * i + 2]}].push_back(cand.triangle[i]);
    std::set<std::array<float, 3>> seen;
    size_t not_candidates = 0;
    for (size_t a = 0; a < n; ++a) {
        const std::array<float, 3> p{s.position[3 * a], s.position[3 * a + 1], s.position[3 * a + 2]};
        auto it = triangles_at.find(p);
        if (it == triangles_at.end() ||
            std::find(it->second.begin(), it->second.end(), s.triangle[a]) == it->second.end())
            ++not_candidates;
        seen.insert(p);
    }
    EXPECT_EQ(not_candidates, 0u);
    EXPECT_EQ(seen.size(), n) << "a position kept twice";
    // The surfels' blue noise on the candidates followed by the surfels
    // (each surfel's own copy is not among the kept, so it takes no part but
    // as a place whose hole is 0).
    std::vector<float> pts = cand.position;
    pts.insert(pts.end(), s.position.begin(), s.position.end());
    std::vector<uint32_t> surfels(n);
    for (size_t a = 0; a < n; ++a) surfels[a] = uint32_t(5 * n + a);
    const BlueNoise r = blue_noise(cand.position, sorted(reference_eliminate(cand.position, n, r_max)), r_max);
    const BlueNoise g = blue_noise(pts, surfels, r_max);
    std::printf("[ info ] in r_max, serial elimination / surfels: closest pair %.4f / %.4f, mean nearest %.4f / %.4f, "
                "largest hole %.4f / %.4f\n", r.min_nn, g.min_nn, r.mean_nn, g.mean_nn, r.max_hole, g.max_hole);
    EXPECT_GE(g.min_nn, 0.97 * r.min_nn);
    EXPECT_GE(g.mean_nn, 0.99 * r.mean_nn);
    EXPECT_LE(g.max_hole, 1.05 * r.max_hole);
}

}  // namespace

TEST(SampleElimination, BunnySurfelsKeepTheSerialBlueNoise) {
    expect_surfels_like_serial(Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj"), 20000, 5);
}

TEST(SampleElimination, SphereAndSquareSurfelsKeepTheSerialBlueNoise) {
    expect_surfels_like_serial(gamma_test::icosphere(3), 8000, 21);
    expect_surfels_like_serial(gamma_test::unit_square(), 4000, 3);
}

TEST(SampleElimination, FewSurfelsAreExactAndThreadCountFree) {
    // Down to a single surfel on a coarse sphere (where the disk passes can
    // fall short and the weighted elimination picks them).
    const Mesh m = gamma_test::icosphere(1);
    for (size_t n = 1; n <= 40; ++n) {
        SurfelSet one, two;
        run_with_threads(1, [&] { one = sample_surfels(m, n, 9); });
        run_with_threads(2, [&] { two = sample_surfels(m, n, 9); });
        ASSERT_EQ(one.triangle.size(), n);
        EXPECT_EQ(one.position, two.position) << n;
        std::set<std::array<float, 3>> distinct;
        for (size_t a = 0; a < n; ++a) distinct.insert({one.position[3 * a], one.position[3 * a + 1], one.position[3 * a + 2]});
        EXPECT_EQ(distinct.size(), n);
    }
}

TEST(SampleElimination, StackedSheetsFallBackOnTheWeightedElimination) {
    // Eight unit squares 0.001 apart: in 3D the disk passes see one square's
    // worth of room for eight squares' worth of surfels and fall short, so
    // the weighted elimination of the same candidates picks them.
    std::vector<float> v;
    std::vector<int32_t> t;
    for (int k = 0; k < 8; ++k) {
        const float z = 0.001f * float(k);
        const float corners[12] = {0, 0, z, 1, 0, z, 1, 1, z, 0, 1, z};
        const int32_t base = int32_t(v.size() / 3);
        v.insert(v.end(), corners, corners + 12);
        const int32_t tris[6] = {base, base + 1, base + 2, base, base + 2, base + 3};
        t.insert(t.end(), tris, tris + 6);
    }
    const Mesh m = Mesh::from_arrays(v.data(), v.size() / 3, t.data(), t.size() / 3);
    const size_t n = 2000;
    SurfelSet one, two;
    run_with_threads(1, [&] { one = sample_surfels(m, n, 4); });
    run_with_threads(2, [&] { two = sample_surfels(m, n, 4); });
    ASSERT_EQ(one.triangle.size(), n);
    EXPECT_EQ(one.position, two.position);
    const SurfelCandidates cand = surfel_candidates(m, n, 4);
    std::set<std::array<float, 3>> expected, got;
    for (const uint32_t i : eliminate_samples(cand.position, n, r_max_for(cand.area, n)))
        expected.insert({cand.position[3 * i], cand.position[3 * i + 1], cand.position[3 * i + 2]});
    for (size_t a = 0; a < n; ++a) got.insert({one.position[3 * a], one.position[3 * a + 1], one.position[3 * a + 2]});
    EXPECT_EQ(got, expected);
}

namespace {

// The disk passes' serial rule, literally (surfels.cpp): the points in the
// order of (Philox hash of the index, index); the first pass keeps each
// point no kept point is closer to than 1.40 r_max; the second, from 1.28
// r_max down by 0.02 while it falls short, keeps each point that no point
// of either pass is closer to than that, until `keep` are kept.  Distances
// by brute force, in double, as the sampler measures them.  `steps` is set
// to the second pass's tries beyond the first.
std::vector<uint32_t> reference_disk_sample(const std::vector<float>& pts, size_t keep, double r_max, uint64_t seed,
                                            int& steps) {
    const size_t m = pts.size() / 3;
    const std::array<uint32_t, 2> key{uint32_t(seed), uint32_t(seed >> 32)};
    std::vector<std::pair<uint64_t, uint32_t>> order(m);
    for (uint32_t i = 0; i < m; ++i)
        order[i] = {(uint64_t(philox4x32_10({kSamplingIteration, i, 1, 0}, key)[0]) << 32) | i, i};
    std::sort(order.begin(), order.end());
    auto dist2 = [&](uint32_t a, uint32_t b) {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double d = double(pts[3 * size_t(a) + k]) - pts[3 * size_t(b) + k];
            d2 += d * d;
        }
        return d2;
    };
    auto clear_of = [&](uint32_t i, const std::vector<uint32_t>& kept, double radius2) {
        for (const uint32_t k : kept)
            if (dist2(i, k) < radius2) return false;
        return true;
    };
    std::vector<uint32_t> first;
    const double wide = 1.40 * r_max;
    for (const auto& o : order)
        if (clear_of(o.second, first, wide * wide)) first.push_back(o.second);
    steps = 0;
    if (first.size() >= keep) return std::vector<uint32_t>(first.begin(), first.begin() + std::ptrdiff_t(keep));
    std::vector<bool> in_first(m, false);
    for (const uint32_t i : first) in_first[i] = true;
    for (int step = 0;; ++step) {
        const double narrow = (1.28 - step * 0.02) * r_max;
        if (narrow < 1.0 * r_max) return {};
        steps = step;
        std::vector<uint32_t> kept = first;
        for (const auto& o : order) {
            if (kept.size() == keep) return kept;
            if (!in_first[o.second] && clear_of(o.second, kept, narrow * narrow)) kept.push_back(o.second);
        }
        if (kept.size() == keep) return kept;
    }
}

// poisson_disk_sample against the serial rule, at 1 and 2 threads, with the
// neighbour lists in the space reserved and packed again (1 entry reserved
// per point: nearly every block's lists spill), their filter in its SSE2
// form and (where the CPU has it) its AVX-512 form.
void expect_disk_passes_serial(const std::vector<float>& pts, size_t keep, double r_max, uint64_t seed, int& steps) {
    const std::vector<uint32_t> expected = sorted(reference_disk_sample(pts, keep, r_max, seed, steps));
    ASSERT_EQ(expected.size(), keep);
    for (int threads : {1, 2})
        for (size_t capacity : {size_t(12), size_t(1)})
            for (bool avx512 : {true, false}) {
                std::vector<uint32_t> got;
                run_with_threads(threads, [&] { got = poisson_disk_sample(pts, keep, r_max, seed, capacity, avx512); });
                EXPECT_EQ(sorted(got), expected)
                    << threads << " threads, " << capacity << " entries per point, AVX-512 allowed: " << avx512;
            }
}

}  // namespace

TEST(SampleElimination, DiskPassesAreTheSerialRule) {
    int steps = 0;
    const Mesh bunny = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    const SurfelCandidates b = surfel_candidates(bunny, 2000, 5);
    expect_disk_passes_serial(b.position, 2000, r_max_for(b.area, 2000), 5, steps);
    const SurfelCandidates s = surfel_candidates(gamma_test::icosphere(3), 1500, 21);
    expect_disk_passes_serial(s.position, 1500, r_max_for(s.area, 1500), 21, steps);
    // A coarse mesh whose second pass falls short at 1.28 r_max and is
    // redone narrower (the lists' narrow flags hold for the first try only).
    const Mesh teapot = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/teapot.obj");
    const SurfelCandidates t = surfel_candidates(teapot, 300, 2);
    expect_disk_passes_serial(t.position, 300, r_max_for(t.area, 300), 2, steps);
    EXPECT_GT(steps, 0);
    // Two spheres 100 apart in y and z: a table over the cells' (y, z)
    // would hold far more entries than there are points, so the rows of
    // cells are found through the hash map instead.
    const SurfelCandidates one = surfel_candidates(gamma_test::icosphere(3), 150, 7);
    std::vector<float> two = one.position;
    for (size_t i = 0; i < one.position.size(); i += 3)
        two.insert(two.end(), {one.position[i], one.position[i + 1] + 100.0f, one.position[i + 2] + 100.0f});
    expect_disk_passes_serial(two, 300, r_max_for(2.0 * one.area, 300), 7, steps);
}
