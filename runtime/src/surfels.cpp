// Surfel sampling (see gamma/surfels.h): 5N candidates uniform by area, then
// two greedy Poisson-disk passes over them down to exactly N; and the tiled
// weighted sample elimination (Yuksel 2015) it falls back on.
//
// The mesh sampler used to be the weighted elimination alone: remove, one at
// a time, the candidate of largest weight (the sum of (1 - d / 2r_max)^8
// over its neighbours closer than 2 r_max) until N are left.  Its tiled
// parallel form (below) is bound by memory latency: tens of passes over
// ~18 neighbours of each of 5N candidates (its cost: bench/RESULTS.md).  The disk passes look at each candidate's ~9
// neighbours closer than 1.40 r_max a few times, and on the same candidates
// give a larger closest pair (1.28 r_max, by construction, against ~1.26), a
// larger mean nearest-neighbour distance (+0.5-0.8 %) and much smaller holes
// (<= 1.40 r_max, by construction, against ~1.9-2.2): the comparison is
// tests/test_sample_elimination.cpp.
//
// The weighted elimination, tiled: the serial rule done literally is a loop
// over a heap of 5N entries in weight order, i.e. at random places in memory.
// Here the same rule is applied in bands of weight, on spatial tiles:
//   - candidates are grouped into tiles (cubes of side >= 4 r_max, stored
//     contiguously) and the tiles coloured by the parity of their coordinates
//     (8 colours), so that two tiles of one colour are at least 4 r_max apart
//     and no candidate is a neighbour of both;
//   - a pass takes a threshold weight (the weight above which lie a fixed
//     fraction of the candidates still to be removed) and, colour after
//     colour, lets every tile of that colour remove its own candidates in
//     decreasing weight order while their weight is above the threshold, in
//     parallel (a tile writes only its own and its neighbours' weights, which
//     no other tile of the colour touches);
//   - passes repeat with lower thresholds until few removals are left, and
//     those are done by the serial rule on the whole set, which makes the
//     count exact.
// Within a band the order across tiles departs from the global order, so the
// result is not the serial algorithm's, but it is the same at any thread
// count: every choice depends only on the candidates, never on scheduling.
// tests/test_sample_elimination.cpp measures the blue-noise quality against
// the serial algorithm.
#include "gamma/surfels.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <memory>
#include <queue>
#include <unordered_map>

#include <emmintrin.h>
#include <immintrin.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include "gamma/error.h"
#include "gamma/philox.h"

#ifdef GAMMA_SURFEL_TIMING
#include <chrono>
#include <cstdio>
#include <ctime>
inline double surfel_cpu_now() {
    timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}
#define SURFEL_TIMEPOINT(name)                                                                        \
    do {                                                                                              \
        const auto now_ = std::chrono::steady_clock::now();                                          \
        const double cpu_ = surfel_cpu_now();                                                         \
        std::fprintf(stderr, "  %s %.4f/%.4f", name, std::chrono::duration<double>(now_ - tp_).count(), cpu_ - tc_); \
        tp_ = now_;                                                                                   \
        tc_ = cpu_;                                                                                   \
    } while (0)
#define SURFEL_TIMING_START auto tp_ = std::chrono::steady_clock::now(); double tc_ = surfel_cpu_now()
#else
#define SURFEL_TIMEPOINT(name) \
    do {                       \
    } while (0)
#define SURFEL_TIMING_START \
    do {                    \
    } while (0)
#endif

namespace gammart {

namespace {

inline uint64_t expand_bits21(uint64_t v) {
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
}

// A cell's key: its tile (the cell coordinates halved) along a Morton curve,
// then which of the tile's 2x2x2 cells it is.  Sorting by it stores each
// tile's candidates contiguously, and neighbouring tiles mostly nearby.
inline uint64_t cell_key(uint64_t x, uint64_t y, uint64_t z) {
    const uint64_t tile = expand_bits21(x >> 1) | (expand_bits21(y >> 1) << 1) | (expand_bits21(z >> 1) << 2);
    return (tile << 3) | ((x & 1) | ((y & 1) << 1) | ((z & 1) << 2));
}

// A heap array of n trivially copyable values left uninitialised: the
// parallel loop that fills it is the first to touch its pages (a
// std::vector would zero them all in one thread first, and the first touch
// of fresh memory costs the kernel's page faults).  Not advised as
// transparent huge pages: at 1.6M surfels (arrays of hundreds of MB, freed
// and made again pass after pass) the kernel spent far longer finding huge
// pages by compaction than it saved (bench/RESULTS.md).
template <class T>
class Uninitialised {
public:
    Uninitialised() = default;
    explicit Uninitialised(size_t n) : p_(new T[n]), n_(n) {}
    T& operator[](size_t i) { return p_[i]; }
    const T& operator[](size_t i) const { return p_[i]; }
    T* data() { return p_.get(); }
    const T* data() const { return p_.get(); }
    size_t size() const { return n_; }
    void swap(Uninitialised& o) noexcept {
        p_.swap(o.p_);
        std::swap(n_, o.n_);
    }

private:
    std::unique_ptr<T[]> p_;
    size_t n_ = 0;
};

// The coordinates of points, x y z after one another, wherever they are
// stored (a vector, or an array the caller has not zeroed).
struct PointsView {
    const float* xyz;
    size_t count;
    PointsView(const std::vector<float>& v) : xyz(v.data()), count(v.size() / 3) {}
    PointsView(const float* p, size_t n) : xyz(p), count(n) {}
    const float& operator[](size_t i) const { return xyz[i]; }
    size_t size() const { return 3 * count; }
    const float* data() const { return xyz; }
};

// Points sorted into cubic cells, ordered by cell_key (each 2x2x2 tile's
// cells contiguous), with a copy of the positions in that order.
struct CellGrid {
    struct Cell {
        uint64_t key;
        uint32_t begin, end;  // the cell's points, [begin, end) in sorted order
        uint32_t c[3];        // cell coordinates
    };
    Uninitialised<uint32_t> original;  // sorted position -> input index
    Uninitialised<float> sp;           // positions in sorted order
    std::vector<Cell> cells;
    std::unordered_map<uint64_t, uint32_t> index;  // cell key -> position in `cells`
    double lo[3], hi[3];                           // the points' bounding box

    // f(cell) for each non-empty cell of the 27 around `cl` (itself included),
    // in a fixed order.
    template <class F>
    void for_each_around(const Cell& cl, F&& f) const {
        const uint64_t c[3] = {cl.c[0], cl.c[1], cl.c[2]};
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy)
                for (int dz = -1; dz <= 1; ++dz) {
                    if ((dx < 0 && c[0] == 0) || (dy < 0 && c[1] == 0) || (dz < 0 && c[2] == 0)) continue;
                    auto it = index.find(cell_key(c[0] + dx, c[1] + dy, c[2] + dz));
                    if (it != index.end()) f(cells[it->second]);
                }
    }

    // With cells in rows (sort_into_cells(..., true)): the row (y, z) of cells
    // by x, as [begin, end) of `cells`.
    std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> rows;
    // The same as a table over the box's (y, z), where it is no larger than
    // a few entries per point (then `rows` is empty): a row looked up
    // without hashing, and the table made without a node per row.
    std::vector<std::pair<uint32_t, uint32_t>> row_table;  // [z * row_dims[0] + y]; empty: (0, 0)
    uint64_t row_dims[2] = {0, 0};

    // The cells of row (y, z), or null if it has none.
    const std::pair<uint32_t, uint32_t>* find_row(uint64_t y, uint64_t z) const {
        if (!row_table.empty()) {
            if (y >= row_dims[0] || z >= row_dims[1]) return nullptr;
            const std::pair<uint32_t, uint32_t>& r = row_table[z * row_dims[0] + y];
            return r.first == r.second ? nullptr : &r;
        }
        auto it = rows.find(row_key(y, z));
        return it == rows.end() ? nullptr : &it->second;
    }

    static uint64_t row_key(uint64_t y, uint64_t z) { return (z << 21) | y; }

    // The cells of the 9 rows around a cell's (its own included) with x in
    // a range, for cells visited in sorted order (rows by x) and ranges
    // that only move forward within a row: the 9 rows are looked up once
    // per row of cells, and their cells found by cursors that only move
    // forward.
    class RowsAround {
    public:
        explicit RowsAround(const CellGrid& g) : g_(g) {}
        // f(x, begin, end) for each of those cells with x in [x_lo, x_hi].
        template <class F>
        void cells_in(const Cell& cl, uint32_t x_lo, uint32_t x_hi, F&& f) {
            const uint64_t row = cl.key >> 21;
            if (row != row_ || x_lo <= x_hi_) {  // (a range behind the cursors: looked up again)
                row_ = row;
                n_ = 0;
                for (int dz = -1; dz <= 1; ++dz)
                    for (int dy = -1; dy <= 1; ++dy) {
                        if ((dy < 0 && cl.c[1] == 0) || (dz < 0 && cl.c[2] == 0)) continue;
                        const std::pair<uint32_t, uint32_t>* found =
                            g_.find_row(cl.c[1] + uint64_t(dy), cl.c[2] + uint64_t(dz));
                        if (found == nullptr) continue;
                        cursor_[n_] = found->first;
                        end_[n_] = found->second;
                        ++n_;
                    }
            }
            for (int r = 0; r < n_; ++r) {
                uint32_t c = cursor_[r];
                while (c < end_[r] && g_.cells[c].c[0] < x_lo) ++c;
                for (; c < end_[r] && g_.cells[c].c[0] <= x_hi; ++c) f(g_.cells[c].c[0], g_.cells[c].begin, g_.cells[c].end);
                cursor_[r] = c;
            }
            x_hi_ = x_hi;
        }

    private:
        const CellGrid& g_;
        uint64_t row_ = UINT64_MAX;
        uint32_t x_hi_ = 0;
        int n_ = 0;
        uint32_t cursor_[9] = {}, end_[9] = {};
    };
};

// Bounding box of the points (exact: min and max do not depend on the
// order they are taken in, and the float extremes are the double ones).
// Four points (12 floats, 3 vectors) at a time: lane l of accumulator v
// sees coordinate (4v + l) mod 3.  A NaN coordinate is passed over, as
// std::min and std::max would.
void point_bounds(PointsView pts, double lo[3], double hi[3]) {
    struct Box {
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    };
    const size_t n = pts.size() / 3;
    const Box box = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, n, 16384), Box{},
        [&](const tbb::blocked_range<size_t>& r, Box b) {
            const float* p = pts.data();
            size_t i = r.begin();
            __m128 mn[3], mx[3];
            for (int v = 0; v < 3; ++v) mn[v] = _mm_set1_ps(INFINITY), mx[v] = _mm_set1_ps(-INFINITY);
            for (; i + 4 <= r.end(); i += 4)
                for (int v = 0; v < 3; ++v) {
                    const __m128 x = _mm_loadu_ps(p + 3 * i + 4 * size_t(v));
                    mn[v] = _mm_min_ps(x, mn[v]);  // (the second operand when one is NaN)
                    mx[v] = _mm_max_ps(x, mx[v]);
                }
            alignas(16) float lanes_lo[3][4], lanes_hi[3][4];
            for (int v = 0; v < 3; ++v) _mm_store_ps(lanes_lo[v], mn[v]), _mm_store_ps(lanes_hi[v], mx[v]);
            for (int v = 0; v < 3; ++v)
                for (int l = 0; l < 4; ++l) {
                    const int k = (4 * v + l) % 3;
                    b.lo[k] = std::min(b.lo[k], lanes_lo[v][l]);
                    b.hi[k] = std::max(b.hi[k], lanes_hi[v][l]);
                }
            for (; i < r.end(); ++i)
                for (int k = 0; k < 3; ++k) {
                    b.lo[k] = std::min(b.lo[k], p[3 * i + k]);
                    b.hi[k] = std::max(b.hi[k], p[3 * i + k]);
                }
            return b;
        },
        [](Box a, const Box& b) {
            for (int k = 0; k < 3; ++k) {
                a.lo[k] = std::min(a.lo[k], b.lo[k]);
                a.hi[k] = std::max(a.hi[k], b.hi[k]);
            }
            return a;
        });
    for (int k = 0; k < 3; ++k) lo[k] = box.lo[k], hi[k] = box.hi[k];
}

