#include "gamma/surfels.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "gamma/error.h"
#include "gamma/philox.h"

namespace gammart {

namespace {

// Indexed binary max-heap over weights (ties: larger index first; any fixed
// rule keeps the elimination deterministic).
class IndexedMaxHeap {
public:
    explicit IndexedMaxHeap(const std::vector<double>& w) : w_(w) {
        const size_t n = w.size();
        heap_.resize(n);
        pos_.resize(n);
        for (size_t i = 0; i < n; ++i) { heap_[i] = uint32_t(i); pos_[i] = uint32_t(i); }
        for (size_t i = n / 2; i-- > 0;) down(i);
    }
    bool empty() const { return heap_.empty(); }
    uint32_t top() const { return heap_[0]; }
    void pop() {
        uint32_t last = heap_.back();
        pos_[heap_[0]] = kRemoved;
        heap_.pop_back();
        if (!heap_.empty()) {
            heap_[0] = last;
            pos_[last] = 0;
            down(0);
        }
    }
    bool contains(uint32_t i) const { return pos_[i] != kRemoved; }
    // Weight of i decreased (caller changed w_[i]).
    void decreased(uint32_t i) { down(pos_[i]); }

private:
    static constexpr uint32_t kRemoved = 0xFFFFFFFFu;
    bool less(uint32_t a, uint32_t b) const {  // a has lower priority than b
        return w_[a] < w_[b] || (w_[a] == w_[b] && a < b);
    }
    void down(size_t i) {
        const size_t n = heap_.size();
        uint32_t item = heap_[i];
        for (;;) {
            size_t c = 2 * i + 1;
            if (c >= n) break;
            if (c + 1 < n && less(heap_[c], heap_[c + 1])) ++c;
            if (!less(item, heap_[c])) break;
            heap_[i] = heap_[c];
            pos_[heap_[i]] = uint32_t(i);
            i = c;
        }
        heap_[i] = item;
        pos_[item] = uint32_t(i);
    }
    const std::vector<double>& w_;
    std::vector<uint32_t> heap_, pos_;
};

inline uint64_t expand_bits21(uint64_t v) {
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
}

}  // namespace

std::vector<uint32_t> eliminate_samples(const std::vector<float>& pts, size_t keep, double r_max) {
    const size_t m = pts.size() / 3;
    std::vector<uint32_t> kept;
    if (keep >= m) {
        for (size_t i = 0; i < m; ++i) kept.push_back(uint32_t(i));
        return kept;
    }
    const double r2 = 2.0 * r_max;  // neighbourhood radius
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
    // Sort points by cell key and work on a copy in that order, so that the
    // points of a cell (and of neighbouring z-cells) are contiguous in memory.
    std::vector<std::pair<uint64_t, uint32_t>> order(m);
    for (size_t i = 0; i < m; ++i)
        order[i] = {key_of(cell_of(i, 0), cell_of(i, 1), cell_of(i, 2)), uint32_t(i)};
    std::sort(order.begin(), order.end());
    std::vector<float> sp(3 * m);
    for (size_t a = 0; a < m; ++a)
        for (int k = 0; k < 3; ++k) sp[3 * a + k] = pts[3 * size_t(order[a].second) + k];
    struct Cell { uint64_t key; uint32_t begin, end; };
    std::vector<Cell> cell_list;
    std::unordered_map<uint64_t, uint32_t> cells;  // key -> index in cell_list
    cells.reserve(m);
    for (size_t a = 0; a < m;) {
        size_t b = a;
        while (b < m && order[b].first == order[a].first) ++b;
        cells.emplace(order[a].first, uint32_t(cell_list.size()));
        cell_list.push_back({order[a].first, uint32_t(a), uint32_t(b)});
        a = b;
    }
    // Neighbour lists (CSR, in sorted index space) and initial weights.
    std::vector<uint64_t> offs(m + 1, 0);
    std::vector<uint32_t> nbr;
    nbr.reserve(m * 24);
    std::vector<double> w(m, 0.0);
    const double r2sq = r2 * r2;
    const double inv_r2 = 1.0 / r2;
    auto weight = [&](uint32_t i, uint32_t j) {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) {
            double d = double(sp[3 * size_t(i) + k]) - sp[3 * size_t(j) + k];
            d2 += d * d;
        }
        double t = 1.0 - std::sqrt(d2) * inv_r2;
        t = t * t;  // ^2
        t = t * t;  // ^4
        return t * t;  // ^8
    };
    std::vector<std::pair<uint32_t, uint32_t>> ranges;
    for (const Cell& cl : cell_list) {
        const int64_t cx = int64_t(cl.key >> 42), cy = int64_t((cl.key >> 21) & 0x1fffff),
                      cz = int64_t(cl.key & 0x1fffff);
        ranges.clear();
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy)
                for (int64_t dz = -1; dz <= 1; ++dz) {
                    if (cx + dx < 0 || cy + dy < 0 || cz + dz < 0) continue;
                    auto it = cells.find(key_of(cx + dx, cy + dy, cz + dz));
                    if (it == cells.end()) continue;
                    const Cell& nc = cell_list[it->second];
                    ranges.emplace_back(nc.begin, nc.end);
                }
        for (uint32_t i = cl.begin; i < cl.end; ++i) {
            const float px = sp[3 * size_t(i)], py = sp[3 * size_t(i) + 1], pz = sp[3 * size_t(i) + 2];
            for (const auto& rg : ranges)
                for (uint32_t j = rg.first; j < rg.second; ++j) {
                    if (j == i) continue;
                    const double dx = double(px) - sp[3 * size_t(j)], dy = double(py) - sp[3 * size_t(j) + 1],
                                 dz = double(pz) - sp[3 * size_t(j) + 2];
                    if (dx * dx + dy * dy + dz * dz < r2sq) nbr.push_back(j);
                }
            offs[i + 1] = nbr.size();
            double sum = 0;
            for (uint64_t a = offs[i]; a < offs[i + 1]; ++a) sum += weight(i, nbr[a]);
            w[i] = sum;
        }
    }
    IndexedMaxHeap heap(w);
    size_t alive = m;
    while (alive > keep) {
        uint32_t i = heap.top();
        heap.pop();
        --alive;
        for (uint64_t a = offs[i]; a < offs[i + 1]; ++a) {
            uint32_t j = nbr[a];
            if (!heap.contains(j)) continue;
            w[j] -= weight(j, i);
            heap.decreased(j);
        }
    }
    kept.reserve(keep);
    for (size_t a = 0; a < m; ++a)
        if (heap.contains(uint32_t(a))) kept.push_back(order[a].second);
    return kept;
}

