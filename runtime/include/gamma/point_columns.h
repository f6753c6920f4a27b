// Exact fixed-radius queries over a static point set, for the setup's
// builds (the triangle lookup's candidates, the splat kernel): the points are
// binned into square columns over the two widest axes of their bounding box
// and sorted by the third coordinate within each column, so a query is a few
// binary searches and scans of contiguous memory instead of a kd-tree
// descent.  The answer is the set a nanoflann kd-tree's radius search gives
// (its float metric, term by term, and its strict `<`), so a build can use
// either and get the same result; the search box is padded far beyond float
// rounding, and the final test is that metric itself.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace gammart {

// The column of coordinate x on an axis of `count` columns from lo, each
// 1 / inv_side wide: clamped to [0, count) (NaN: 0).
inline int grid_column(double x, double lo, double inv_side, int count) {
    const double t = std::floor((x - lo) * inv_side);
    if (!(t >= 0)) return 0;  // also NaN
    return t >= double(count - 1) ? count - 1 : int(t);
}

// A column grid over a box lo..hi (per axis): square columns over its two
// widest axes u and v (ties: the lower axis first), points sorted along the
// third, w; nu x nv columns from (lo_u, lo_v), each 1 / inv_side wide.
struct ColumnLayout {
    int u = 0, v = 1, w = 2;
    double lo_u = 0, lo_v = 0, inv_side = 1;
    int nu = 1, nv = 1;
};

// The box's axes by extent, widest first (ties: the lower axis first).
inline void axes_by_extent(const double lo[3], const double hi[3], int axes[3]) {
    axes[0] = 0, axes[1] = 1, axes[2] = 2;
    std::sort(axes, axes + 3, [&](int a, int b) {
        return hi[a] - lo[a] > hi[b] - lo[b] || (hi[a] - lo[a] == hi[b] - lo[b] && a < b);
    });
}

// The layout over lo..hi (axes: axes_by_extent's) of columns `side` wide
// (each caller clamps it to the box first), widened by half again while
// there would be more than about 2 columns per point (n points).
inline ColumnLayout column_layout(const double lo[3], const double hi[3], const int axes[3], double side,
                                  size_t n) {
    ColumnLayout g;
    g.u = axes[0], g.v = axes[1], g.w = axes[2];
    const double eu = hi[g.u] - lo[g.u], ev = hi[g.v] - lo[g.v];
    const double max_columns = 2.0 * double(n) + 64.0;
    while ((std::floor(eu / side) + 1) * (std::floor(ev / side) + 1) > max_columns) side *= 1.5;
    g.lo_u = lo[g.u], g.lo_v = lo[g.v];
    g.inv_side = 1.0 / side;
    g.nu = int(std::floor(eu * g.inv_side)) + 1;
    g.nv = int(std::floor(ev * g.inv_side)) + 1;
    return g;
}

// Points p[3 i .. 3 i + 2], i < n, binned into the nu x nv columns over axes
// u and v (column a * nv + b): start holds each column's first place, then
// the end; id the points column by column, each column in index order.
template <class Ids>
void bin_into_columns(const float* p, size_t n, int u, int v, double lo_u, double lo_v, double inv_side, int nu,
                      int nv, std::vector<uint32_t>& start, Ids& id) {
    const size_t ncol = size_t(nu) * size_t(nv);
    std::unique_ptr<uint32_t[]> col(new uint32_t[n]);
    start.assign(ncol + 1, 0);
    for (size_t i = 0; i < n; ++i) {
        col[i] = uint32_t(size_t(grid_column(double(p[3 * i + size_t(u)]), lo_u, inv_side, nu)) * size_t(nv) +
                          size_t(grid_column(double(p[3 * i + size_t(v)]), lo_v, inv_side, nv)));
        ++start[col[i] + 1];
    }
    for (size_t c = 0; c < ncol; ++c) start[c + 1] += start[c];
    id.resize(n);
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (size_t i = 0; i < n; ++i) id[fill[col[i]]++] = uint32_t(i);
}

