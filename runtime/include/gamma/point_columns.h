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
#include <vector>

namespace gammart {

class PointColumns {
public:
    // Indexes p[3 i .. 3 i + 2], i < n (copied); `side` is the column width
    // (a little more than the usual query radius works well).  Widened if
    // the box would need too many columns.
    void build(const float* p, size_t n, double side);
    size_t size() const { return id_.size(); }

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
            for (uint32_t k = lo; k < end && !(key_[k] > c1); ++k) {
                const float d2 = metric(q, &pos_[3 * size_t(k)]);
                if (d2 < r2) f(id_[k], d2);
            }
        });
    }

    // Appends make(index, d2) to `out` for the points `within` finds, in
    // within's order.  Every point scanned is written and the end advanced
    // only past the ones inside: no branch on each point's outcome (taken
    // or not at random, those branches cost more than the writes).
    template <class T, class Make>
    void append_within(const float q[3], float r2, std::vector<T>& out, Make&& make) const {
        size_t n = out.size();
        scan(q, r2, [&](uint32_t lo, uint32_t end, float c1) {
            if (out.size() < n + (end - lo)) out.resize(std::max(2 * out.size(), n + (end - lo)));
            T* o = out.data();
            for (uint32_t k = lo; k < end && !(key_[k] > c1); ++k) {
                const float d2 = metric(q, &pos_[3 * size_t(k)]);
                o[n] = make(id_[k], d2);
                n += d2 < r2;
            }
        });
        out.resize(n);
    }

private:
    // visit(lo, end, c1) for each column the query's box meets: lo is its
    // first point with a key at least the box's lower end in w, end the
    // column's end; the caller scans from lo while the key is <= c1.
    template <class Visit>
    void scan(const float q[3], float r2, Visit&& visit) const {
        if (id_.empty() || !(r2 > 0)) return;
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

    int column_of(double x, double lo, int n) const {
        const double t = std::floor((x - lo) * inv_side_);
        if (!(t >= 0)) return 0;  // also NaN
        return t >= double(n - 1) ? n - 1 : int(t);
    }

    int u_ = 0, v_ = 1, w_ = 2;  // column axes, sorted axis
    int nu_ = 1, nv_ = 1;
    double lo_u_ = 0, lo_v_ = 0, inv_side_ = 1;
    std::vector<uint32_t> start_;  // per column (u major), then the end
    std::vector<float> key_;       // sorted: the w coordinate (rounded down to float: exact)
    std::vector<float> pos_;       // sorted positions
    std::vector<uint32_t> id_;     // sorted: original index
};

}  // namespace gammart
