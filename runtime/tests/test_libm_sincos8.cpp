// sincosf8 against the C library's sinf / cosf: the emission's outputs stay
// the same bits only if every angle it can form gives the libm's answer.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>

#include "gamma/libm_sincos8.h"
#include "gamma/sampling.h"

using namespace gammart;

namespace {
bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// Lanes of x whose sine or cosine differ from std::sin / std::cos.
int differing_lanes(const float x[8]) {
    float s[8], c[8];
    sincosf8(x, s, c);
    int bad = 0;
    for (int j = 0; j < 8; ++j) bad += !same_bits(s[j], std::sin(x[j])) || !same_bits(c[j], std::cos(x[j]));
    return bad;
}
}  // namespace

// Where glibc runs its FMA variant (AVX2 and FMA), sincosf8 must be usable:
// otherwise the emission silently keeps the slow scalar calls.
TEST(LibmSincos8, UsableWhereGlibcHasItsFmaVariant) {
#if defined(__GLIBC__) && defined(__x86_64__)
    const bool fma_variant = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    EXPECT_EQ(sincosf8_matches_libm(), fma_variant);
#else
    EXPECT_FALSE(sincosf8_matches_libm() && !__builtin_cpu_supports("fma"));
#endif
}

// Every angle the emission forms, 2 pi u for u = m 2^-24 (m < 2^24, the
// uniform_sphere / around azimuths): all 16,777,216 of them.
TEST(LibmSincos8, EqualsLibmOnEveryEmissionAngle) {
    if (!sincosf8_matches_libm()) {
        EXPECT_FALSE(__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"));
        return;
    }
    int64_t differ = 0, compared = 0;
    float x[8];
    for (uint32_t m0 = 0; m0 < (1u << 24); m0 += 8) {
        for (uint32_t j = 0; j < 8; ++j) x[j] = kTwoPi * (float(m0 + j) * (1.0f / 16777216.0f));
        differ += differing_lanes(x);
        compared += 8;
    }
    EXPECT_EQ(compared, int64_t(1) << 24);
    EXPECT_EQ(differ, 0);
}

// Any other float it handles itself (|x| < 120, both signs, the quadrant
// boundaries, tiny and subnormal values), and the lanes it hands to the
// libm (|x| >= 120, inf, nan).
TEST(LibmSincos8, EqualsLibmElsewhere) {
    if (!sincosf8_matches_libm()) {
        EXPECT_FALSE(__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"));
        return;
    }
    std::mt19937 gen(7);
    std::uniform_real_distribution<float> wide(-119.9f, 119.9f);
    std::uniform_int_distribution<uint32_t> bits(0, 0xFFFFFFFFu);
    int64_t differ = 0;
    float x[8];
    for (int k = 0; k < (1 << 19); ++k) {
        for (int j = 0; j < 8; ++j) x[j] = wide(gen);
        differ += differing_lanes(x);
        for (int j = 0; j < 8; ++j) {  // any bit pattern below 120 in magnitude
            uint32_t b = bits(gen);
            std::memcpy(&x[j], &b, sizeof b);
            if (!(std::fabs(x[j]) < 120.0f)) x[j] = std::fmod(std::fabs(x[j]) < INFINITY ? x[j] : 1.0f, 120.0f);
        }
        differ += differing_lanes(x);
    }
    for (int q = -80; q <= 80; ++q) {  // near multiples of pi/4
        const float at = float(q) * 0.78539816339744831f;
        float y = at;
        for (int j = 0; j < 4; ++j) y = std::nextafter(y, -INFINITY);
        for (int j = 0; j < 8; ++j, y = std::nextafter(y, INFINITY)) x[j] = y;
        differ += differing_lanes(x);
    }
    const float special[][8] = {
        {0.0f, -0.0f, 1e-45f, -1e-45f, 1e-38f, 0x1p-12f, -0x1p-12f, std::nextafter(0x1p-12f, 0.0f)},
        {120.0f, -120.0f, 1e6f, -3e30f, INFINITY, -INFINITY, NAN, 1.0f},
        {119.99999f, 1.0f, 2.0f, 3.0f, 100.0f, 1000.0f, 0.5f, -0.5f},
    };
    for (const auto& row : special) {
        float s[8], c[8];
        sincosf8(row, s, c);
        for (int j = 0; j < 8; ++j) {
            const float ls = std::sin(row[j]), lc = std::cos(row[j]);
            differ += !(same_bits(s[j], ls) || (std::isnan(s[j]) && std::isnan(ls))) ||
                      !(same_bits(c[j], lc) || (std::isnan(c[j]) && std::isnan(lc)));
        }
    }
    EXPECT_EQ(differ, 0);
}