// The a < n with keep(a), ascending: counted, then written, in parallel
// over fixed blocks (keep must give the same answer both times).
template <class Keep>
std::vector<uint32_t> select_in_order(size_t n, Keep&& keep) {
    constexpr size_t kBlock = 16384;
    const size_t nblocks = (n + kBlock - 1) / kBlock;
    std::vector<size_t> at(nblocks + 1, 0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b) {
            size_t count = 0;
            for (size_t a = b * kBlock; a < std::min(n, (b + 1) * kBlock); ++a) count += keep(a) ? 1 : 0;
            at[b + 1] = count;
        }
    });
    for (size_t b = 0; b < nblocks; ++b) at[b + 1] += at[b];
    std::vector<uint32_t> out(at[nblocks]);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b) {
            size_t w = at[b];
            for (size_t a = b * kBlock; a < std::min(n, (b + 1) * kBlock); ++a)
                if (keep(a)) out[w++] = uint32_t(a);
        }
    });
    return out;
}

// Sorts words (key << 32 | index) by their key (below 2^key_bits), stably:
// least significant digit first, each pass over fixed blocks of the words
// (counted, then moved, in parallel), so the result is the serial sort's.
void radix_sort_upper(Uninitialised<uint64_t>& words, int key_bits) {
    // As few passes as digits of up to 12 bits allow (a pass reads and
    // moves every word), the digits as even as can be.
    constexpr int kMaxDigitBits = 12;
    const int passes = std::max(1, (key_bits + kMaxDigitBits - 1) / kMaxDigitBits);
    const int digit_bits = (key_bits + passes - 1) / passes;
    const size_t kDigits = size_t(1) << digit_bits;
    constexpr size_t kWordsPerBlock = 32768;
    const size_t n = words.size();
    const size_t nblocks = (n + kWordsPerBlock - 1) / kWordsPerBlock;
    Uninitialised<uint64_t> moved(n);
    std::vector<size_t> count(nblocks * kDigits);  // block-major
    for (int shift = 32; shift < 32 + key_bits; shift += digit_bits) {
        auto digit = [shift, kDigits](uint64_t w) { return size_t(w >> shift) & (kDigits - 1); };
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t b = r.begin(); b < r.end(); ++b) {
                size_t* c = &count[b * kDigits];
                std::fill(c, c + kDigits, 0);
                for (size_t i = b * kWordsPerBlock; i < std::min(n, (b + 1) * kWordsPerBlock); ++i) ++c[digit(words[i])];
            }
        });
        // where each block's words of each digit go: digits in order, blocks in order within a digit
        size_t at = 0;
        for (size_t d = 0; d < kDigits; ++d)
            for (size_t b = 0; b < nblocks; ++b) {
                const size_t k = count[b * kDigits + d];
                count[b * kDigits + d] = at;
                at += k;
            }
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t b = r.begin(); b < r.end(); ++b) {
                size_t* c = &count[b * kDigits];
                for (size_t i = b * kWordsPerBlock; i < std::min(n, (b + 1) * kWordsPerBlock); ++i)
                    moved[c[digit(words[i])]++] = words[i];
            }
        });
        words.swap(moved);
    }
}

// Cells a little larger than `radius`, so that a point closer than `radius`
// to another is always in one of the 27 cells around the other's; ordered
// in tiles (cell_key, `index` filled) or, with `in_rows`, by (z, y, x)
// (`rows` filled).
CellGrid sort_into_cells(PointsView pts, double radius, bool in_rows = false) {
    const size_t m = pts.size() / 3;
    CellGrid g;
    double* lo = g.lo;
    double* hi = g.hi;
    point_bounds(pts, lo, hi);
    double cell = radius * (1.0 + 1e-6);
    for (int k = 0; k < 3; ++k) cell = std::max(cell, (hi[k] - lo[k]) / 1.0e6);
    if (!(cell > 0)) cell = 1.0;
    auto cell_of = [&](size_t i, int k) { return uint64_t((double(pts[3 * i + k]) - lo[k]) / cell); };
    g.original = Uninitialised<uint32_t>(m);
    g.sp = Uninitialised<float>(3 * m);
    Uninitialised<uint64_t> sorted_key(m);
    // In rows: the cells numbered (z, y, x) in the box, if that fits 32 bits,
    // and (number << 32 | index) sorted by number with a stable radix sort
    // (the order of the (key, index) pairs' sort: the same cells and points).
    uint64_t dims[3];
    for (int k = 0; k < 3; ++k) dims[k] = uint64_t((hi[k] - lo[k]) / cell) + 1;
    const bool numbered = in_rows && m > 0 && dims[0] * dims[1] * dims[2] <= (uint64_t(1) << 32);
    if (numbered) {
        int bits = 1;
        while (bits < 32 && (uint64_t(1) << bits) < dims[0] * dims[1] * dims[2]) ++bits;
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i < r.end(); ++i)
                sorted_key[i] = (((cell_of(i, 2) * dims[1] + cell_of(i, 1)) * dims[0] + cell_of(i, 0)) << 32) | i;
        });
        radix_sort_upper(sorted_key, bits);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            // (the points are read in a random order: fetched a few ahead)
            constexpr size_t kAhead = 16;
            for (size_t a = r.begin(); a < r.end(); ++a) {
                if (a + kAhead < r.end()) __builtin_prefetch(&pts[3 * size_t(uint32_t(sorted_key[a + kAhead]))]);
                const uint32_t i = uint32_t(sorted_key[a]);
                g.original[a] = i;
                sorted_key[a] >>= 32;
                for (int k = 0; k < 3; ++k) g.sp[3 * a + k] = pts[3 * size_t(i) + k];
            }
        });
    } else {
        // (key, index) pairs are unique: the parallel sort's order is the serial one.
        std::vector<std::pair<uint64_t, uint32_t>> order(m);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i < r.end(); ++i)
                order[i] = {in_rows ? (CellGrid::row_key(cell_of(i, 1), cell_of(i, 2)) << 21) | cell_of(i, 0)
                                    : cell_key(cell_of(i, 0), cell_of(i, 1), cell_of(i, 2)),
                            uint32_t(i)};
        });
        tbb::parallel_sort(order.begin(), order.end());
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t a = r.begin(); a < r.end(); ++a) {
                g.original[a] = order[a].second;
                sorted_key[a] = order[a].first;
                for (int k = 0; k < 3; ++k) g.sp[3 * a + k] = pts[3 * size_t(order[a].second) + k];
            }
        });
    }
    // A cell per run of equal keys, found in parallel (a run starts where
    // the key changes).
    const std::vector<uint32_t> starts =
        select_in_order(m, [&](size_t a) { return a == 0 || sorted_key[a] != sorted_key[a - 1]; });
    g.cells.resize(starts.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, starts.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t n = r.begin(); n < r.end(); ++n) {
            const uint32_t a = starts[n], b = n + 1 < starts.size() ? starts[n + 1] : uint32_t(m);
            // (from the sorted copy of the point's coordinates, read in order)
            auto sorted_cell_of = [&](int k) { return uint32_t((double(g.sp[3 * size_t(a) + k]) - lo[k]) / cell); };
            const uint32_t c[3] = {sorted_cell_of(0), sorted_cell_of(1), sorted_cell_of(2)};
            const uint64_t key = numbered ? (CellGrid::row_key(c[1], c[2]) << 21) | c[0] : sorted_key[a];
            g.cells[n] = {key, a, b, {c[0], c[1], c[2]}};
        }
    });
    if (in_rows && m > 0 && dims[1] * dims[2] <= std::max<uint64_t>(65536, 2 * uint64_t(m))) {
        g.row_dims[0] = dims[1];
        g.row_dims[1] = dims[2];
        g.row_table.assign(dims[1] * dims[2], {0, 0});
        for (size_t c = 0; c < g.cells.size(); ++c) {
            std::pair<uint32_t, uint32_t>& row = g.row_table[g.cells[c].c[2] * dims[1] + g.cells[c].c[1]];
            if (c == 0 || (g.cells[c].key >> 21) != (g.cells[c - 1].key >> 21)) row.first = uint32_t(c);
            row.second = uint32_t(c + 1);
        }
    } else if (in_rows) {
        std::pair<uint32_t, uint32_t>* row = nullptr;
        for (size_t c = 0; c < g.cells.size(); ++c) {
            if (c == 0 || (g.cells[c].key >> 21) != (g.cells[c - 1].key >> 21))
                row = &g.rows.try_emplace(g.cells[c].key >> 21, uint32_t(c), uint32_t(c)).first->second;
            row->second = uint32_t(c + 1);
        }
    } else {
        g.index.reserve(g.cells.size());
        for (size_t c = 0; c < g.cells.size(); ++c) g.index.emplace(g.cells[c].key, uint32_t(c));
    }
    return g;
}

// Fraction of the removals still to do that a pass's threshold lets through,
// and the remaining count below which the serial rule finishes.
constexpr double kPassFraction = 0.25;
constexpr size_t kSerialFinishMin = 64;
constexpr size_t kSerialFinishDivisor = 256;  // of the kept count
// The pass threshold is estimated on every kThresholdStride-th candidate.
constexpr size_t kThresholdStride = 64;

// Candidates per parallel work item of the neighbour search (fixed: the lists
// do not depend on the thread count).
constexpr size_t kCellsPerTask = 256;

constexpr double kRemoved = -INFINITY;

// Candidates per surfel asked for.
constexpr size_t kCandidatesPerSurfel = 5;
// A candidate's triangle is found by a count over this many cumulative
// areas where its guide bucket holds no more (fill_candidates).
constexpr size_t kGuideScan = 8;

}  // namespace