SurfelSet sample_surfels(const Mesh& mesh, size_t n, uint64_t seed) {
    if (n == 0) throw Error("surfel count must be at least 1");
    const size_t m = mesh.num_triangles();
    const float* V = mesh.vertices.data();
    const int32_t* T = mesh.triangles.data();
    std::vector<double> cum(m);
    std::vector<float> tri_normal(3 * m);
    double total = 0;
    for (size_t t = 0; t < m; ++t) {
        const float* a = V + 3 * size_t(T[3 * t]);
        const float* b = V + 3 * size_t(T[3 * t + 1]);
        const float* c = V + 3 * size_t(T[3 * t + 2]);
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) { e1[k] = double(b[k]) - a[k]; e2[k] = double(c[k]) - a[k]; }
        double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                        e1[0] * e2[1] - e1[1] * e2[0]};
        double len = std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
        total += 0.5 * len;
        cum[t] = total;
        for (int k = 0; k < 3; ++k) tri_normal[3 * t + k] = float(len > 0 ? cr[k] / len : 0.0);
    }
    const size_t nc = 5 * n;
    std::vector<float> cand(3 * nc);
    std::vector<int32_t> cand_tri(nc);
    const std::array<uint32_t, 2> key{uint32_t(seed), uint32_t(seed >> 32)};
    for (size_t i = 0; i < nc; ++i) {
        Philox4 r = philox4x32_10({kSamplingIteration, uint32_t(i), uint32_t(uint64_t(i) >> 32), 0}, key);
        // 53-bit uniform for the triangle choice (24 bits are too coarse for
        // very large meshes), 24-bit floats for the barycentrics.
        double u = (double(r[0] >> 5) * 67108864.0 + double(r[1] >> 6)) * (1.0 / 9007199254740992.0);
        double target = u * total;
        size_t t = size_t(std::upper_bound(cum.begin(), cum.end(), target) - cum.begin());
        if (t >= m) t = m - 1;
        double r1 = std::sqrt(double(u01(r[2]))), r2 = u01(r[3]);
        double ba = 1.0 - r1, bb = r1 * (1.0 - r2), bc = r1 * r2;
        const float* a = V + 3 * size_t(T[3 * t]);
        const float* b = V + 3 * size_t(T[3 * t + 1]);
        const float* c = V + 3 * size_t(T[3 * t + 2]);
        for (int k = 0; k < 3; ++k) cand[3 * i + k] = float(ba * a[k] + bb * b[k] + bc * c[k]);
        cand_tri[i] = int32_t(t);
    }
    SurfelSet out;
    out.r_max = std::sqrt(total / (2.0 * std::sqrt(3.0) * double(n)));
    std::vector<uint32_t> kept = eliminate_samples(cand, n, out.r_max);
    // Morton order for locality of surfel rows.
    std::vector<std::pair<uint64_t, uint32_t>> order(kept.size());
    double ext = 0;
    for (int k = 0; k < 3; ++k) ext = std::max(ext, double(mesh.hi[k]) - mesh.lo[k]);
    if (!(ext > 0)) ext = 1;
    for (size_t a = 0; a < kept.size(); ++a) {
        uint32_t i = kept[a];
        uint64_t q[3];
        for (int k = 0; k < 3; ++k) {
            double f = (double(cand[3 * size_t(i) + k]) - mesh.lo[k]) / ext;
            q[k] = uint64_t(std::clamp(f, 0.0, 1.0) * 2097151.0);
        }
        order[a] = {expand_bits21(q[0]) | (expand_bits21(q[1]) << 1) | (expand_bits21(q[2]) << 2), i};
    }
    std::sort(order.begin(), order.end());
    out.position.resize(3 * order.size());
    out.normal.resize(3 * order.size());
    out.triangle.resize(order.size());
    for (size_t a = 0; a < order.size(); ++a) {
        uint32_t i = order[a].second;
        int32_t t = cand_tri[i];
        for (int k = 0; k < 3; ++k) {
            out.position[3 * a + k] = cand[3 * size_t(i) + k];
            out.normal[3 * a + k] = tri_normal[3 * size_t(t) + k];
        }
        out.triangle[a] = t;
    }
    return out;
}

}  // namespace gammart
