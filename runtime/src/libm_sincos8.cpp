// Eight sines and cosines as glibc's __sincosf_fma computes them (see
// gamma/libm_sincos8.h).  The operations below are those of that function's
// object code in glibc 2.36 (x86-64), lane by lane: each lane is widened to
// double, reduced by the nearest multiple n of pi/2 with one fused
// multiply-add, and evaluated by the sine and cosine polynomials of the
// reduced x with the fused multiply-adds glibc's compiled code makes, the
// two swapped where n is odd and the cosine's coefficients negated where n & 2.
#include "gamma/libm_sincos8.h"

#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "gamma/sampling.h"

namespace gammart {

namespace {

// glibc's __sincosf_table[0] (sysdeps/ieee754/flt-32/s_sincosf_data.c);
// table[1] is the same with the cosine's coefficients negated.
constexpr double kHalfPiInvScaled = 0x1.45f306dc9c883p+23;  // 2/pi * 2^24: n in bits 24..31
constexpr double kHalfPi = 0x1.921fb54442d18p+0;
constexpr double kC0 = 1.0, kC1 = -0x1.ffffffd0c621cp-2, kC2 = 0x1.55553e1068f19p-5, kC3 = -0x1.6c087e89a359dp-10,
                 kC4 = 0x1.99343027bf8c3p-16;
constexpr double kS1 = -0x1.555545995a603p-3, kS2 = 0x1.1107605230bc4p-7, kS3 = -0x1.994eb3774cf24p-13;

// v, negated in the lanes where neg has the sign bit.
__attribute__((target("avx2,fma"))) inline __m256d signed_by(double v, __m256d neg) {
    return _mm256_xor_pd(_mm256_set1_pd(v), neg);
}

// Four lanes: glibc's path for 2^-12 <= |y| < 120, which for |y| < pi/4
// (n = 0) is also its small-argument path, operation for operation.
__attribute__((target("avx2,fma"))) inline void sincos4(__m128 y, __m128& sin_out, __m128& cos_out) {
    const __m256d x = _mm256_cvtps_pd(y);
    const __m256d r = _mm256_mul_pd(x, _mm256_set1_pd(kHalfPiInvScaled));
    // n = ((int32_t) r + 0x800000) >> 24: truncation, then an arithmetic shift
    const __m128i n = _mm_srai_epi32(_mm_add_epi32(_mm256_cvttpd_epi32(r), _mm_set1_epi32(0x800000)), 24);
    const __m256d xr = _mm256_fnmadd_pd(_mm256_cvtepi32_pd(n), _mm256_set1_pd(kHalfPi), x);  // x - n pi/2
    // sign[n & 3] = {1, -1, -1, 1}: a product by -1 is exact, a sign flip
    const __m128i one = _mm_set1_epi32(1);
    const __m128i flip = _mm_and_si128(_mm_xor_si128(n, _mm_srli_epi32(n, 1)), one);
    const __m256d sign_bit = _mm256_castsi256_pd(_mm256_slli_epi64(_mm256_cvtepu32_epi64(flip), 63));
    const __m256d X = _mm256_xor_pd(xr, sign_bit);
    const __m256d X2 = _mm256_mul_pd(xr, xr);
    // where n & 2: the second table, -cos's coefficients
    const __m128i second = _mm_and_si128(_mm_srli_epi32(n, 1), one);
    const __m256d neg_c = _mm256_castsi256_pd(_mm256_slli_epi64(_mm256_cvtepu32_epi64(second), 63));
    const __m256d s1 = _mm256_fmadd_pd(X2, _mm256_set1_pd(kS3), _mm256_set1_pd(kS2));
    const __m256d c2 = _mm256_fmadd_pd(X2, signed_by(kC4, neg_c), signed_by(kC3, neg_c));
    const __m256d x3 = _mm256_mul_pd(X2, X), x4 = _mm256_mul_pd(X2, X2);
    const __m256d x5 = _mm256_mul_pd(X2, x3), x6 = _mm256_mul_pd(X2, x4);
    const __m256d c1 = _mm256_fmadd_pd(X2, signed_by(kC1, neg_c), signed_by(kC0, neg_c));
    const __m256d s = _mm256_fmadd_pd(x3, _mm256_set1_pd(kS1), X);
    const __m256d cc = _mm256_fmadd_pd(x4, signed_by(kC2, neg_c), c1);
    const __m128 sin_poly = _mm256_cvtpd_ps(_mm256_fmadd_pd(s1, x5, s));
    const __m128 cos_poly = _mm256_cvtpd_ps(_mm256_fmadd_pd(c2, x6, cc));
    // odd n: the polynomials swap
    const __m128 odd = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(n, one), one));
    __m128 sn = _mm_blendv_ps(sin_poly, cos_poly, odd), cs = _mm_blendv_ps(cos_poly, sin_poly, odd);
    // |y| < 2^-12 (abstop12 below 0x398): sin y = y, cos y = 1
    const __m128i abs_bits = _mm_and_si128(_mm_castps_si128(y), _mm_set1_epi32(0x7fffffff));
    const __m128 tiny = _mm_castsi128_ps(_mm_cmplt_epi32(abs_bits, _mm_set1_epi32(0x39800000)));
    sin_out = _mm_blendv_ps(sn, y, tiny);
    cos_out = _mm_blendv_ps(cs, _mm_set1_ps(1.0f), tiny);
}