namespace {

// Yuksel's weighted sample elimination (the fallback of sample_surfels):
// the heaviest candidate is removed until `keep` are left, each removal
// lowering its neighbours' weights.  Most removals go in parallel passes
// over tiles of 2x2x2 cells, one colour of tiles at a time (tiles of one
// colour share no neighbour); the last by the serial rule on a heap.
class WeightedElimination {
public:
    WeightedElimination(PointsView pts, double r_max);
    void find_neighbours();
    void weigh();
    size_t parallel_passes(size_t keep);
    void serial_finish();
    std::vector<uint32_t> kept() const;

private:
    // Yuksel's weight (1 - d / 2r_max)^8; symmetric bit for bit in i and j.
    double weight(uint32_t i, uint32_t j) const {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double d = double(sp_[3 * size_t(i) + k]) - sp_[3 * size_t(j) + k];
            d2 += d * d;
        }
        double t = 1.0 - std::sqrt(d2) * inv_r2_;
        t = t * t;  // ^2
        t = t * t;  // ^4
        return t * t;  // ^8
    }
    // (weight, rank) is a strict total order (ranks are unique): which
    // candidate is removed first never depends on a layout or a schedule.
    bool above(uint32_t a, uint32_t b) const { return w_[a] > w_[b] || (w_[a] == w_[b] && a > b); }
    // A removed candidate's weight is kRemoved.
    void remove(uint32_t i) {
        w_[i] = kRemoved;
        for (uint64_t a = offs_[i]; a < offs_[i + 1]; ++a) {
            const uint32_t j = nbrs_[a];
            if (w_[j] != kRemoved) w_[j] -= weight(j, i);
        }
    }
    void rescan_max(size_t t) {
        double mx = kRemoved;
        for (uint32_t i = tile_begin_[t]; i < tile_begin_[t + 1]; ++i) mx = std::max(mx, w_[i]);
        tile_max_[t] = mx;
    }
    template <class TileWanted, class Wanted>
    void gather(std::vector<uint32_t>& all, TileWanted&& tile_wanted, Wanted&& wanted);
    void forward_lists(std::vector<std::vector<uint32_t>>& fwd, std::vector<uint32_t>& f_count,
                       std::vector<uint64_t>& f_start, std::vector<std::atomic<uint32_t>>& b_count) const;
    void pass_threshold(size_t k, std::vector<uint32_t>& over, uint32_t& th, double& th_w);
    size_t remove_above(const std::vector<uint32_t>& over, uint32_t th, double th_w);
    void remove_in_tiles(const std::vector<uint32_t>& tiles, size_t q_begin, size_t q_end,
                         const std::vector<uint32_t>& over, uint32_t th, double th_w, size_t& removed);

    static constexpr size_t kTilesPerBlock = 512;   // fixed blocks of tiles for the parallel gathers
    const size_t m_;
    const double r2_, r2sq_, inv_r2_;   // neighbourhood radius 2 r_max, its square, its inverse
    CellGrid grid_;
    const Uninitialised<float>& sp_;
    std::vector<uint32_t> tile_begin_;   // tiles: runs of cells with the same key >> 3, as [begin, end) of points
    std::vector<uint8_t> tile_colour_;
    size_t n_tiles_ = 0;
    std::vector<uint64_t> offs_;
    std::vector<uint32_t> nbrs_;
    std::vector<double> w_;
    std::vector<double> tile_max_;   // per tile an upper bound of its weights (weights only decrease)
    std::vector<std::vector<uint32_t>> tiles_of_colour_ = std::vector<std::vector<uint32_t>>(8);
    std::vector<uint32_t> over_begin_;   // each tile's candidates above a pass's threshold: a run of its `over`
    std::vector<std::vector<uint32_t>> block_pool_;
    size_t to_remove_ = 0, alive_ = 0;
};

// Cells a little larger than the radius also make two tiles (2x2x2 cells)
// of one colour farther apart than twice the radius even after rounding.
WeightedElimination::WeightedElimination(PointsView pts, double r_max)
    : m_(pts.size() / 3), r2_(2.0 * r_max), r2sq_(r2_ * r2_), inv_r2_(1.0 / r2_), grid_(sort_into_cells(pts, r2_)),
      sp_(grid_.sp) {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    for (size_t c = 0; c < cells.size(); ++c) {
        const uint64_t key = cells[c].key;
        if (c == 0 || (cells[c - 1].key >> 3) != (key >> 3)) {
            tile_begin_.push_back(cells[c].begin);
            // The tile's parity in x, y, z: bits 0, 1, 2 of its Morton code.
            tile_colour_.push_back(uint8_t((key >> 3) & 7));
        }
    }
    tile_begin_.push_back(uint32_t(m_));
    n_tiles_ = tile_colour_.size();
    for (size_t t = 0; t < n_tiles_; ++t) tiles_of_colour_[tile_colour_[t]].push_back(uint32_t(t));
}

// F(i) = neighbours j > i, searched in the own cell and the neighbouring
// cells of larger key, in parallel over fixed blocks of cells; and how many
// lists each point is in (|B(i)|).
void WeightedElimination::forward_lists(std::vector<std::vector<uint32_t>>& fwd, std::vector<uint32_t>& f_count,
                                        std::vector<uint64_t>& f_start,
                                        std::vector<std::atomic<uint32_t>>& b_count) const {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, fwd.size(), 1), [&](const tbb::blocked_range<size_t>& br) {
        std::vector<std::pair<uint32_t, uint32_t>> ranges;  // neighbouring cells of larger key
        std::vector<uint32_t> scratch;
        for (size_t b = br.begin(); b < br.end(); ++b) {
            std::vector<uint32_t>& nbr = fwd[b];
            const size_t c_begin = b * kCellsPerTask, c_end = std::min(cells.size(), c_begin + kCellsPerTask);
            nbr.reserve(size_t(cells[c_end - 1].end - cells[c_begin].begin) * 10);
            for (size_t ci = c_begin; ci < c_end; ++ci) {
                const CellGrid::Cell& cl = cells[ci];
                ranges.clear();
                grid_.for_each_around(cl, [&](const CellGrid::Cell& nc) {
                    if (nc.key > cl.key) ranges.emplace_back(nc.begin, nc.end);
                });
                std::sort(ranges.begin(), ranges.end());
                size_t span = cl.end - cl.begin;
                for (const auto& rg : ranges) span += rg.second - rg.first;
                if (scratch.size() < span) scratch.resize(span);
                for (uint32_t i = cl.begin; i < cl.end; ++i) {
                    const double px = sp_[3 * size_t(i)], py = sp_[3 * size_t(i) + 1], pz = sp_[3 * size_t(i) + 2];
                    // Every j is written, the cursor advanced only for the
                    // neighbours: no branch to mispredict.
                    uint32_t* hit = scratch.data();
                    auto scan = [&](uint32_t j0, uint32_t j1) {
                        for (uint32_t j = j0; j < j1; ++j) {
                            const double dx = px - sp_[3 * size_t(j)], dy = py - sp_[3 * size_t(j) + 1],
                                         dz = pz - sp_[3 * size_t(j) + 2];
                            *hit = j;
                            hit += dx * dx + dy * dy + dz * dz < r2sq_;
                        }
                    };
                    scan(i + 1, cl.end);
                    for (const auto& rg : ranges) scan(rg.first, rg.second);
                    f_start[i] = nbr.size();
                    f_count[i] = uint32_t(hit - scratch.data());
                    nbr.insert(nbr.end(), scratch.data(), hit);
                    for (const uint32_t* h = scratch.data(); h < hit; ++h)
                        b_count[*h].fetch_add(1, std::memory_order_relaxed);
                }
            }
        }
    });
}

// Neighbour lists, each pair found once (forward_lists), then each list
// completed with B(i) = {j < i : i in F(j)} (filled with atomic cursors, then
// sorted, so that the lists do not depend on the scheduling).  List of i =
// B(i) then F(i), ascending, which is the order of the sum of its weights.
void WeightedElimination::find_neighbours() {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    const size_t nblocks = (cells.size() + kCellsPerTask - 1) / kCellsPerTask;
    std::vector<std::vector<uint32_t>> fwd(nblocks);
    std::vector<uint32_t> f_count(m_);
    std::vector<uint64_t> f_start(m_);  // offset of F(i) in its block's list
    std::vector<std::atomic<uint32_t>> b_count(m_);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 8192), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) b_count[i].store(0, std::memory_order_relaxed);
    });
    forward_lists(fwd, f_count, f_start, b_count);
    // Offsets of the whole lists: |B(i)| + |F(i)| each.
    offs_.assign(m_ + 1, 0);
    for (size_t i = 0; i < m_; ++i) offs_[i + 1] = offs_[i] + b_count[i].load(std::memory_order_relaxed) + f_count[i];
    nbrs_.assign(offs_[m_], 0);
    // F(i) goes after B(i); B(j) is filled from the front by cursors.
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) b_count[i].store(0, std::memory_order_relaxed);
    });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& br) {
        for (size_t b = br.begin(); b < br.end(); ++b) {
            const size_t c_begin = b * kCellsPerTask, c_end = std::min(cells.size(), c_begin + kCellsPerTask);
            for (uint32_t i = cells[c_begin].begin; i < cells[c_end - 1].end; ++i) {
                const uint32_t* f = fwd[b].data() + f_start[i];
                std::copy(f, f + f_count[i], nbrs_.begin() + std::ptrdiff_t(offs_[i + 1] - f_count[i]));
                for (uint32_t k = 0; k < f_count[i]; ++k) {
                    const uint32_t j = f[k];
                    nbrs_[offs_[j] + b_count[j].fetch_add(1, std::memory_order_relaxed)] = i;
                }
            }
            fwd[b] = {};
        }
    });
    // B(i) in ascending order
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i)
            std::sort(nbrs_.begin() + std::ptrdiff_t(offs_[i]), nbrs_.begin() + std::ptrdiff_t(offs_[i + 1] - f_count[i]));
    });
}

// The initial weights: the sum over each list in its order; and each
// tile's largest.
void WeightedElimination::weigh() {
    w_.assign(m_, 0.0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            double sum = 0;
            for (uint64_t a = offs_[i]; a < offs_[i + 1]; ++a) sum += weight(uint32_t(i), nbrs_[a]);
            w_[i] = sum;
        }
    });
    tile_max_.assign(n_tiles_, 0.0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_tiles_, 256), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t t = r.begin(); t < r.end(); ++t) rescan_max(t);
    });
}

// The candidates `wanted` of the tiles `tile_wanted`, ascending (gathered
// in fixed blocks of tiles, concatenated in block order: independent of the
// thread count).
template <class TileWanted, class Wanted>
void WeightedElimination::gather(std::vector<uint32_t>& all, TileWanted&& tile_wanted, Wanted&& wanted) {
    const size_t n_blocks = (n_tiles_ + kTilesPerBlock - 1) / kTilesPerBlock;
    block_pool_.resize(n_blocks);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_blocks, 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b) {
            std::vector<uint32_t>& out = block_pool_[b];
            out.clear();
            const size_t t1 = std::min(n_tiles_, (b + 1) * kTilesPerBlock);
            for (size_t t = b * kTilesPerBlock; t < t1; ++t)
                if (tile_wanted(t))
                    for (uint32_t i = tile_begin_[t]; i < tile_begin_[t + 1]; ++i)
                        if (wanted(i)) out.push_back(i);
        }
    });
    all.clear();
    for (const auto& v : block_pool_) all.insert(all.end(), v.begin(), v.end());
}

