// The triangle lookup's pruning test (scene_index.cpp, compute_lookup): a
// surfel y found for a sphere B(c, r) is left out when one of the few
// surfels nearest to c (the "x") is nearer than y everywhere in B, i.e. when
// |c-y|^2 - |c-x|^2 > 2 r |y-x| (plus a margin far above float rounding).
//
// Two forms of the one rule, giving the same answer bit for bit: `never`,
// which tests all the x at once, two to an SSE2 register and without a
// branch per x (the scalar form's branches, taken or not at random, cost
// more than its skipped square roots: the lookup was bound by mispredicted
// branches), and `never_scalar`, the rule as written before, for targets
// without SSE2 and for the tests.  Both do the same double operations in the
// same order (no fused multiply-add at the default target), and a square
// root is correctly rounded packed or not.
#pragma once
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace gammart {

struct LookupPruning {
    // The most x a sphere is tested against.
    static constexpr size_t kNearest = 8;

    // The x of one sphere: position (by axis), distance from the centre and
    // its square, as doubles of the floats the lookup holds.  Slots from n
    // on never decide (their distance is -infinity, so the pair is skipped).
    struct Nearest {
        size_t n = 0;
        alignas(16) double x[3][kNearest];
        alignas(16) double from_c[kNearest];   // sqrt(from_c2)
        alignas(16) double from_c2[kNearest];  // |c - x|^2 (the float, widened)

        // Sets slot k (k < kNearest) to point p at squared distance d2 from c.
        void set(size_t k, const float* p, float d2) {
            for (int a = 0; a < 3; ++a) x[a][k] = double(p[a]);
            from_c2[k] = double(d2);
            from_c[k] = std::sqrt(double(d2));
        }
        // n slots set: the rest made inert.
        void close(size_t count) {
            n = count;
            for (size_t k = count; k < kNearest; ++k) {
                for (int a = 0; a < 3; ++a) x[a][k] = 0.0;
                from_c2[k] = 0.0;
                from_c[k] = -std::numeric_limits<double>::infinity();
            }
        }
    };

    // True when y (position, squared distance cy2 from c as the float the
    // search gave, widened) loses to some x everywhere in B(c, r); `self` is
    // the slot holding y itself (>= kNearest if none), which is never tested.
    static bool never_scalar(const Nearest& X, const float* y, double cy2, size_t self, double r) {
        const double cy = std::sqrt(cy2);
        for (size_t k = 0; k < X.n; ++k) {
            // y can lose to x only if |c-y| + |c-x| > 2r (with
            // |y-x| >= |c-y| - |c-x| the left side is at most 2r|y-x|
            // otherwise, below the right side by the whole margin).
            if (k == self || cy + X.from_c[k] <= 2.0 * r) continue;
            const double ex = double(y[0]) - X.x[0][k], ey = double(y[1]) - X.x[1][k],
                         ez = double(y[2]) - X.x[2][k];
            const double yx = std::sqrt(ex * ex + ey * ey + ez * ez);
            const double scale = r + cy + yx;
            if (cy2 - X.from_c2[k] > 2.0 * r * yx + 1e-3 * scale * scale) return true;
        }
        return false;
    }

    static bool never(const Nearest& X, const float* y, double cy2, size_t self, double r) {
#if defined(__SSE2__)
        const double cy = std::sqrt(cy2);
        const __m128d y0 = _mm_set1_pd(double(y[0])), y1 = _mm_set1_pd(double(y[1])), y2 = _mm_set1_pd(double(y[2]));
        const __m128d vcy = _mm_set1_pd(cy), vcy2 = _mm_set1_pd(cy2), two_r = _mm_set1_pd(2.0 * r),
                      r_cy = _mm_set1_pd(r + cy), milli = _mm_set1_pd(1e-3);
        int mask = 0;
        for (size_t k = 0; k < X.n; k += 2) {
            const __m128d ex = _mm_sub_pd(y0, _mm_load_pd(&X.x[0][k]));
            const __m128d ey = _mm_sub_pd(y1, _mm_load_pd(&X.x[1][k]));
            const __m128d ez = _mm_sub_pd(y2, _mm_load_pd(&X.x[2][k]));
            const __m128d yx =
                _mm_sqrt_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(ex, ex), _mm_mul_pd(ey, ey)), _mm_mul_pd(ez, ez)));
            const __m128d scale = _mm_add_pd(r_cy, yx);
            const __m128d rhs = _mm_add_pd(_mm_mul_pd(two_r, yx), _mm_mul_pd(_mm_mul_pd(milli, scale), scale));
            const __m128d lhs = _mm_sub_pd(vcy2, _mm_load_pd(&X.from_c2[k]));
            // !(cy + |c-x| <= 2r): the scalar form's skip, negated as written
            const __m128d far = _mm_cmpnle_pd(_mm_add_pd(vcy, _mm_load_pd(&X.from_c[k])), two_r);
            mask |= _mm_movemask_pd(_mm_and_pd(_mm_cmpgt_pd(lhs, rhs), far)) << k;
        }
        if (self < kNearest) mask &= ~(1 << self);
        return mask != 0;
#else
        return never_scalar(X, y, cy2, self, r);
#endif
    }
};

}  // namespace gammart