class PointColumns {
public:
    // Indexes p[3 i .. 3 i + 2], i < n (copied); `side` is the column width
    // (a little more than the usual query radius works well).  Widened if
    // the box would need too many columns.
    void build(const float* p, size_t n, double side);
    size_t size() const { return n_; }

    // The squared distance from q to point i as nanoflann's L2_Simple_Adaptor
    // measures it (float differences, summed in axis order).
    static float metric(const float q[3], const float* p) {
        float d2 = 0.0f;
        for (int k = 0; k < 3; ++k) {
            const float d = q[k] - p[k];
            d2 += d * d;
        }
        return d2;
    }

    // Calls f(index, d2) for every point with metric(q, p) < r2, in no
    // particular order.
    template <class F>
    void within(const float q[3], float r2, F&& f) const {
        scan(q, r2, [&](uint32_t lo, uint32_t end, float c1) {
            run(q, r2, lo, end, c1, [&](uint32_t k, unsigned, unsigned inside, const float* d2) {
                for (unsigned i = 0; inside >> i; ++i)
                    if ((inside >> i) & 1u) f(id_[k + i], d2[i]);
            });
        });
    }

    // Appends make(index, d2) to `out` for the points `within` finds, in
    // within's order.  Every point scanned is written and the end advanced
    // only past the ones inside: no branch on each point's outcome (taken
    // or not at random, those branches cost more than the writes).
    // (`out`: a std::vector of any allocator.)
    template <class Vector, class Make>
    void append_within(const float q[3], float r2, Vector& out, Make&& make) const {
        using T = typename Vector::value_type;
        size_t n = out.size();
        scan(q, r2, [&](uint32_t lo, uint32_t end, float c1) {
            // room for the column's points and a group's writes past them
            if (out.size() < n + (end - lo) + kGroup) out.resize(std::max(2 * out.size(), n + (end - lo) + kGroup));
            T* o = out.data();
            run(q, r2, lo, end, c1, [&](uint32_t k, unsigned, unsigned inside, const float* d2) {
                for (unsigned i = 0; i < kGroup; ++i) {
                    o[n] = make(id_[k + i], d2[i]);
                    n += (inside >> i) & 1u;
                }
            });
        });
        out.resize(n);
    }

private:
    // Points are scanned kGroup at a time (the metric of four in one SSE
    // register); the arrays hold kGroup - 1 entries of padding past the
    // last point, so that a group may read past a column's end.
    static constexpr unsigned kGroup = 4;
    // Columns of at most this many points are scanned whole (see scan).
    static constexpr uint32_t kScannedColumn = 16;

    // The points a column's scan visits: from lo while k < end and the key
    // is not past c1 (the scalar loop's condition, NaN keys included).
    // each(k, lanes, inside, d2) per group of points k .. k + kGroup - 1:
    // `lanes` has bit i set for the ones visited, `inside` for those of
    // them with metric < r2, whose distances are d2[i].  The same float
    // operations as metric(), lane by lane (sums in axis order; the first
    // term's 0 + d*d is d*d exactly).
    template <class Each>
    void run(const float q[3], float r2, uint32_t lo, uint32_t end, float c1, Each&& each) const {
#if defined(__SSE2__)
        const __m128 qx = _mm_set1_ps(q[0]), qy = _mm_set1_ps(q[1]), qz = _mm_set1_ps(q[2]);
        const __m128 vr2 = _mm_set1_ps(r2), vc1 = _mm_set1_ps(c1);
        for (uint32_t k = lo; k < end; k += kGroup) {
            const __m128 dx = _mm_sub_ps(qx, _mm_loadu_ps(&x_[k]));
            const __m128 dy = _mm_sub_ps(qy, _mm_loadu_ps(&y_[k]));
            const __m128 dz = _mm_sub_ps(qz, _mm_loadu_ps(&z_[k]));
            const __m128 d2 = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy)), _mm_mul_ps(dz, dz));
            unsigned lanes = end - k >= kGroup ? (1u << kGroup) - 1 : (1u << (end - k)) - 1;
            const unsigned past = unsigned(_mm_movemask_ps(_mm_cmpgt_ps(_mm_loadu_ps(&key_[k]), vc1)));
            if (past) lanes &= (past & (0u - past)) - 1;   // the lanes before the first key past c1
            const unsigned inside = unsigned(_mm_movemask_ps(_mm_cmplt_ps(d2, vr2))) & lanes;
            alignas(16) float d[kGroup];
            _mm_store_ps(d, d2);
            each(k, lanes, inside, d);
            if (past) break;
        }