// A pass's threshold: about the weight of the k-th heaviest candidate left,
// estimated on every kThresholdStride-th candidate (by rank: spread over the
// scene), and the candidates above it (`over`).  If the estimate lets
// through more than the removals left, the exact k-th of those is taken
// instead.  The threshold is (th_w, th): above it means (weight, rank) above.
void WeightedElimination::pass_threshold(size_t k, std::vector<uint32_t>& over, uint32_t& th, double& th_w) {
    auto by_weight = [this](uint32_t a, uint32_t b) { return above(a, b); };
    std::vector<uint32_t> sub;
    for (size_t i = 0; i < m_; i += kThresholdStride)
        if (w_[i] != kRemoved) sub.push_back(uint32_t(i));
    th = 0;
    th_w = INFINITY;
    if (!sub.empty()) {
        const size_t k_sub =
            std::min(sub.size(), std::max<size_t>(1, size_t(double(k) * double(sub.size()) / double(alive_))));
        std::nth_element(sub.begin(), sub.begin() + std::ptrdiff_t(k_sub - 1), sub.end(), by_weight);
        th = sub[k_sub - 1];
        th_w = w_[th];
    }
    const double est_w = th_w;
    const uint32_t est = th;
    gather(over, [&](size_t t) { return tile_max_[t] >= est_w; },
           [&](uint32_t i) { return w_[i] != kRemoved && (w_[i] > est_w || (w_[i] == est_w && i > est)); });
    if (over.size() <= to_remove_ && !over.empty()) return;
    // Too many let through (or none): the exact k-th heaviest.
    if (over.empty()) gather(over, [](size_t) { return true; }, [&](uint32_t i) { return w_[i] != kRemoved; });
    std::vector<uint32_t> pick(over);
    std::nth_element(pick.begin(), pick.begin() + std::ptrdiff_t(k - 1), pick.end(), by_weight);
    th = pick[k - 1];
    th_w = w_[th];
    std::vector<uint32_t> kept_over;
    for (const uint32_t i : over)
        if (w_[i] > th_w || (w_[i] == th_w && i >= th)) kept_over.push_back(i);
    over.swap(kept_over);
    // th itself is let through: the threshold is just below it.
    if (th == 0) th_w = std::nextafter(th_w, -INFINITY);
    else --th;
}

// The parallel passes, while more than a small remainder is to go: each
// removes only candidates that were above its threshold at its start.
// Returns the number of passes.
size_t WeightedElimination::parallel_passes(size_t keep) {
    to_remove_ = m_ - keep;
    alive_ = m_;
    const size_t serial_finish = std::max(kSerialFinishMin, keep / kSerialFinishDivisor);
    size_t passes = 0;
    std::vector<uint32_t> over;
    while (to_remove_ > serial_finish) {
        const size_t k = std::max<size_t>(1, size_t(double(to_remove_) * kPassFraction));
        uint32_t th;
        double th_w;
        pass_threshold(k, over, th, th_w);
        const size_t removed = remove_above(over, th, th_w);
        to_remove_ -= removed;
        alive_ -= removed;
        ++passes;
    }
    return passes;
}

// One pass's removals, colour by colour of tiles, the tiles of a colour in
// parallel; returns how many.
size_t WeightedElimination::remove_above(const std::vector<uint32_t>& over, uint32_t th, double th_w) {
    // Each tile's candidates above the threshold: a run of `over`.
    over_begin_.assign(n_tiles_ + 1, 0);
    size_t a = 0;
    for (size_t t = 0; t < n_tiles_; ++t) {
        over_begin_[t] = uint32_t(a);
        while (a < over.size() && over[a] < tile_begin_[t + 1]) ++a;
    }
    over_begin_[n_tiles_] = uint32_t(a);
    std::atomic<size_t> removed{0};
    for (const std::vector<uint32_t>& tiles : tiles_of_colour_)
        tbb::parallel_for(tbb::blocked_range<size_t>(0, tiles.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
            size_t removed_here = 0;
            remove_in_tiles(tiles, r.begin(), r.end(), over, th, th_w, removed_here);
            removed.fetch_add(removed_here, std::memory_order_relaxed);
        });
    return removed.load();
}

// The removals of tiles[q_begin, q_end), each tile's candidates heaviest
// first while above the threshold (nothing below it at the start can rise).
// They are bound by memory latency, not arithmetic: tiles go through a
// pipeline that requests their data ahead of use (a tile's candidates above
// the threshold do not change before it is processed: no other tile of the
// colour touches them).
//   q + 3: the list offsets of its candidates above the threshold;
//   q + 2: their neighbour lists;
//   q + 1: their neighbours' weights and positions;
//   q:     its removals.
void WeightedElimination::remove_in_tiles(const std::vector<uint32_t>& tiles, size_t q_begin, size_t q_end,
                                          const std::vector<uint32_t>& over, uint32_t th, double th_w,
                                          size_t& removed) {
    auto each_active = [&](size_t q, auto&& f) {
        const uint32_t t = tiles[q];
        for (uint32_t a = over_begin_[t]; a < over_begin_[t + 1]; ++a) f(over[a]);
    };
    auto stage_offsets = [&](size_t q) { each_active(q, [&](uint32_t i) { __builtin_prefetch(&offs_[i]); }); };
    auto stage_lists = [&](size_t q) {
        each_active(q, [&](uint32_t i) {
            __builtin_prefetch(&nbrs_[offs_[i]]);
            __builtin_prefetch(&nbrs_[offs_[i]] + 16);
        });
    };
    auto stage_neighbours = [&](size_t q) {
        each_active(q, [&](uint32_t i) {
            for (uint64_t a = offs_[i]; a < offs_[i + 1]; ++a) {
                __builtin_prefetch(&w_[nbrs_[a]], 1);
                __builtin_prefetch(&sp_[3 * size_t(nbrs_[a])]);
            }
        });
    };
    auto is_above = [&](uint32_t i) { return w_[i] > th_w || (w_[i] == th_w && i > th); };
    for (size_t q = q_begin; q < std::min(q_end, q_begin + 3); ++q) stage_offsets(q);
    for (size_t q = q_begin; q < std::min(q_end, q_begin + 2); ++q) stage_lists(q);
    stage_neighbours(q_begin);
    std::vector<uint32_t> active;
    for (size_t q = q_begin; q < q_end; ++q) {
        if (q + 3 < q_end) stage_offsets(q + 3);
        if (q + 2 < q_end) stage_lists(q + 2);
        if (q + 1 < q_end) stage_neighbours(q + 1);
        const uint32_t t = tiles[q];
        if (over_begin_[t] == over_begin_[t + 1]) continue;
        active.assign(over.begin() + over_begin_[t], over.begin() + over_begin_[t + 1]);
        while (!active.empty()) {
            size_t best = 0;
            for (size_t a = 1; a < active.size(); ++a)
                if (above(active[a], active[best])) best = a;
            const uint32_t i = active[best];
            if (!is_above(i)) break;
            active[best] = active.back();
            active.pop_back();
            remove(i);
            ++removed;
        }
        rescan_max(t);
    }
}

// The last removals by the serial rule, on a heap with lazy updates: an
// entry whose weight has dropped since it was pushed is pushed again with
// its current weight (weights only decrease, so the top entry that is
// current is the heaviest candidate).
void WeightedElimination::serial_finish() {
    using Entry = std::pair<double, uint32_t>;  // (weight, rank): the same order as `above`
    std::vector<Entry> entries;
    entries.reserve(alive_);
    for (size_t i = 0; i < m_; ++i)
        if (w_[i] != kRemoved) entries.emplace_back(w_[i], uint32_t(i));
    std::priority_queue<Entry> heap(std::less<Entry>(), std::move(entries));
    while (to_remove_ > 0) {
        const Entry e = heap.top();
        heap.pop();
        if (w_[e.second] == kRemoved) continue;
        if (e.first != w_[e.second]) {
            heap.emplace(w_[e.second], e.second);
            continue;
        }
        remove(e.second);
        --to_remove_;
    }
}

std::vector<uint32_t> WeightedElimination::kept() const {
    std::vector<uint32_t> kept;
    kept.reserve(alive_);
    for (size_t a = 0; a < m_; ++a)
        if (w_[a] != kRemoved) kept.push_back(grid_.original[a]);
    return kept;
}

std::vector<uint32_t> eliminate_samples_in(PointsView pts, size_t keep, double r_max) {
    const size_t m = pts.size() / 3;
    std::vector<uint32_t> kept;
    if (keep >= m) {
        for (size_t i = 0; i < m; ++i) kept.push_back(uint32_t(i));
        return kept;
    }
    SURFEL_TIMING_START;
    WeightedElimination elimination(pts, r_max);
    SURFEL_TIMEPOINT("cells");
    elimination.find_neighbours();
    elimination.weigh();
    SURFEL_TIMEPOINT("lists+weights");
    const size_t passes = elimination.parallel_passes(keep);
    SURFEL_TIMEPOINT("passes");
    elimination.serial_finish();
    SURFEL_TIMEPOINT("serial");
#ifdef GAMMA_SURFEL_TIMING
    std::fprintf(stderr, "  [%zu passes]\n", passes);
#else
    (void)passes;
#endif
    return elimination.kept();
}

}  // namespace

std::vector<uint32_t> eliminate_samples(const std::vector<float>& pts, size_t keep, double r_max) {
    return eliminate_samples_in(pts, keep, r_max);
}

namespace {

// The two disk radii, in units of r_max.  On 5N uniform candidates the
// first pass (1.40) keeps about 0.89 N on the bunny and the second fills
// the rest at 1.28; where the second pass cannot reach N at a radius it is
// redone kDiskRadiusStep smaller, down to kDiskRadiusMin (below that the
// weighted elimination does all the work).
constexpr double kWideRadius = 1.40;
constexpr double kNarrowRadius = 1.28;
constexpr double kDiskRadiusStep = 0.02;
constexpr double kDiskRadiusMin = 1.0;
// Points per parallel work item of the disk rounds.
constexpr size_t kPointsPerTask = 2048;

enum : uint8_t { kUndecided = 0, kIn = 1, kOut = 2 };

// The narrow radius of the second pass's try `step` (0, 1, ...).
inline double narrow_radius(int step, double r_max) { return (kNarrowRadius - step * kDiskRadiusStep) * r_max; }

// A neighbour list entry: the neighbour's sorted position, and this bit if
// it is also closer than the first narrow radius.
constexpr uint32_t kNarrowBit = 0x80000000u;
constexpr uint32_t kPositionBits = ~kNarrowBit;

// A point's neighbour list: [begin, end) of the lists' array.
struct ListSpan {
    uint32_t begin, end;
};
// The mark of a block whose lists did not fit the entries reserved.
constexpr uint64_t kSpilled = UINT64_MAX;

// For each 4-bit mask, the lanes whose bit is set, first to last (the
// rest 0): a vector comparison's passing lanes packed by one store.
const __m128i kSetLanes[16] = {
    _mm_setr_epi32(0, 0, 0, 0), _mm_setr_epi32(0, 0, 0, 0), _mm_setr_epi32(1, 0, 0, 0), _mm_setr_epi32(0, 1, 0, 0),
    _mm_setr_epi32(2, 0, 0, 0), _mm_setr_epi32(0, 2, 0, 0), _mm_setr_epi32(1, 2, 0, 0), _mm_setr_epi32(0, 1, 2, 0),
    _mm_setr_epi32(3, 0, 0, 0), _mm_setr_epi32(0, 3, 0, 0), _mm_setr_epi32(1, 3, 0, 0), _mm_setr_epi32(0, 1, 3, 0),
    _mm_setr_epi32(2, 3, 0, 0), _mm_setr_epi32(0, 2, 3, 0), _mm_setr_epi32(1, 2, 3, 0), _mm_setr_epi32(0, 1, 2, 3),
};
constexpr uint8_t kSetLaneCount[16] = {0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4};

// Entries of a window's copy past its last point (at infinity, never
// passed): a vector's read from the window's last point, and the room a
// list is given beyond its window.
constexpr size_t kWindowPad = 16;

// The neighbour lists' test of a point against its window (the points of
// the 27 cells around its own, copied side by side as x y z, biased order
// hash and sorted position): its earlier neighbours closer than the wide
// radius, each with kNarrowBit if also closer than the first narrow radius.
// A float filter, closer than the wide radius by a margin larger than its
// rounding error and not later by the order's hash; the float squared
// distance decides the exact test where it is farther from the radii than
// that margin (sure_wide2, sure_narrow2, not_narrow2), the exact test in
// double on the whole order key decides the rest (near misses, hash ties).
// Two forms with the same lists (up to their order, which no decision
// reads): SSE2, four points at a time, the passing ones then tested one by
// one; AVX-512 (chosen at run time where the CPU has it), sixteen at a time,
// those the float distance decides written at once, only the rest one by
// one.  (A window is read to a whole vector past its end: points of cells
// two or more away, farther than the wide radius, or the padding.)
struct WindowFilter {
    const float* sp;          // sorted positions
    const uint64_t* order_key;
    float filter_radius2, sure_wide2, sure_narrow2, not_narrow2;
    double wide2, narrow_first2;
    ListSpan* lists;
    // the window's copy (refreshed when its arrays grow)
    const float *nx = nullptr, *ny = nullptr, *nz = nullptr;
    const int32_t* nhash = nullptr;
    const uint32_t* nid = nullptr;
    uint32_t* maybe = nullptr;  // SSE2: the window entries the filter passed
    float* nd2 = nullptr;       // SSE2: their float squared distances

