// The triangle lookup's pruning test (scene_index.cpp, compute_lookup): a
// surfel y found for a sphere B(c, r) is left out when one of the few
// surfels nearest to c (the "x") is nearer than y everywhere in B, i.e. when
// |c-y|^2 - |c-x|^2 > 2 r |y-x| (plus a margin far above float rounding).
//
// Three forms of the one rule, giving the same answer bit for bit: `never`,
// which tests all the x at once, two to an SSE2 register and without a
// branch per x (the scalar form's branches, taken or not at random, cost
// more than its skipped square roots: the lookup was bound by mispredicted
// branches); `never_avx512`, the same on all eight x in one AVX-512
// register, for CPUs that have it (`keep` chooses at run time); and
// `never_scalar`, the rule as written before, for targets without SSE2 and
// for the tests.  All do the same double operations in the same order (no
// fused multiply-add: the files that include this are compiled with
// -ffp-contract=off), and a square root is correctly rounded packed or not.
#pragma once
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define GAMMA_LOOKUP_PRUNING_AVX512 1
#endif

namespace gammart {

// A surfel the lookup found for a sphere, as one word that orders as the
// pair (squared distance from the centre, point index) does, distance
// first: the bits of a float >= +0 order as the float (the distances are
// sums of squares, never -0 or NaN).  The lookup sorts and selects these
// words instead of pairs under a two-key comparison.
inline uint64_t distance_key(float d2, uint32_t i) {
    uint32_t bits;
    std::memcpy(&bits, &d2, sizeof bits);
    return (uint64_t(bits) << 32) | i;
}
inline float key_distance(uint64_t key) {
    const uint32_t bits = uint32_t(key >> 32);
    float d2;
    std::memcpy(&d2, &bits, sizeof d2);
    return d2;
}
inline uint32_t key_index(uint64_t key) { return uint32_t(key); }

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

#if defined(GAMMA_LOOKUP_PRUNING_AVX512)
    // `never` on all eight slots at once (slots from X.n on never decide).
    [[gnu::target("avx512f")]] static bool never_avx512(const Nearest& X, const float* y, double cy2, size_t self,
                                                        double r) {
        const double cy = std::sqrt(cy2);
        const __m512d ex = _mm512_sub_pd(_mm512_set1_pd(double(y[0])), _mm512_loadu_pd(X.x[0]));
        const __m512d ey = _mm512_sub_pd(_mm512_set1_pd(double(y[1])), _mm512_loadu_pd(X.x[1]));
        const __m512d ez = _mm512_sub_pd(_mm512_set1_pd(double(y[2])), _mm512_loadu_pd(X.x[2]));
        // (the zero-masking form with every lane on: GCC 12 warns about the
        // undefined source operand of the plain _mm512_sqrt_pd)
        const __m512d yx = _mm512_maskz_sqrt_pd(
            __mmask8(0xFF), _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(ex, ex), _mm512_mul_pd(ey, ey)),
                                          _mm512_mul_pd(ez, ez)));
        const __m512d scale = _mm512_add_pd(_mm512_set1_pd(r + cy), yx);
        const __m512d rhs = _mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(2.0 * r), yx),
                                          _mm512_mul_pd(_mm512_mul_pd(_mm512_set1_pd(1e-3), scale), scale));
        const __m512d lhs = _mm512_sub_pd(_mm512_set1_pd(cy2), _mm512_loadu_pd(X.from_c2));
        const __mmask8 far = _mm512_cmp_pd_mask(_mm512_add_pd(_mm512_set1_pd(cy), _mm512_loadu_pd(X.from_c)),
                                                _mm512_set1_pd(2.0 * r), _CMP_NLE_UQ);
        unsigned mask = unsigned(_mm512_cmp_pd_mask(lhs, rhs, _CMP_GT_OS) & far);
        if (self < kNearest) mask &= ~(1u << self);
        return mask != 0;
    }
    static bool has_avx512() {
        static const bool has = __builtin_cpu_supports("avx512f");
        return has;
    }
#endif

    // The surfels of found[0, n) (distance_key words from the sphere's
    // centre; `points` holds their positions, 3 per point index) that no x
    // beats everywhere in B(c, r), in their order, written to kept (room
    // for n); X's slots hold found[0, X.n).  Returns how many were kept.
    static size_t keep(const Nearest& X, const uint64_t* found, size_t n, const float* points, double r,
                       uint64_t* kept) {
#if defined(GAMMA_LOOKUP_PRUNING_AVX512)
        if (has_avx512()) return keep_avx512(X, found, n, points, r, kept);
#endif
        return keep_with(X, found, n, points, r, kept, &never);
    }

private:
    // Every entry is written and the cursor advanced past the kept ones (no
    // branch on the outcome).  Always inlined, so that in keep_avx512 the
    // test it is given is inlined too (under that function's target).
    template <class Never>
    [[gnu::always_inline]] static inline size_t keep_with(const Nearest& X, const uint64_t* found, size_t n,
                                                          const float* points, double r, uint64_t* kept,
                                                          Never test) {
        size_t n_kept = 0;
        for (size_t p = 0; p < n; ++p) {
            const uint64_t f = found[p];
            kept[n_kept] = f;
            n_kept += !test(X, points + 3 * size_t(key_index(f)), double(key_distance(f)), p, r);
        }
        return n_kept;
    }
#if defined(GAMMA_LOOKUP_PRUNING_AVX512)
    [[gnu::target("avx512f")]] static size_t keep_avx512(const Nearest& X, const uint64_t* found, size_t n,
                                                         const float* points, double r, uint64_t* kept) {
        return keep_with(X, found, n, points, r, kept, &never_avx512);
    }
#endif
};

}  // namespace gammart