#else
        for (uint32_t k = lo; k < end; k += kGroup) {
            unsigned lanes = 0, inside = 0;
            float d[kGroup] = {};
            for (unsigned i = 0; i < kGroup && k + i < end && !(key_[k + i] > c1); ++i) {
                const float p[3] = {x_[k + i], y_[k + i], z_[k + i]};
                d[i] = metric(q, p);
                lanes |= 1u << i;
                inside |= unsigned(d[i] < r2) << i;
            }
            each(k, lanes, inside, d);
            if (lanes != (1u << kGroup) - 1) break;
        }
#endif
    }

    // visit(lo, end, c1) for each column the query's box meets: lo is its
    // first point with a key at least the box's lower end in w, end the
    // column's end; the caller scans from lo while the key is <= c1.
    template <class Visit>
    void scan(const float q[3], float r2, Visit&& visit) const {
        if (n_ == 0 || !(r2 > 0)) return;
        // |q_k - p_k| <= sqrt(d2) * (1 + 2e-7) for the float metric: a pad
        // of 1e-5 relative covers it many times over.
        const double reach = std::sqrt(double(r2)) * (1.0 + 1e-5) + 1e-30;
        const double a = double(q[u_]), b = double(q[v_]), c = double(q[w_]);
        const int i0 = column_of(a - reach, lo_u_, nu_), i1 = column_of(a + reach, lo_u_, nu_);
        const int j0 = column_of(b - reach, lo_v_, nv_), j1 = column_of(b + reach, lo_v_, nv_);
        const float c0 = float(c - reach), c1 = float(c + reach);
        for (int i = i0; i <= i1; ++i)
            for (int j = j0; j <= j1; ++j) {
                const size_t col = size_t(i) * size_t(nv_) + size_t(j);
                const uint32_t begin = start_[col], end = start_[col + 1];
                if (begin == end) continue;
                // A short column is scanned from its start: its points
                // below c0 are outside the query's box, so they fail the
                // metric's test (the same points found, in the same order),
                // and their scan costs less than a search's chain of
                // dependent loads.  (Only with every key finite: the keys
                // are then sorted by `<`, so none before c0 stops the scan.)
                if (end - begin <= kScannedColumn && finite_keys_) {
                    visit(begin, end, c1);
                    continue;
                }
                // the first point with key >= c0 (keys: the third
                // coordinate), by halving without a branch on the
                // comparisons (a conditional move each)
                const float* base = key_.data() + begin;
                for (uint32_t len = end - begin; len > 1;) {
                    const uint32_t half = len / 2;
                    base = base[half] < c0 ? base + half : base;
                    len -= half;
                }
                visit(uint32_t(base - key_.data()) + (*base < c0 ? 1u : 0u), end, c1);
            }
    }

    int column_of(double x, double lo, int n) const { return grid_column(x, lo, inv_side_, n); }

    int u_ = 0, v_ = 1, w_ = 2;  // column axes, sorted axis
    int nu_ = 1, nv_ = 1;
    double lo_u_ = 0, lo_v_ = 0, inv_side_ = 1;
    std::vector<uint32_t> start_;  // per column (u major), then the end
    // per point, sorted (each with kGroup - 1 entries of padding after):
    std::vector<float> key_;       // the w coordinate (rounded down to float: exact)
    std::vector<float> x_, y_, z_;  // the position
    std::vector<uint32_t> id_;     // the original index
    size_t n_ = 0;
    bool finite_keys_ = false;
};

}  // namespace gammart