    void refresh(const std::vector<float>& x, const std::vector<float>& y, const std::vector<float>& z,
                 const std::vector<int32_t>& h, const std::vector<uint32_t>& id, std::vector<uint32_t>& m,
                 std::vector<float>& d2) {
        nx = x.data(), ny = y.data(), nz = z.data(), nhash = h.data(), nid = id.data(), maybe = m.data(), nd2 = d2.data();
    }

    static int32_t biased_hash(uint64_t key) { return int32_t(uint32_t(key >> 32) ^ 0x80000000u); }

    // Entry k of the window for point i (whose key is ki, at px py pz), which
    // the filter passed and whose float squared distance is f2: written to
    // *hit, and whether it is an earlier neighbour (every entry is written,
    // the caller's cursor advanced only for the neighbours: no branch on
    // the outcome).
    uint32_t test_one(size_t k, float f2, double px, double py, double pz, uint64_t ki, uint32_t* hit) const {
        // (bitwise: one branch, nearly always taken)
        if ((f2 < sure_wide2) & ((f2 < sure_narrow2) | (f2 >= not_narrow2))) {
            // The filter passed only hashes at most i's: a smaller one is
            // earlier, an equal one (the point itself, or a tie) is by the
            // whole key.
            *hit = nid[k] | (f2 < sure_narrow2 ? kNarrowBit : 0);
            return uint32_t((nhash[k] != biased_hash(ki)) | (order_key[nid[k]] < ki));
        }
        const double dx = px - nx[k], dy = py - ny[k], dz = pz - nz[k];
        const double d2 = dx * dx + dy * dy + dz * dz;
        *hit = nid[k] | (d2 < narrow_first2 ? kNarrowBit : 0);
        return uint32_t((d2 < wide2) & (order_key[nid[k]] < ki));
    }

    // The lists of points [i_begin, i_end), whose window is [w_begin,
    // w_end), written from list[used] on (room for each point's whole
    // window and kWindowPad more); returns the entries used.
    size_t cell_lists_sse2(uint32_t i_begin, uint32_t i_end, size_t w_begin, size_t w_end, uint32_t* list,
                           size_t used) const {
        const __m128 limit = _mm_set1_ps(filter_radius2);
        for (uint32_t i = i_begin; i < i_end; ++i) {
            const __m128 px4 = _mm_set1_ps(sp[3 * size_t(i)]), py4 = _mm_set1_ps(sp[3 * size_t(i) + 1]),
                         pz4 = _mm_set1_ps(sp[3 * size_t(i) + 2]);
            const __m128i hi4 = _mm_set1_epi32(biased_hash(order_key[i]));
            size_t n_maybe = 0;
            for (size_t k = w_begin; k < w_end; k += 4) {
                const __m128 dx = _mm_sub_ps(px4, _mm_loadu_ps(&nx[k]));
                const __m128 dy = _mm_sub_ps(py4, _mm_loadu_ps(&ny[k]));
                const __m128 dz = _mm_sub_ps(pz4, _mm_loadu_ps(&nz[k]));
                const __m128 d2 = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy)), _mm_mul_ps(dz, dz));
                _mm_storeu_ps(&nd2[k], d2);
                const __m128 near = _mm_cmpnge_ps(d2, limit);
                const __m128i later = _mm_cmpgt_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(&nhash[k])), hi4);
                const int mask = _mm_movemask_ps(_mm_andnot_ps(_mm_castsi128_ps(later), near));
                _mm_storeu_si128(reinterpret_cast<__m128i*>(&maybe[n_maybe]),
                                 _mm_add_epi32(_mm_set1_epi32(int32_t(k)), kSetLanes[mask]));
                n_maybe += kSetLaneCount[mask];
            }
            const double px = sp[3 * size_t(i)], py = sp[3 * size_t(i) + 1], pz = sp[3 * size_t(i) + 2];
            const uint64_t ki = order_key[i];
            uint32_t* hit = list + used;
            size_t found = 0;
            for (size_t c = 0; c < n_maybe; ++c) found += test_one(maybe[c], nd2[maybe[c]], px, py, pz, ki, hit + found);
            lists[i] = {uint32_t(used), uint32_t(used + found)};  // in the block's, for now
            used += found;
        }
        return used;
    }

#if defined(__x86_64__) && defined(__GNUC__)
#define GAMMA_DISK_FILTER_AVX512 1
    static bool has_avx512() {
        static const bool has = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("popcnt") &&
                                __builtin_cpu_supports("bmi");
        return has;
    }
    // cell_lists_sse2's lists, sixteen window points at a time: the
    // entries the float distance decides (all but near misses, hash ties
    // and the point itself, which is never its own neighbour) are packed
    // into the list by one compress; the rest go through test_one.  The
    // same float operations as the SSE2 form (no fused multiply-add: this
    // file is compiled with -ffp-contract=off).
    [[gnu::target("avx512f,popcnt,bmi")]] size_t cell_lists_avx512(uint32_t i_begin, uint32_t i_end, size_t w_begin,
                                                                   size_t w_end, uint32_t* list, size_t used) const {
        const __m512 limit = _mm512_set1_ps(filter_radius2), sure_w = _mm512_set1_ps(sure_wide2),
                     sure_n = _mm512_set1_ps(sure_narrow2), not_n = _mm512_set1_ps(not_narrow2);
        const __m512i narrow_bit = _mm512_set1_epi32(int32_t(kNarrowBit));
        for (uint32_t i = i_begin; i < i_end; ++i) {
            const float pxf = sp[3 * size_t(i)], pyf = sp[3 * size_t(i) + 1], pzf = sp[3 * size_t(i) + 2];
            const __m512 px16 = _mm512_set1_ps(pxf), py16 = _mm512_set1_ps(pyf), pz16 = _mm512_set1_ps(pzf);
            const uint64_t ki = order_key[i];
            const __m512i hi16 = _mm512_set1_epi32(biased_hash(ki));
            const __m512i self16 = _mm512_set1_epi32(int32_t(i));
            uint32_t* hit = list + used;
            size_t found = 0;
            for (size_t k = w_begin; k < w_end; k += 16) {
                const __m512 dx = _mm512_sub_ps(px16, _mm512_loadu_ps(&nx[k]));
                const __m512 dy = _mm512_sub_ps(py16, _mm512_loadu_ps(&ny[k]));
                const __m512 dz = _mm512_sub_ps(pz16, _mm512_loadu_ps(&nz[k]));
                const __m512 d2 =
                    _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy)), _mm512_mul_ps(dz, dz));
                const __m512i h = _mm512_loadu_si512(&nhash[k]);
                const __m512i id = _mm512_loadu_si512(&nid[k]);
                const __mmask16 passed = _mm512_cmp_ps_mask(d2, limit, _CMP_NGE_UQ) & _mm512_cmple_epi32_mask(h, hi16) &
                                         _mm512_cmpneq_epi32_mask(id, self16);
                const __mmask16 narrow = _mm512_cmp_ps_mask(d2, sure_n, _CMP_LT_OQ);
                const __mmask16 decided = _mm512_cmp_ps_mask(d2, sure_w, _CMP_LT_OQ) &
                                          (narrow | _mm512_cmp_ps_mask(d2, not_n, _CMP_GE_OQ)) &
                                          _mm512_cmplt_epi32_mask(h, hi16);
                const __mmask16 fast = passed & decided;
                _mm512_storeu_si512(hit + found,
                                    _mm512_maskz_compress_epi32(fast, _mm512_mask_or_epi32(id, narrow, id, narrow_bit)));
                found += unsigned(__builtin_popcount(unsigned(fast)));
                unsigned slow = unsigned(passed & ~decided);
                if (slow != 0) {
                    alignas(64) float f2[16];
                    _mm512_store_ps(f2, d2);
                    for (; slow != 0; slow &= slow - 1) {
                        const unsigned lane = unsigned(__builtin_ctz(slow));
                        found += test_one(k + lane, f2[lane], pxf, pyf, pzf, ki, hit + found);
                    }
                }
            }
            lists[i] = {uint32_t(used), uint32_t(used + found)};  // in the block's, for now
            used += found;
        }
        return used;
    }
#else
    static bool has_avx512() { return false; }
    size_t cell_lists_avx512(uint32_t i_begin, uint32_t i_end, size_t w_begin, size_t w_end, uint32_t* list,
                             size_t used) const {
        return cell_lists_sse2(i_begin, i_end, w_begin, w_end, list, used);
    }
#endif
};

}  // namespace

// Exactly `keep` of `pts` as two greedy Poisson-disk passes in one fixed
// random order of the points (random sequential adsorption from a finite
// pool of candidates): the first keeps each point that no point kept before
// it lies closer than the wide radius to; the second, over the points left,
// keeps each that no point kept so far (in either pass) lies closer than
// the narrow radius to, and stops when `keep` are kept.  The first pass
// leaves no point of the pool farther than the wide radius from a kept one
// (no holes); the second fills the gaps it left with points no closer than
// the narrow radius.
//
// The serial rule has a unique answer, so each pass is computed in parallel
// rounds: a point is "out" as soon as an earlier neighbour is in, "in" once
// all its earlier neighbours are out, whatever the order in which the
// rounds visit the points; the second pass's first `still wanted` points in
// the order are the serial pass stopped at `keep`.  The same at any thread
// count.  Returns the kept indices (in no particular order), or nothing if
// the second pass falls short even at kDiskRadiusMin.
namespace {

// The state of poisson_disk_sample_in: the candidates in cells, their order,
// each one's earlier neighbours and its state in the pass under way.
class DiskSampler {
public:
    DiskSampler(PointsView pts, double r_max, uint64_t seed);
    void find_earlier_neighbours(size_t list_capacity, bool allow_avx512);
    std::vector<uint32_t> first_pass(size_t keep);
    bool second_pass(std::vector<uint32_t>& chosen, size_t wanted);
    void to_input_indices(std::vector<uint32_t>& chosen) const;

private:
    bool earlier(uint32_t a, uint32_t b) const { return order_key_[a] < order_key_[b]; }
    double dist2(uint32_t a, uint32_t b) const {
        double d2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double d = double(sp_[3 * size_t(a) + k]) - sp_[3 * size_t(b) + k];
            d2 += d * d;
        }
        return d2;
    }
    // The scratch of one task's blocks of cells.
    struct BlockScratch;
    size_t block_lists(size_t b, BlockScratch& s, bool avx512) const;
    void store_block(size_t b, const std::vector<uint32_t>& list, size_t used);
    void pack_spilled();
    void greedy_pass(double radius);
    bool decide(uint32_t i, double radius2, bool every_listed, bool flagged);
    template <class Kept>
    std::vector<uint32_t> earliest_kept(Kept&& kept, size_t count) const;
    void narrow_states(const std::vector<uint32_t>& chosen, int step, double narrow2);

