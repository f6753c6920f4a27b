// Surfel sampling: 5N candidates uniform by area, Yuksel's weighted sample
// elimination down to N (see gamma/surfels.h).  The candidates, the cell sort
// and the neighbour lists are built in parallel, the elimination itself is
// serial; the result is that of the serial algorithm at any thread count.
#include "gamma/surfels.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include "gamma/error.h"
#include "gamma/philox.h"

namespace gammart {

namespace {

// Max-heap of candidates keyed by (weight, rank): larger weight first, ties
// larger rank (index in the sorted points) first.  The key is a strict total order, so the sequence of
// eliminations depends only on the weights, never on the heap's layout.
// 4-ary with each entry holding its weight (16 bytes): the four children of
// a node share one 64-byte cache line, and no indirection to a weight array.
class EliminationHeap {
public:
    explicit EliminationHeap(const std::vector<double>& w) : n_(w.size()) {
        // Entries live at slot k + 3 of a 64-byte-aligned block, so the
        // children 4k+1..4k+4 of node k sit at slots 4(k+1)..4(k+1)+3.
        storage_.resize(n_ + 3 + 4);
        const uintptr_t p = reinterpret_cast<uintptr_t>(storage_.data());
        const size_t skew = ((64 - p % 64) % 64) / sizeof(Entry);
        h_ = storage_.data() + skew + 3;
        pos_.resize(n_);
        for (size_t i = 0; i < n_; ++i) { h_[i] = {w[i], uint32_t(i), 0}; pos_[i] = uint32_t(i); }
        for (size_t i = n_ / 4 + 1; i-- > 0;) down(i);
    }
    uint32_t top() const { return h_[0].index; }
    void pop() {
        pos_[h_[0].index] = kRemoved;
        --n_;
        if (n_ > 0) {
            h_[0] = h_[n_];
            pos_[h_[0].index] = 0;
            down(0);
        }
    }
    bool contains(uint32_t i) const { return pos_[i] != kRemoved; }
    // Cache hints for i's position, then (once that is in) its entry.
    void prefetch_position(uint32_t i) const { __builtin_prefetch(&pos_[i]); }
    void prefetch_entry(uint32_t i) const {
        const uint32_t p = pos_[i];
        if (p != kRemoved) __builtin_prefetch(&h_[p], 1);
    }
    // Subtracts d from i's weight (d >= 0, so i can only move down).
    void decrease(uint32_t i, double d) {
        const uint32_t p = pos_[i];
        h_[p].weight -= d;
        down(p);
    }

private:
    struct Entry {
        double weight;
        uint32_t index, pad;
    };
    static_assert(sizeof(Entry) == 16, "four entries per cache line");
    static constexpr uint32_t kRemoved = 0xFFFFFFFFu;
    static bool before(const Entry& a, const Entry& b) {  // a has higher priority than b
        return a.weight > b.weight || (a.weight == b.weight && a.index > b.index);
    }
    void down(size_t i) {
        const Entry item = h_[i];
        for (;;) {
            const size_t c0 = 4 * i + 1;
            if (c0 >= n_) break;
            const size_t ce = std::min(c0 + 4, n_);
            // The next level down (the children's children, one line each)
            // is requested now, while this level is compared.
            for (size_t c = c0; c < ce && 4 * c + 1 < n_; ++c) __builtin_prefetch(&h_[4 * c + 1]);
            size_t best = c0;
            for (size_t c = c0 + 1; c < ce; ++c)
                if (before(h_[c], h_[best])) best = c;
            if (!before(h_[best], item)) break;
            h_[i] = h_[best];
            pos_[h_[i].index] = uint32_t(i);
            i = best;
        }
        h_[i] = item;
        pos_[item.index] = uint32_t(i);
    }
    size_t n_;
    std::vector<Entry> storage_;
    Entry* h_ = nullptr;
    std::vector<uint32_t> pos_;
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

// Cells per parallel work item of the neighbour search (fixed: the lists do
// not depend on the thread count, and each item's lists are contiguous).
constexpr size_t kCellsPerTask = 512;

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
    // (key, index) pairs are unique: the parallel sort's order is the serial one.
    std::vector<uint32_t> original(m);
    std::vector<float> sp(3 * m);
    std::vector<uint64_t> sorted_key(m);
    {
        std::vector<std::pair<uint64_t, uint32_t>> order(m);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i < r.end(); ++i)
                order[i] = {key_of(cell_of(i, 0), cell_of(i, 1), cell_of(i, 2)), uint32_t(i)};
        });
        tbb::parallel_sort(order.begin(), order.end());
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t a = r.begin(); a < r.end(); ++a) {
                original[a] = order[a].second;
                sorted_key[a] = order[a].first;
                for (int k = 0; k < 3; ++k) sp[3 * a + k] = pts[3 * size_t(order[a].second) + k];
            }
        });
    }
    struct Cell { uint64_t key; uint32_t begin, end; };
    std::vector<Cell> cell_list;
    for (size_t a = 0; a < m;) {
        size_t b = a;
        while (b < m && sorted_key[b] == sorted_key[a]) ++b;
        cell_list.push_back({sorted_key[a], uint32_t(a), uint32_t(b)});
        a = b;
    }
    sorted_key = {};
    std::unordered_map<uint64_t, uint32_t> cells;  // key -> index in cell_list
    cells.reserve(cell_list.size());
    for (size_t c = 0; c < cell_list.size(); ++c) cells.emplace(cell_list[c].key, uint32_t(c));

    const double r2sq = r2 * r2;
    const double inv_r2 = 1.0 / r2;
    // Yuksel's weight (1 - d / 2r_max)^8; symmetric bit for bit in i and j.
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
    // Neighbour lists in rank order (the order of the sorted points), each
    // pair found once: F(i) = neighbours ranked after i, searched in the own
    // cell and the 13 neighbouring cells of larger key, in parallel over
    // fixed blocks of cells (block b's lists contiguous in fwd[b]); then
    // B(j) = neighbours ranked before j, the transpose of F.  B(i) then F(i)
    // is i's whole neighbourhood in rank order, which is the order of the
    // sum of its weights.
    const size_t nblocks = (cell_list.size() + kCellsPerTask - 1) / kCellsPerTask;
    std::vector<std::vector<uint32_t>> fwd(nblocks);
    std::vector<const uint32_t*> f_first(m);
    std::vector<uint32_t> f_count(m);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& br) {
        std::vector<std::pair<uint32_t, uint32_t>> ranges;  // later cells, ascending key
        for (size_t b = br.begin(); b < br.end(); ++b) {
            std::vector<uint32_t>& nbr = fwd[b];
            const size_t c_begin = b * kCellsPerTask, c_end = std::min(cell_list.size(), c_begin + kCellsPerTask);
            nbr.reserve(size_t(cell_list[c_end - 1].end - cell_list[c_begin].begin) * 10);
            for (size_t ci = c_begin; ci < c_end; ++ci) {
                const Cell& cl = cell_list[ci];
                const int64_t cx = int64_t(cl.key >> 42), cy = int64_t((cl.key >> 21) & 0x1fffff),
                              cz = int64_t(cl.key & 0x1fffff);
                ranges.clear();
                for (int64_t dx = 0; dx <= 1; ++dx)
                    for (int64_t dy = dx ? -1 : 0; dy <= 1; ++dy)
                        for (int64_t dz = (dx || dy) ? -1 : 1; dz <= 1; ++dz) {
                            if (cy + dy < 0 || cz + dz < 0) continue;
                            auto it = cells.find(key_of(cx + dx, cy + dy, cz + dz));
                            if (it == cells.end()) continue;
                            const Cell& nc = cell_list[it->second];
                            ranges.emplace_back(nc.begin, nc.end);
                        }
                for (uint32_t i = cl.begin; i < cl.end; ++i) {
                    const size_t before = nbr.size();
                    const double px = sp[3 * size_t(i)], py = sp[3 * size_t(i) + 1], pz = sp[3 * size_t(i) + 2];
                    auto scan = [&](uint32_t j0, uint32_t j1) {
                        for (uint32_t j = j0; j < j1; ++j) {
                            const double dx = px - sp[3 * size_t(j)], dy = py - sp[3 * size_t(j) + 1],
                                         dz = pz - sp[3 * size_t(j) + 2];
                            if (dx * dx + dy * dy + dz * dz < r2sq) nbr.push_back(j);
                        }
                    };
                    scan(i + 1, cl.end);
                    for (const auto& rg : ranges) scan(rg.first, rg.second);
                    f_count[i] = uint32_t(nbr.size() - before);
                }
            }
            nbr.shrink_to_fit();
            // Pointers only once the block's list no longer moves.
            const uint32_t* p = nbr.data();
            for (uint32_t i = cell_list[c_begin].begin; i < cell_list[c_end - 1].end; ++i) {
                f_first[i] = p;
                p += f_count[i];
            }
        }
    });
    // The transpose, in rank order of i (so each B(j) is ascending).
    std::vector<uint64_t> b_offs(m + 1, 0);
    for (size_t i = 0; i < m; ++i)
        for (uint32_t k = 0; k < f_count[i]; ++k) ++b_offs[f_first[i][k] + 1];
    for (size_t j = 0; j < m; ++j) b_offs[j + 1] += b_offs[j];
    std::vector<uint32_t> bwd(b_offs[m]);
    {
        std::vector<uint64_t> fill(b_offs.begin(), b_offs.end() - 1);
        for (size_t i = 0; i < m; ++i)
            for (uint32_t k = 0; k < f_count[i]; ++k) bwd[fill[f_first[i][k]]++] = uint32_t(i);
    }
    // Initial weights: the sum over B(i) then F(i), i.e. in rank order.
    std::vector<double> w(m, 0.0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            double sum = 0;
            for (uint64_t a = b_offs[i]; a < b_offs[i + 1]; ++a) sum += weight(uint32_t(i), bwd[a]);
            for (uint32_t k = 0; k < f_count[i]; ++k) sum += weight(uint32_t(i), f_first[i][k]);
            w[i] = sum;
        }
    });
    // Sequential elimination: the heaviest candidate goes, its neighbours
    // lose its contribution.
    EliminationHeap heap(w);
    w = {};
    // The loop is bound by memory latency (random places in the heap): the
    // neighbours' positions, coordinates and heap entries are requested in
    // two waves before they are used, so their cache misses overlap.
    std::vector<uint32_t> nb;
    for (size_t left = m; left > keep; --left) {
        const uint32_t i = heap.top();
        heap.pop();
        nb.assign(bwd.begin() + std::ptrdiff_t(b_offs[i]), bwd.begin() + std::ptrdiff_t(b_offs[i + 1]));
        nb.insert(nb.end(), f_first[i], f_first[i] + f_count[i]);
        for (const uint32_t j : nb) {
            heap.prefetch_position(j);
            __builtin_prefetch(&sp[3 * size_t(j)]);
        }
        for (const uint32_t j : nb) heap.prefetch_entry(j);
        for (const uint32_t j : nb)
            if (heap.contains(j)) heap.decrease(j, weight(j, i));
    }
    kept.reserve(keep);
    for (size_t a = 0; a < m; ++a)
        if (heap.contains(uint32_t(a))) kept.push_back(original[a]);
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
    // Each candidate depends only on (seed, i): generated in parallel.
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nc, 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
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
    });
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
