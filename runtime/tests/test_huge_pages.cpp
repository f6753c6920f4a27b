// HugePageAllocator: blocks of 2 MiB or more on 2 MiB boundaries, smaller
// ones from operator new; every element it hands out is constructed (a
// resize value-initialises: no garbage, not even what the same block held).
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "gamma/huge_pages.h"

using namespace gammart;

namespace {
struct Entry {   // a padded record, as the triangle lookup's heads
    float x = 1.0f, y = 2.0f;
    uint32_t id = 7;
};
template <class T>
using HugeVector = std::vector<T, HugePageAllocator<T>>;
}  // namespace

TEST(HugePageAllocator, LargeBlocksOnHugePageBoundariesSmallOnesAligned) {
    for (size_t n : {size_t(1), size_t(1000), (kHugePageBytes / sizeof(Entry)) - 1, kHugePageBytes / sizeof(Entry),
                     3 * kHugePageBytes / sizeof(Entry) + 5}) {
        HugeVector<Entry> v;
        v.resize(n);
        ASSERT_EQ(v.size(), n);
        const auto at = reinterpret_cast<uintptr_t>(v.data());
        if (n * sizeof(Entry) >= kHugePageBytes) EXPECT_EQ(at % kHugePageBytes, 0u) << n;
        else EXPECT_EQ(at % alignof(Entry), 0u) << n;
        // the whole block is usable: written and read back
        for (size_t i = 0; i < n; ++i) v[i] = Entry{float(i), -float(i), uint32_t(i)};
        for (size_t i = 0; i < n; i += 1 + n / 97) ASSERT_EQ(v[i].id, uint32_t(i));
    }
}

TEST(HugePageAllocator, AResizeConstructsTheNewElementsEvenInTheBlockItHad) {
    const size_t n = kHugePageBytes / sizeof(Entry) + 3;   // a huge-page block
    HugeVector<Entry> v;
    v.assign(n, Entry{5.0f, 6.0f, 9});
    const Entry* block = v.data();
    v.resize(0);
    v.resize(n);                                           // the same block again
    ASSERT_EQ(v.data(), block);
    for (size_t i = 0; i < n; ++i) ASSERT_TRUE(v[i].x == 1.0f && v[i].y == 2.0f && v[i].id == 7u) << i;
    HugeVector<uint64_t> counts;
    counts.assign(1000, ~uint64_t(0));
    counts.resize(0);
    counts.resize(1000);
    for (uint64_t c : counts) ASSERT_EQ(c, 0u);
}

TEST(HugePageAllocator, ConstructionWithAValueStillWritesIt) {
    const size_t n = kHugePageBytes / sizeof(Entry) + 3;   // a huge-page block
    HugeVector<Entry> v;
    v.assign(n, Entry{5.0f, 6.0f, 9});
    for (size_t i = 0; i < n; ++i) ASSERT_TRUE(v[i].x == 5.0f && v[i].y == 6.0f && v[i].id == 9u) << i;
    // growing copies the old elements into the new block
    v[n - 1].id = 42;
    v.resize(3 * n);
    EXPECT_EQ(v[0].id, 9u);
    EXPECT_EQ(v[n - 1].id, 42u);
    v.push_back(Entry{});
    EXPECT_EQ(v.back().id, 7u);   // a default-constructed value, passed in, is written
    HugeVector<uint32_t> filled(1000, 3u);
    for (uint32_t x : filled) ASSERT_EQ(x, 3u);
    // a copy of the vector holds the same values
    const HugeVector<Entry> copy = v;
    EXPECT_EQ(copy[n - 1].id, 42u);
    EXPECT_EQ(copy.size(), v.size());
}