    const size_t m_;
    const double r_max_, wide_, wide2_, narrow_first_, narrow_first2_;
    const CellGrid grid_;
    const Uninitialised<float>& sp_;
    Uninitialised<uint64_t> order_key_;
    // the float filter's limits (see the constructor)
    float filter_radius2_, sure_wide2_, sure_narrow2_, not_narrow2_;
    size_t nblocks_ = 0, capacity_ = 0;
    Uninitialised<ListSpan> lists_;
    Uninitialised<uint32_t> nbrs_;
    std::atomic<size_t> nbrs_used_{0};
    std::vector<uint64_t> block_at_;   // where a block's lists are in nbrs_, or kSpilled
    std::vector<std::vector<uint32_t>> spilled_;
    std::atomic<bool> any_spilled_{false};
    Uninitialised<std::atomic<uint8_t>> state_;
    Uninitialised<uint8_t> first_in_;
};

// The order: a Philox hash of the point's index, ties by the index (not by
// the sorted position: the answer does not depend on the layout).
DiskSampler::DiskSampler(PointsView pts, double r_max, uint64_t seed)
    : m_(pts.size() / 3), r_max_(r_max), wide_(kWideRadius * r_max), wide2_(wide_ * wide_),
      narrow_first_(narrow_radius(0, r_max)), narrow_first2_(narrow_first_ * narrow_first_),
      grid_(sort_into_cells(pts, wide_, true)), sp_(grid_.sp), order_key_(m_), lists_(m_), state_(m_),
      first_in_(m_) {
    const std::array<uint32_t, 2> key{uint32_t(seed), uint32_t(seed >> 32)};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t a = r.begin(); a < r.end(); ++a) {
            const uint32_t i = grid_.original[a];
            order_key_[a] = (uint64_t(philox4x32_10({kSamplingIteration, i, 1, 0}, key)[0]) << 32) | i;
        }
    });
    // The float filter passes every pair the exact test can accept when its
    // error bound holds: coordinates and squared distances of normal floats,
    // far from overflow.  Otherwise its limit is NaN, which passes
    // everything (the comparison is "not at or above the limit").
    double extent = 0;
    for (int k = 0; k < 3; ++k) extent = std::max({extent, std::abs(grid_.lo[k]), std::abs(grid_.hi[k])});
    const bool filter_sound = wide2_ > 1e-30 && extent < 1e15 && wide2_ < 1e30;
    filter_radius2_ = filter_sound ? float(wide2_ * (1.0 + 1e-5)) : NAN;
    // Float squared distances that decide the exact tests by the same
    // margin: below sure_wide2 is closer than the wide radius; below
    // sure_narrow2 closer than the first narrow radius, from not_narrow2 up
    // not.  In between, and on a tie of the order's hash, the exact test
    // decides.  (Without a sound filter every one takes the exact test.)
    sure_wide2_ = filter_sound ? float(wide2_ * (1.0 - 1e-5)) : -1.0f;
    sure_narrow2_ = float(narrow_first2_ * (1.0 - 1e-5));
    not_narrow2_ = float(narrow_first2_ * (1.0 + 1e-5));
}

struct DiskSampler::BlockScratch {
    // A row's cells go in clusters (consecutive cells at most 2 apart in x,
    // whose neighbourhoods overlap).  The points of the 9 rows around a
    // cluster, over its x range widened by one, are copied side by side in
    // order of x (then of row): the points of the 27 cells around each of
    // its cells are then one run of them, and each point is copied about 9
    // times instead of once per cell around it.
    struct Run {
        uint32_t x, begin, end;
    };
    std::vector<Run> runs;
    std::vector<uint32_t> x_start, x_fill;
    std::vector<float> nx, ny, nz, nd2;  // nd2: the last point's float squared distances
    std::vector<int32_t> nhash;  // order hash, biased for a signed comparison
    std::vector<uint32_t> nid, maybe;
    std::vector<uint32_t> list;  // the block's lists; its size is its capacity
    CellGrid::RowsAround rows;
    WindowFilter window;
};

// Block b's lists into s.list (positions relative to it); returns their
// length.
size_t DiskSampler::block_lists(size_t b, BlockScratch& s, bool avx512) const {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    size_t used = 0;
    const size_t c_begin = b * kCellsPerTask, c_end = std::min(cells.size(), c_begin + kCellsPerTask);
    for (size_t ci = c_begin; ci < c_end;) {
        const uint64_t row = cells[ci].key >> 21;
        size_t cj = ci + 1;
        while (cj < c_end && (cells[cj].key >> 21) == row && cells[cj].c[0] <= cells[cj - 1].c[0] + 2) ++cj;
        const uint32_t x_lo = cells[ci].c[0] > 0 ? cells[ci].c[0] - 1 : 0, x_hi = cells[cj - 1].c[0] + 1;
        const size_t span = x_hi - x_lo + 1;
        s.runs.clear();
        s.x_start.assign(span + 1, 0);
        s.rows.cells_in(cells[ci], x_lo, x_hi, [&](uint32_t x, uint32_t begin, uint32_t end) {
            s.runs.push_back({x, begin, end});
            s.x_start[x - x_lo + 1] += end - begin;
        });
        for (size_t x = 0; x < span; ++x) s.x_start[x + 1] += s.x_start[x];
        const size_t count = s.x_start[span];
        if (s.nid.size() < count + kWindowPad) {
            // arrays that only grow (no capacity test per point)
            const size_t grown = std::max(2 * s.nid.size(), count + kWindowPad);
            s.nx.resize(grown), s.ny.resize(grown), s.nz.resize(grown), s.nhash.resize(grown), s.nid.resize(grown);
            s.maybe.resize(grown + 4), s.nd2.resize(grown + 4);
        }
        s.x_fill.assign(s.x_start.begin(), s.x_start.end() - 1);
        for (const BlockScratch::Run& run : s.runs) {
            uint32_t k = s.x_fill[run.x - x_lo];
            for (uint32_t j = run.begin; j < run.end; ++j, ++k) {
                s.nx[k] = sp_[3 * size_t(j)];
                s.ny[k] = sp_[3 * size_t(j) + 1];
                s.nz[k] = sp_[3 * size_t(j) + 2];
                s.nhash[k] = int32_t(uint32_t(order_key_[j] >> 32) ^ 0x80000000u);
                s.nid[k] = j;
            }
            s.x_fill[run.x - x_lo] = k;
        }
        for (size_t k = count; k < count + kWindowPad; ++k) {  // read past the last run, never passed
            s.nx[k] = s.ny[k] = s.nz[k] = INFINITY;
            s.nhash[k] = INT32_MAX;
            s.nid[k] = 0;
        }
        s.window.refresh(s.nx, s.ny, s.nz, s.nhash, s.nid, s.maybe, s.nd2);
        for (; ci < cj; ++ci) {
            const uint32_t x = cells[ci].c[0];
            const size_t w_begin = s.x_start[x > x_lo ? x - 1 - x_lo : 0], w_end = s.x_start[x + 2 - x_lo];
            // room for every point's list to take its whole window and a vector more
            const size_t room = used + size_t(cells[ci].end - cells[ci].begin) * (w_end - w_begin + kWindowPad);
            if (s.list.size() < room) s.list.resize(std::max(2 * s.list.size(), room));
            used = avx512 ? s.window.cell_lists_avx512(cells[ci].begin, cells[ci].end, w_begin, w_end, s.list.data(), used)
                          : s.window.cell_lists_sse2(cells[ci].begin, cells[ci].end, w_begin, w_end, s.list.data(), used);
        }
    }
    return used;
}

// Block b's lists copied to the next free place of nbrs_, or set aside
// (spilled) when nbrs_ is full.
void DiskSampler::store_block(size_t b, const std::vector<uint32_t>& list, size_t used) {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    const size_t c_begin = b * kCellsPerTask, c_end = std::min(cells.size(), c_begin + kCellsPerTask);
    const uint32_t p_begin = cells[c_begin].begin, p_end = cells[c_end - 1].end;
    const size_t at = nbrs_used_.fetch_add(used, std::memory_order_relaxed);
    if (at + used <= capacity_) {
        std::copy(list.data(), list.data() + used, nbrs_.data() + at);
        for (uint32_t i = p_begin; i < p_end; ++i) lists_[i] = {uint32_t(lists_[i].begin + at), uint32_t(lists_[i].end + at)};
        block_at_[b] = at;
    } else {
        spilled_[b].assign(list.data(), list.data() + used);
        block_at_[b] = kSpilled;
        any_spilled_.store(true, std::memory_order_relaxed);
    }
}

// Each point's earlier neighbours closer than the wide radius (the same test
// in double the passes make), per fixed block of cells.  Only earlier ones:
// a point's decision waits on those alone; the list's order, and where it is
// stored, do not matter to any decision.  A neighbour also closer than the
// first narrow radius has kNarrowBit set: the second pass reads that instead
// of computing the distance again.  A block's lists are made in a scratch
// array its task reuses, then copied to the next free place of nbrs_ (fresh
// memory touched once; reserved for `list_capacity` entries per point, far
// more than the ~4.5 a point has on a surface: a mesh with more, e.g. many
// sheets closer than the wide radius, has its lists packed again).
void DiskSampler::find_earlier_neighbours(size_t list_capacity, bool allow_avx512) {
    nblocks_ = (grid_.cells.size() + kCellsPerTask - 1) / kCellsPerTask;
    capacity_ = std::min<size_t>(list_capacity * m_, UINT32_MAX);
    Uninitialised<uint32_t>(capacity_).swap(nbrs_);
    block_at_.assign(nblocks_, 0);
    spilled_.assign(nblocks_, {});
    const bool avx512 = allow_avx512 && WindowFilter::has_avx512();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks_, 1), [&](const tbb::blocked_range<size_t>& br) {
        BlockScratch s{{}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, CellGrid::RowsAround(grid_),
                       WindowFilter{sp_.data(), order_key_.data(), filter_radius2_, sure_wide2_, sure_narrow2_,
                                    not_narrow2_, wide2_, narrow_first2_, lists_.data()}};
        for (size_t b = br.begin(); b < br.end(); ++b) store_block(b, s.list, block_lists(b, s, avx512));
    });
    if (any_spilled_.load()) pack_spilled();
}

