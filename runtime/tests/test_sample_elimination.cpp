// The parallel sample elimination (surfels.cpp) against the serial reference
// it replaced: the same candidates kept, bit for bit, at every thread count,
// including point sets with exact ties (a regular grid) and duplicates.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "gamma/philox.h"
#include "gamma/surfels.h"
#include "gamma/threads.h"
#include "helpers.h"

using namespace gammart;

namespace {

// The serial elimination as it was before it was parallelised: grid of cells
// of side 2 r_max, points ranked by (x, y, z) cell key, full neighbour lists
// in rank order, an indexed binary max-heap on (weight, rank).
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

void expect_same_as_reference(const std::vector<float>& pts, size_t keep, double r_max) {
    const std::vector<uint32_t> ref = sorted(reference_eliminate(pts, keep, r_max));
    ASSERT_EQ(ref.size(), keep);
    for (int threads : {1, 2, 4}) EXPECT_EQ(eliminate_at(threads, pts, keep, r_max), ref) << threads << " threads";
}

}  // namespace

TEST(SampleElimination, RandomPointsInAVolumeMatchTheSerialReference) {
    std::vector<float> pts;
    const std::array<uint32_t, 2> key{5, 6};
    for (uint32_t i = 0; i < 20000; ++i) {
        const Philox4 r = philox4x32_10({i, 0, 0, 0}, key);
        for (int k = 0; k < 3; ++k) pts.push_back(u01(r[size_t(k)]));
    }
    expect_same_as_reference(pts, 4000, 0.02);
}

TEST(SampleElimination, SurfaceCandidatesMatchTheSerialReference) {
    // Candidates on a sphere (a surface crossing cells at every angle), many
    // cells per parallel work item and many work items.
    std::vector<float> pts;
    const std::array<uint32_t, 2> key{7, 8};
    for (uint32_t i = 0; i < 60000; ++i) {
        const Philox4 r = philox4x32_10({i, 1, 0, 0}, key);
        const double z = 2.0 * u01(r[0]) - 1.0, phi = 6.283185307179586 * u01(r[1]);
        const double s = std::sqrt(std::max(0.0, 1.0 - z * z));
        pts.push_back(float(s * std::cos(phi)));
        pts.push_back(float(s * std::sin(phi)));
        pts.push_back(float(z));
    }
    const size_t keep = 12000;
    expect_same_as_reference(pts, keep, std::sqrt(4.0 * 3.141592653589793 / (2.0 * std::sqrt(3.0) * keep)));
}

TEST(SampleElimination, GridTiesAndDuplicatesMatchTheSerialReference) {
    // A regular grid: equal weights everywhere, decided by the rank; every
    // tenth point doubled (a neighbour at distance 0).
    std::vector<float> pts;
    for (int i = 0; i < 3000; ++i) {
        const float p[3] = {float(i % 50) * 0.01f, float((i / 50) % 60) * 0.01f, 0.0f};
        pts.insert(pts.end(), p, p + 3);
        if (i % 10 == 0) pts.insert(pts.end(), p, p + 3);
    }
    expect_same_as_reference(pts, 700, 0.012);
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
