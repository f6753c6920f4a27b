// FalseColourView's bytes (the cache of views, gamma/driver/view_cache.py):
// read back they give the same view, and no damaged or cut copy is read past
// its end or gives a neighbour that is not a surfel (run under ASan/UBSan).
#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include "gamma/renderer.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;

namespace {

FalseColourView cast(const Simulation& sim) {
    return sim.false_colour_view({0.3f, 0.4f, 3.0f}, {0, 0, 0}, {0, 1, 0}, 45.0f, 24, 20, 2);
}

Simulation* sphere_simulation() {
    static const Mesh mesh = gamma_test::icosphere(2);
    Config c;
    c.surfels = 500;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 1}};
    static Simulation sim(mesh, c);
    return &sim;
}

}  // namespace

TEST(FalseColourViewBytes, ReadBackTheSameView) {
    const FalseColourView view = cast(*sphere_simulation());
    size_t hits = 0;
    for (uint8_t c : view.count) hits += c != FalseColourView::kMissed;
    ASSERT_GT(hits, 0u);
    ASSERT_LT(hits, view.count.size());               // the sphere and the background
    const std::vector<uint8_t> bytes = view.to_bytes();
    const FalseColourView back = FalseColourView::from_bytes(bytes.data(), bytes.size());
    EXPECT_EQ(back.width, view.width);
    EXPECT_EQ(back.height, view.height);
    EXPECT_EQ(back.surfels, view.surfels);
    EXPECT_EQ(back.count, view.count);
    EXPECT_EQ(back.first, view.first);
    EXPECT_EQ(back.index, view.index);
    EXPECT_EQ(0, std::memcmp(back.weight.data(), view.weight.data(), view.weight.size() * sizeof(double)));
    EXPECT_EQ(0, std::memcmp(back.shade.data(), view.shade.data(), view.shade.size() * sizeof(float)));
    std::vector<float> values(view.surfels);
    for (size_t i = 0; i < values.size(); ++i) values[i] = float(i % 17) * 0.25f;
    for (size_t px = 0; px < view.count.size(); ++px) {
        const float a = view.value(px, values.data()), b = back.value(px, values.data());
        EXPECT_TRUE(std::memcmp(&a, &b, sizeof a) == 0) << px;
    }
    EXPECT_EQ(back.to_bytes(), bytes);
}

TEST(FalseColourViewBytes, DamagedOrCutBytesAreRefusedOrSafe) {
    const FalseColourView view = cast(*sphere_simulation());
    const std::vector<uint8_t> bytes = view.to_bytes();
    auto safe = [&](const std::vector<uint8_t>& data) {
        try {
            const FalseColourView v = FalseColourView::from_bytes(data.data(), data.size());
            for (size_t px = 0; px < v.count.size(); ++px) {
                if (v.count[px] == FalseColourView::kMissed) continue;
                ASSERT_LE(v.count[px], size_t(kSmoothingNeighbours));
                ASSERT_LE(size_t(v.first[px]) + v.count[px], v.index.size());
                for (size_t j = 0; j < v.count[px]; ++j) ASSERT_LT(v.index[v.first[px] + j], v.surfels);
            }
            EXPECT_EQ(v.count.size(), size_t(v.width) * size_t(v.height));
        } catch (const Error&) {
        }
    };
    for (size_t n = 0; n < bytes.size(); n += 7) safe(std::vector<uint8_t>(bytes.begin(), bytes.begin() + long(n)));
    size_t refused = 0;
    for (size_t k = 0; k < bytes.size(); k += 3) {
        std::vector<uint8_t> damaged = bytes;
        damaged[k] ^= 0xA5;
        safe(damaged);
        try {
            FalseColourView::from_bytes(damaged.data(), damaged.size());
        } catch (const Error&) {
            ++refused;
        }
    }
    EXPECT_GT(refused, 0u);
    std::vector<uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_THROW(FalseColourView::from_bytes(longer.data(), longer.size()), Error);
    EXPECT_THROW(FalseColourView::from_bytes(bytes.data(), 0), Error);
}

TEST(FalseColourViewBytes, HeaderSizesThatWouldWrapAreRefused) {
    // magic, version, width, height, surfels, neighbours, unused, entries: sizes whose
    // products wrap around 2^64 (width * height * 5 is 4 modulo 2^64 here)
    struct Header {
        char magic[4];
        uint32_t version;
        int32_t width, height;
        uint64_t surfels;
        uint32_t neighbours, unused;
        uint64_t entries;
    } h{{'G', 'M', 'F', 'V'}, 1, 2147418113, 1718039348, 1000, uint32_t(kSmoothingNeighbours), 0, 0};
    std::vector<uint8_t> data(sizeof h + 4, 0);
    std::memcpy(data.data(), &h, sizeof h);
    EXPECT_THROW(FalseColourView::from_bytes(data.data(), data.size()), Error);
    // a whole view's header claiming more neighbours than its bytes hold
    const FalseColourView view = cast(*sphere_simulation());
    std::vector<uint8_t> bytes = view.to_bytes();
    std::memcpy(&h, bytes.data(), sizeof h);
    h.entries = uint64_t(1) << 61;
    std::memcpy(bytes.data(), &h, sizeof h);
    EXPECT_THROW(FalseColourView::from_bytes(bytes.data(), bytes.size()), Error);
}

TEST(FalseColourViewBytes, TheSameViewAtOneAndTwoThreads) {
    const Simulation& sim = *sphere_simulation();
    const FalseColourView one = sim.false_colour_view({0.3f, 0.4f, 3.0f}, {0, 0, 0}, {0, 1, 0}, 45.0f, 24, 20, 1);
    EXPECT_EQ(one.to_bytes(), cast(sim).to_bytes());
}