// Every block's lists packed again in block order (a block's last point's
// list ends its block's lists).
void DiskSampler::pack_spilled() {
    const std::vector<CellGrid::Cell>& cells = grid_.cells;
    std::vector<uint64_t> packed_at(nblocks_ + 1, 0);
    for (size_t b = 0; b < nblocks_; ++b) {
        const size_t c_end = std::min(cells.size(), (b + 1) * kCellsPerTask);
        packed_at[b + 1] = packed_at[b] + (block_at_[b] == kSpilled ? spilled_[b].size()
                                                                     : lists_[cells[c_end - 1].end - 1].end - block_at_[b]);
    }
    if (packed_at[nblocks_] > UINT32_MAX) throw Error("surfel candidates' neighbour lists too long");
    Uninitialised<uint32_t> packed(packed_at[nblocks_]);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks_, 1), [&](const tbb::blocked_range<size_t>& br) {
        for (size_t b = br.begin(); b < br.end(); ++b) {
            const size_t c_begin = b * kCellsPerTask, c_end = std::min(cells.size(), c_begin + kCellsPerTask);
            const uint64_t from = block_at_[b] == kSpilled ? 0 : block_at_[b];
            const uint32_t* list = block_at_[b] == kSpilled ? spilled_[b].data() : nbrs_.data() + from;
            std::copy(list, list + (packed_at[b + 1] - packed_at[b]), packed.data() + packed_at[b]);
            for (uint32_t i = cells[c_begin].begin; i < cells[c_end - 1].end; ++i)
                lists_[i] = {uint32_t(lists_[i].begin - from + packed_at[b]), uint32_t(lists_[i].end - from + packed_at[b])};
            spilled_[b] = {};
        }
    });
    nbrs_.swap(packed);
}

// Whether point i is decided now (and its state stored): out if one of its
// listed neighbours within the radius is in, else in if none is undecided.
// The states seen are gathered as bits over the whole list, without
// branches that depend on them.
bool DiskSampler::decide(uint32_t i, double radius2, bool every_listed, bool flagged) {
    uint32_t seen = 0;
    const uint32_t a_end = lists_[i].end;
    if (every_listed) {
        for (uint32_t a = lists_[i].begin; a < a_end; ++a)
            seen |= 1u << state_[nbrs_[a] & kPositionBits].load(std::memory_order_relaxed);
    } else if (flagged) {
        for (uint32_t a = lists_[i].begin; a < a_end; ++a)
            seen |= (nbrs_[a] >> 31) << state_[nbrs_[a] & kPositionBits].load(std::memory_order_relaxed);
    } else {
        for (uint32_t a = lists_[i].begin; a < a_end; ++a) {
            const uint32_t j = nbrs_[a] & kPositionBits;
            seen |= uint32_t(dist2(i, j) < radius2) << state_[j].load(std::memory_order_relaxed);
        }
    }
    if (seen & (1u << kIn)) {
        state_[i].store(kOut, std::memory_order_relaxed);
        return true;
    }
    if (seen & (1u << kUndecided)) return false;  // wait for that neighbour
    state_[i].store(kIn, std::memory_order_relaxed);
    return true;
}

// One greedy pass at `radius` over the points whose state is kUndecided
// (the others count as out): afterwards every point is in or out.  The
// lists hold exactly the earlier points closer than the wide radius, so a
// pass at it needs no distance.  The first round goes over every point
// (skipping those decided before the pass), the later ones over the points
// left waiting.  A fixed block of them sweeps its points, then sweeps again
// those still waiting while that decides any (their lists are in cache: a
// point mostly waits on nearby ones, which the block holds); the rest, each
// block's in block order, wait for the next round.
void DiskSampler::greedy_pass(double radius) {
    const double radius2 = radius * radius;
    const bool every_listed = radius == wide_;
    const bool flagged = radius == narrow_first_;
    std::vector<uint32_t> undecided;
    bool first_round = true;
    for (size_t left = m_; left > 0; first_round = false) {
        const size_t n_item = (left + kPointsPerTask - 1) / kPointsPerTask;
        std::vector<std::vector<uint32_t>> waiting_in(n_item);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n_item, 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t item = r.begin(); item < r.end(); ++item) {
                std::vector<uint32_t>& waiting = waiting_in[item];
                const size_t u_end = std::min(left, (item + 1) * kPointsPerTask);
                for (size_t u = item * kPointsPerTask; u < u_end; ++u) {
                    const uint32_t i = first_round ? uint32_t(u) : undecided[u];
                    if (first_round && state_[i].load(std::memory_order_relaxed) != kUndecided) continue;
                    if (!decide(i, radius2, every_listed, flagged)) waiting.push_back(i);
                }
                for (size_t before = 0; !waiting.empty() && waiting.size() != before;) {
                    before = waiting.size();
                    size_t still = 0;
                    for (const uint32_t i : waiting)
                        if (!decide(i, radius2, every_listed, flagged)) waiting[still++] = i;
                    waiting.resize(still);
                }
            }
        });
        undecided.clear();
        for (const std::vector<uint32_t>& waiting : waiting_in) undecided.insert(undecided.end(), waiting.begin(), waiting.end());
        left = undecided.size();
    }
}

// The `count` earliest in the order of the points a pass kept (all of them
// if fewer), in no particular order: sample_surfels orders the surfels by
// itself, and which are the earliest is unique (the keys are).
template <class Kept>
std::vector<uint32_t> DiskSampler::earliest_kept(Kept&& kept, size_t count) const {
    std::vector<uint32_t> out = select_in_order(m_, kept);
    if (out.size() > count) {
        std::nth_element(out.begin(), out.begin() + std::ptrdiff_t(count), out.end(),
                         [this](uint32_t a, uint32_t b) { return earlier(a, b); });
        out.resize(count);
    }
    return out;
}

// The first pass at the wide radius over every point: the earliest `keep`
// of those it keeps.
std::vector<uint32_t> DiskSampler::first_pass(size_t keep) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 8192), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) state_[i].store(kUndecided, std::memory_order_relaxed);
    });
    greedy_pass(wide_);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 8192), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) first_in_[i] = state_[i].load(std::memory_order_relaxed) == kIn;
    });
    return earliest_kept([&](size_t a) { return first_in_[a] != 0; }, keep);
}

// The first pass's points are in from the start: a point closer than the
// narrow radius to one of them (earlier or later) is out.  Earlier ones
// from the point's own list; a kept point marks its own listed (earlier)
// points (stores of one value: the same states at any thread count).  (The
// whole list read without an early exit, and the kept points' marks from
// `chosen`, which holds every one of them here: no branch on a point's
// state to mispredict.)
void DiskSampler::narrow_states(const std::vector<uint32_t>& chosen, int step, double narrow2) {
    // Whether listed entry e of point i is closer than the narrow radius.
    auto within_narrow = [&](uint32_t i, uint32_t e) {
        return step == 0 ? (e & kNarrowBit) != 0 : dist2(i, e & kPositionBits) < narrow2;
    };
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m_, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
            uint32_t out = first_in_[i];
            if (step == 0) {
                for (uint32_t a = lists_[i].begin; a < lists_[i].end; ++a)
                    out |= uint32_t(first_in_[nbrs_[a] & kPositionBits]) & (nbrs_[a] >> 31);
            } else {
                for (uint32_t a = lists_[i].begin; a < lists_[i].end; ++a)
                    out |= uint32_t(first_in_[nbrs_[a] & kPositionBits]) & uint32_t(within_narrow(uint32_t(i), nbrs_[a]));
            }
            state_[i].store(out ? kOut : kUndecided, std::memory_order_relaxed);
        }
    });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, chosen.size(), 1024), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t c = r.begin(); c < r.end(); ++c) {
            const uint32_t j = chosen[c];
            for (uint32_t a = lists_[j].begin; a < lists_[j].end; ++a)
                if (within_narrow(j, nbrs_[a])) state_[nbrs_[a] & kPositionBits].store(kOut, std::memory_order_relaxed);
        }
    });
}

// The second pass over the points left, at the narrow radius, until it
// gives `wanted` more (added to `chosen`); false if it falls short even at
// kDiskRadiusMin.
bool DiskSampler::second_pass(std::vector<uint32_t>& chosen, size_t wanted) {
    for (int step = 0;; ++step) {
        const double narrow = narrow_radius(step, r_max_);
        if (narrow < kDiskRadiusMin * r_max_) return false;
        narrow_states(chosen, step, narrow * narrow);
        greedy_pass(narrow);
        std::vector<uint32_t> second =
            earliest_kept([&](size_t a) { return state_[a].load(std::memory_order_relaxed) == kIn; }, wanted);
        if (second.size() >= wanted) {
            chosen.insert(chosen.end(), second.begin(), second.begin() + std::ptrdiff_t(wanted));
            return true;
        }
    }
}

void DiskSampler::to_input_indices(std::vector<uint32_t>& chosen) const {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, chosen.size(), 8192), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t k = r.begin(); k < r.end(); ++k) chosen[k] = grid_.original[chosen[k]];
    });
}

std::vector<uint32_t> poisson_disk_sample_in(PointsView pts, size_t keep, double r_max, uint64_t seed,
                                             size_t list_capacity, bool allow_avx512) {
    // (sorted positions fit under kNarrowBit: 2^31 candidates are far
    // beyond the memory of any machine this runs on)
    if (pts.size() / 3 >= size_t(kNarrowBit)) throw Error("too many surfel candidates");
    SURFEL_TIMING_START;
    DiskSampler sampler(pts, r_max, seed);
    SURFEL_TIMEPOINT("disk: cells, order");
    sampler.find_earlier_neighbours(list_capacity, allow_avx512);
    SURFEL_TIMEPOINT("lists");
    std::vector<uint32_t> chosen = sampler.first_pass(keep);
    SURFEL_TIMEPOINT("first pass");
    if (chosen.size() < keep && !sampler.second_pass(chosen, keep - chosen.size())) return {};
    SURFEL_TIMEPOINT("second pass");
    sampler.to_input_indices(chosen);
    return chosen;
}

// The candidates of surfel_candidates, written to `position` (3 per
// candidate) and `triangle`; returns the mesh's area.
double fill_candidates(const Mesh& mesh, size_t n, uint64_t seed, float* position, int32_t* triangle);

}  // namespace

std::vector<uint32_t> poisson_disk_sample(const std::vector<float>& pts, size_t keep, double r_max, uint64_t seed,
                                          size_t list_capacity, bool allow_avx512) {
    return poisson_disk_sample_in(pts, keep, r_max, seed, list_capacity, allow_avx512);
}

SurfelCandidates surfel_candidates(const Mesh& mesh, size_t n, uint64_t seed) {
    SurfelCandidates out;
    out.position.resize(3 * kCandidatesPerSurfel * n);
    out.triangle.resize(kCandidatesPerSurfel * n);
    out.area = fill_candidates(mesh, n, seed, out.position.data(), out.triangle.data());
    return out;
}