__attribute__((target("avx2,fma"))) void sincos8_avx2(const float x[8], float sin_out[8], float cos_out[8]) {
    const __m256 y = _mm256_loadu_ps(x);
    // glibc's other paths (|y| >= 120: the long reduction; inf, nan): the libm calls
    const __m256 abs_y = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), y);
    if (_mm256_movemask_ps(_mm256_cmp_ps(abs_y, _mm256_set1_ps(120.0f), _CMP_LT_OQ)) != 0xFF) {
        for (int j = 0; j < 8; ++j) {
            sin_out[j] = std::sin(x[j]);
            cos_out[j] = std::cos(x[j]);
        }
        return;
    }
    __m128 s_lo, c_lo, s_hi, c_hi;
    sincos4(_mm256_castps256_ps128(y), s_lo, c_lo);
    sincos4(_mm256_extractf128_ps(y, 1), s_hi, c_hi);
    _mm_storeu_ps(sin_out, s_lo);
    _mm_storeu_ps(sin_out + 4, s_hi);
    _mm_storeu_ps(cos_out, c_lo);
    _mm_storeu_ps(cos_out + 4, c_hi);
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// The angles the emission forms, 2 pi u with u = m 2^-24: 4,097 spread over
// the turn (and its end), and the 64 smallest.
bool check_against_libm() {
    float x[8], s[8], c[8];
    int filled = 0;
    bool same = true;
    auto flush = [&] {
        sincos8_avx2(x, s, c);
        for (int j = 0; j < filled; ++j)
            same = same && same_bits(s[j], std::sin(x[j])) && same_bits(c[j], std::cos(x[j]));
        filled = 0;
    };
    auto add = [&](uint32_t m) {
        x[filled++] = kTwoPi * (float(m) * (1.0f / 16777216.0f));
        if (filled == 8) flush();
    };
    for (uint32_t k = 0; k <= 4096; ++k) add(std::min<uint32_t>(k * 4096u + (k * 2654435761u >> 20), 16777215u));
    for (uint32_t m = 0; m < 64; ++m) add(m);
    for (int j = filled; j < 8; ++j) x[j] = 0.0f;
    if (filled) flush();
    return same;
}

}  // namespace

bool sincosf8_matches_libm() {
    static const bool yes = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && check_against_libm();
    return yes;
}

void sincosf8(const float x[8], float sin_out[8], float cos_out[8]) { sincos8_avx2(x, sin_out, cos_out); }

}  // namespace gammart
