#include <gtest/gtest.h>

#include "gamma/philox.h"

using namespace gammart;

TEST(Philox, KnownAnswerZero) {
    Philox4 r = philox4x32_10({0, 0, 0, 0}, {0, 0});
    EXPECT_EQ(r[0], 0x6627e8d5u);
    EXPECT_EQ(r[1], 0xe169c58du);
    EXPECT_EQ(r[2], 0xbc57ac4cu);
    EXPECT_EQ(r[3], 0x9b00dbd8u);
}

TEST(Philox, KnownAnswerOnes) {
    Philox4 r = philox4x32_10({0xffffffffu, 0xffffffffu, 0xffffffffu, 0xffffffffu}, {0xffffffffu, 0xffffffffu});
    EXPECT_EQ(r[0], 0x408f276du);
    EXPECT_EQ(r[1], 0x41c83b0eu);
    EXPECT_EQ(r[2], 0xa20bc7c6u);
    EXPECT_EQ(r[3], 0x6d5451fdu);
}

TEST(Philox, KnownAnswerPi) {
    Philox4 r = philox4x32_10({0x243f6a88u, 0x85a308d3u, 0x13198a2eu, 0x03707344u}, {0xa4093822u, 0x299f31d0u});
    EXPECT_EQ(r[0], 0xd16cfe09u);
    EXPECT_EQ(r[1], 0x94fdccebu);
    EXPECT_EQ(r[2], 0x5001e420u);
    EXPECT_EQ(r[3], 0x24126ea1u);
}

TEST(Philox, UniformBounds) {
    EXPECT_EQ(u01(0u), 0.0f);
    EXPECT_EQ(u01(0xFFu), 0.0f);
    EXPECT_LT(u01(0xFFFFFFFFu), 1.0f);
    EXPECT_EQ(u01(0xFFFFFFFFu), 1.0f - 1.0f / 16777216.0f);
    EXPECT_EQ(u01(0x80000000u), 0.5f);
}

TEST(Philox, StreamUsesCounterLayout) {
    // Counter = (iteration, index_lo, index_hi, draw); key = seed (lo, hi).
    const uint64_t seed = 0x123456789abcdef0ULL;
    const uint64_t index = 0x0000000500000007ULL;
    PhiloxStream s(seed, 3, index);
    Philox4 b0 = philox4x32_10({3, 7, 5, 0}, {0x9abcdef0u, 0x12345678u});
    Philox4 b1 = philox4x32_10({3, 7, 5, 1}, {0x9abcdef0u, 0x12345678u});
    for (int i = 0; i < 4; ++i) EXPECT_EQ(s.next_u32(), b0[i]);
    for (int i = 0; i < 4; ++i) EXPECT_EQ(s.next_u32(), b1[i]);
}

TEST(Philox, UniformMean) {
    PhiloxStream s(42, 0, 0);
    double sum = 0;
    float lo = 1, hi = 0;
    const int n = 1 << 20;
    for (int i = 0; i < n; ++i) {
        float u = s.next();
        sum += u;
        lo = std::min(lo, u);
        hi = std::max(hi, u);
    }
    EXPECT_NEAR(sum / n, 0.5, 2e-3);
    EXPECT_GE(lo, 0.0f);
    EXPECT_LT(hi, 1.0f);
}