namespace {

double fill_candidates(const Mesh& mesh, size_t n, uint64_t seed, float* cand, int32_t* cand_tri) {
    const size_t m = mesh.num_triangles();
    const float* V = mesh.vertices.data();
    const int32_t* T = mesh.triangles.data();
    // (kGuideScan entries past the last, at infinity: read by the scan below)
    Uninitialised<double> cum(m + kGuideScan);
    // The corners of each triangle side by side: a candidate falls on a
    // random triangle, and reads one record instead of an index row and
    // three vertex rows at four random places.
    Uninitialised<std::array<float, 9>> corners(m);
    // Each triangle's half cross product length in parallel, then their
    // running sum in order (the same additions as one loop).
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t t = r.begin(); t < r.end(); ++t) {
        const float* a = V + 3 * size_t(T[3 * t]);
        const float* b = V + 3 * size_t(T[3 * t + 1]);
        const float* c = V + 3 * size_t(T[3 * t + 2]);
        for (size_t k = 0; k < 3; ++k) {
            corners[t][k] = a[k];
            corners[t][3 + k] = b[k];
            corners[t][6 + k] = c[k];
        }
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) { e1[k] = double(b[k]) - a[k]; e2[k] = double(c[k]) - a[k]; }
        double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                        e1[0] * e2[1] - e1[1] * e2[0]};
        double len = std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
        cum[t] = 0.5 * len;
    }
    });
    double total = 0;
    for (size_t t = 0; t < m; ++t) {
        total += cum[t];
        cum[t] = total;
    }
    for (size_t t = m; t < m + kGuideScan; ++t) cum[t] = INFINITY;
    // A guide table over the cumulative areas: the triangle of a target is
    // searched only between the answers for the two bucket bounds around it
    // (the same answer as a search of the whole table, found in cache).
    const size_t n_buckets = std::max<size_t>(1, m);
    std::vector<uint32_t> guide(n_buckets + 1);
    const double bucket_area = total / double(n_buckets);
    auto bound = [&](size_t b) { return double(b) * bucket_area; };
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_buckets + 1, 4096), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b)
            guide[b] = uint32_t(std::upper_bound(cum.data(), cum.data() + m, bound(b)) - cum.data());
    });
    const size_t nc = kCandidatesPerSurfel * n;
    const std::array<uint32_t, 2> key{uint32_t(seed), uint32_t(seed >> 32)};
    // Each candidate depends only on (seed, i): generated in parallel, in
    // runs of kCandidateRun, in stages that each start the fetch of what the
    // next reads (a candidate's bucket, cumulative areas and triangle are
    // random places in tables larger than the cache: waited for in turn,
    // those misses were most of the time):
    //   1. the draws and the bucket of the target area (its guide entries fetched);
    //   2. the bucket's first cumulative area fetched;
    //   3. the triangle (its corners fetched);
    //   4. the point.
    constexpr size_t kCandidateRun = 256;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nc, 4096), [&](const tbb::blocked_range<size_t>& range) {
        uint32_t bary[kCandidateRun][2];
        double target[kCandidateRun];
        uint32_t bucket[kCandidateRun];
        for (size_t run = range.begin(); run < range.end(); run += kCandidateRun) {
            const size_t run_end = std::min(range.end(), run + kCandidateRun);
            for (size_t i = run; i < run_end; ++i) {
                const Philox4 r = philox4x32_10({kSamplingIteration, uint32_t(i), uint32_t(uint64_t(i) >> 32), 0}, key);
                // 53-bit uniform for the triangle choice (24 bits are too coarse for
                // very large meshes), 24-bit floats for the barycentrics.
                double u = (double(r[0] >> 5) * 67108864.0 + double(r[1] >> 6)) * (1.0 / 9007199254740992.0);
                const double t = u * total;
                size_t g = size_t(std::clamp(t / total * double(n_buckets), 0.0, double(n_buckets - 1)));
                while (g > 0 && bound(g) > t) --g;                     // bound(g) <= t
                while (g + 1 < n_buckets && !(bound(g + 1) > t)) ++g;  // t < bound(g + 1)
                __builtin_prefetch(&guide[g]);
                target[i - run] = t;
                bucket[i - run] = uint32_t(g);
                bary[i - run][0] = r[2];
                bary[i - run][1] = r[3];
            }
            for (size_t i = run; i < run_end; ++i) {
                __builtin_prefetch(cum.data() + guide[bucket[i - run]]);
                __builtin_prefetch(cum.data() + guide[bucket[i - run]] + kGuideScan - 1);
            }
            for (size_t i = run; i < run_end; ++i) {
                const size_t g = bucket[i - run];
                const double* first = cum.data() + guide[g];
                const double* last = g + 1 < n_buckets ? cum.data() + guide[g + 1] : cum.data() + m;
                // upper_bound's answer: where the bucket holds at most
                // kGuideScan areas (nearly always), counted without
                // branches over kGuideScan of them (those past `last` are
                // above the target: the next bucket's, or the padding);
                // the binary search's branches were mispredicted about once
                // a candidate.
                size_t t;
                if (last - first <= std::ptrdiff_t(kGuideScan)) {
                    size_t below = 0;
                    for (size_t k = 0; k < kGuideScan; ++k) below += !(target[i - run] < first[k]);
                    t = size_t(first - cum.data()) + below;
                } else {
                    t = size_t(std::upper_bound(first, last, target[i - run]) - cum.data());
                }
                if (t >= m) t = m - 1;
                __builtin_prefetch(corners[t].data());
                __builtin_prefetch(corners[t].data() + 8);   // a record may straddle two lines
                cand_tri[i] = int32_t(t);
            }
            for (size_t i = run; i < run_end; ++i) {
                double r1 = std::sqrt(double(u01(bary[i - run][0]))), r2 = u01(bary[i - run][1]);
                double ba = 1.0 - r1, bb = r1 * (1.0 - r2), bc = r1 * r2;
                const float* a = corners[size_t(cand_tri[i])].data();
                const float* b = a + 3;
                const float* c = a + 6;
                for (int k = 0; k < 3; ++k) cand[3 * i + k] = float(ba * a[k] + bb * b[k] + bc * c[k]);
            }
        }
    });
    return total;
}

}  // namespace

namespace {

// Sorts unique (key, index) pairs: put in buckets by the keys' top 16 bits
// that are ever set (counted, then moved), each bucket then sorted by
// itself, in parallel.  The sorted order is unique, so it is the one a
// sort of the whole array gives; the buckets of a surface's Morton keys
// hold a few dozen pairs each, so sorting them bucket by bucket is cheaper
// than a comparison sort of the whole array (bench/RESULTS.md).  Keys crowded into few buckets (a mesh with a
// far outlier) take the parallel sort of the whole array.
void sort_unique_keys(std::vector<std::pair<uint64_t, uint32_t>>& order) {
    constexpr int kBucketBits = 16;
    const size_t n = order.size();
    uint64_t any = 0;
    for (const auto& o : order) any |= o.first;
    const int used = any != 0 ? 64 - __builtin_clzll(any) : 1;
    const int shift = std::max(0, used - kBucketBits);
    const size_t n_buckets = size_t(1) << std::min(used, kBucketBits);
    std::vector<uint32_t> at(n_buckets + 1, 0);
    for (const auto& o : order) ++at[size_t(o.first >> shift) + 1];
    uint32_t largest = 0;
    for (size_t b = 0; b < n_buckets; ++b) {
        largest = std::max(largest, at[b + 1]);
        at[b + 1] += at[b];
    }
    if (largest > n / 8 + 64) {
        tbb::parallel_sort(order.begin(), order.end());
        return;
    }
    std::vector<std::pair<uint64_t, uint32_t>> sorted(n);
    for (const auto& o : order) sorted[at[size_t(o.first >> shift)]++] = o;  // at[b]: now the end of bucket b
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_buckets, 2048), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t b = r.begin(); b < r.end(); ++b) {
            const uint32_t begin = b > 0 ? at[b - 1] : 0;
            if (at[b] - begin > 1) std::sort(sorted.begin() + begin, sorted.begin() + at[b]);
        }
    });
    order.swap(sorted);
}

}  // namespace

SurfelSet sample_surfels(const Mesh& mesh, size_t n, uint64_t seed, const CancelToken& cancel) {
    if (n == 0) throw Error("surfel count must be at least 1");
    const size_t m = mesh.num_triangles();
    Uninitialised<float> tri_normal(3 * m);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t t = r.begin(); t < r.end(); ++t) {
        const float* a = &mesh.vertices[3 * size_t(mesh.triangles[3 * t])];
        const float* b = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + 1])];
        const float* c = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + 2])];
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) { e1[k] = double(b[k]) - a[k]; e2[k] = double(c[k]) - a[k]; }
        double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                        e1[0] * e2[1] - e1[1] * e2[0]};
        double len = std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
        for (int k = 0; k < 3; ++k) tri_normal[3 * t + k] = float(len > 0 ? cr[k] / len : 0.0);
    }
    });
    // The candidates in arrays their parallel loop touches first (vectors
    // would be zeroed in one thread first: ~8 MB at 100,000 surfels).
    const size_t nc = kCandidatesPerSurfel * n;
    Uninitialised<float> cand(3 * nc);
    Uninitialised<int32_t> cand_tri(nc);
    const double area = fill_candidates(mesh, n, seed, cand.data(), cand_tri.data());
    cancel.check("the surfel sampling");
    const PointsView cand_points(cand.data(), nc);
    SurfelSet out;
    out.r_max = std::sqrt(area / (2.0 * std::sqrt(3.0) * double(n)));
    // Should the disk passes fall short (very few surfels on a compact
    // mesh), the weighted elimination picks the n.
    std::vector<uint32_t> kept = poisson_disk_sample_in(cand_points, n, out.r_max, seed, kDiskListCapacity, true);
    cancel.check("the surfel sampling");
    if (kept.size() != n) kept = eliminate_samples_in(cand_points, n, out.r_max);
    cancel.check("the surfel sampling");
    // The kept candidates in ascending order, so that their Morton keys
    // read the candidates' positions in address order (not 100,000 random
    // reads out of 500,000; the keys' sort below makes the surfels' order
    // independent of this one).
    {
        Uninitialised<uint8_t> is_kept(nc);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nc, 16384), [&](const tbb::blocked_range<size_t>& r) {
            std::fill(is_kept.data() + r.begin(), is_kept.data() + r.end(), uint8_t(0));
        });
        tbb::parallel_for(tbb::blocked_range<size_t>(0, kept.size(), 16384), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t a = r.begin(); a < r.end(); ++a) is_kept[kept[a]] = 1;
        });
        kept = select_in_order(nc, [&](size_t i) { return is_kept[i] != 0; });
    }
    // Morton order for locality of surfel rows.
    std::vector<std::pair<uint64_t, uint32_t>> order(kept.size());
    double ext = 0;
    for (int k = 0; k < 3; ++k) ext = std::max(ext, double(mesh.hi[k]) - mesh.lo[k]);
    if (!(ext > 0)) ext = 1;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, kept.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t a = r.begin(); a < r.end(); ++a) {
        uint32_t i = kept[a];
        uint64_t q[3];
        for (int k = 0; k < 3; ++k) {
            double f = (double(cand[3 * size_t(i) + k]) - mesh.lo[k]) / ext;
            q[k] = uint64_t(std::clamp(f, 0.0, 1.0) * 2097151.0);
        }
        order[a] = {expand_bits21(q[0]) | (expand_bits21(q[1]) << 1) | (expand_bits21(q[2]) << 2), i};
    }
    });
    // (key, index) pairs are unique: the order does not depend on kept's.
    sort_unique_keys(order);
    out.position.resize(3 * order.size());
    out.normal.resize(3 * order.size());
    out.triangle.resize(order.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, order.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t a = r.begin(); a < r.end(); ++a) {
        uint32_t i = order[a].second;
        int32_t t = cand_tri[i];
        for (int k = 0; k < 3; ++k) {
            out.position[3 * a + k] = cand[3 * size_t(i) + k];
            out.normal[3 * a + k] = tri_normal[3 * size_t(t) + k];
        }
        out.triangle[a] = t;
    }
    });
    return out;
}

}  // namespace gammart
