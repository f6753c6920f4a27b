// Sources on their own: validation messages, the emission schedule of an
// iteration and where emitted gamma-tons start.
#include <gtest/gtest.h>

#include <cstring>

#include "gamma/sources.h"
#include "helpers.h"

using namespace gammart;
using gamma_test::expect_error;

namespace {
SceneFrame unit_frame() {
    const Mesh m = gamma_test::icosphere(1);
    return SceneFrame::of(m, {0, -1, 0});
}
}  // namespace

TEST(Sources, ValidationNamesTheSource) {
    Config c;
    c.add_ton_type(1, 0, 0, {});
    c.add_source("point", 0, 10);
    Source bad;
    bad.kind = "spot";
    bad.ton_type = 0;
    bad.count = 10;
    bad.angle_deg = 190;
    c.add_source(bad);
    const std::string msg = expect_error([&] { build_sources(c, unit_frame()); });
    EXPECT_NE(msg.find("source 1"), std::string::npos) << msg;
    EXPECT_NE(msg.find("angle_deg"), std::string::npos) << msg;
    Config d;
    d.add_source("laser", 0, 1);
    EXPECT_NE(expect_error([&] { build_sources(d, unit_frame()); }).find("unknown source kind 'laser'"),
              std::string::npos);
}

TEST(Sources, ScheduleSkipsInactiveSources) {
    std::vector<Source> s(3);
    s[0].count = 5;
    s[1].count = 7;
    s[1].first_iteration = 3;
    s[2].count = 11;
    s[2].last_iteration = 2;
    const EmissionSchedule a = schedule(s, 1);
    EXPECT_EQ(a.active, (std::vector<size_t>{0, 2}));
    EXPECT_EQ(a.start, (std::vector<int64_t>{0, 5, 16}));
    const EmissionSchedule b = schedule(s, 3);
    EXPECT_EQ(b.active, (std::vector<size_t>{0, 1}));
    EXPECT_EQ(b.total(), 12);
}

TEST(Sources, RectOriginsLieOnTheRectangle) {
    Config c;
    c.add_ton_type(1, 0, 0, {});
    Source r;
    r.kind = "rect";
    r.count = 1;
    r.position = {1, 2, 3};
    r.direction = {0, -1, 0};
    r.size = {2, 4};
    c.add_source(r);
    const std::vector<SourceRt> rt = build_sources(c, unit_frame());
    ASSERT_EQ(rt.size(), 1u);
    for (uint64_t g = 0; g < 200; ++g) {
        PhiloxStream rng(7, 1, g);
        V3 o, d;
        emit(rt[0], rng, o, d);
        EXPECT_FLOAT_EQ(o.y, 2.0f);
        EXPECT_LE(std::fabs(o.x - 1.0f), 2.0f);
        EXPECT_LE(std::fabs(o.z - 3.0f), 2.0f);
        EXPECT_EQ(d.y, -1.0f);  // parallel emission: exactly along the normal
        EXPECT_EQ(rng.draws(), 1u);  // two draws: one Philox block
    }
}

TEST(Sources, HemisphereOriginsAreInTheUpperHalf) {
    Config c;
    c.add_ton_type(1, 0, 0, {});
    c.add_source("hemisphere", 0, 1);
    const SceneFrame f = unit_frame();
    const std::vector<SourceRt> rt = build_sources(c, f);
    for (uint64_t g = 0; g < 500; ++g) {
        PhiloxStream rng(1, 1, g);
        V3 o, d;
        emit(rt[0], rng, o, d);
        EXPECT_GE(dot(o - f.centre, f.up), 0.0f);
        EXPECT_NEAR(length(o - f.centre), f.radius, 1e-5f * f.radius);
        EXPECT_LT(dot(d, o - f.centre), 0.0f);  // inward
    }
}

// emit_run against emit, one gamma-ton at a time: the same bits for origins,
// directions and the streams' next draws, over runs of every length 1..20,
// at indices whose upper 32 bits are non-zero too, for both environment
// kinds and a point source (emitted one by one).
TEST(Sources, EmitRunIsEmitBitForBit) {
    Config c;
    c.add_ton_type(1, 0, 0, {});
    c.add_source("sphere", 0, 1);
    c.add_source("hemisphere", 0, 1);
    c.add_source("point", 0, 1);
    const std::vector<SourceRt> rt = build_sources(c, unit_frame());
    ASSERT_EQ(rt.size(), 3u);
    auto same = [](float x, float y) { return std::memcmp(&x, &y, sizeof x) == 0; };
    int64_t compared = 0;
    for (const SourceRt& s : rt)
        for (const uint64_t seed : {uint64_t(1), uint64_t(0x9E3779B97F4A7C15ull)})
            for (const int64_t first : {int64_t(0), int64_t(12345), (int64_t(1) << 32) - 5, int64_t(7) << 40})
                for (size_t n = 1; n <= 20; ++n) {
                    PhiloxStream rng[20];
                    V3 org[20], dir[20];
                    emit_run(s, seed, 3, first, n, rng, org, dir);
                    for (size_t i = 0; i < n; ++i) {
                        PhiloxStream one(seed, 3, uint64_t(first) + i);
                        V3 o, d;
                        emit(s, one, o, d);
                        for (int k = 0; k < 3; ++k) {
                            ASSERT_TRUE(same(org[i][k], o[k])) << "origin, gamma-ton " << first + int64_t(i);
                            ASSERT_TRUE(same(dir[i][k], d[k])) << "direction, gamma-ton " << first + int64_t(i);
                        }
                        ASSERT_EQ(rng[i].draws(), one.draws());
                        for (int k = 0; k < 6; ++k) ASSERT_EQ(rng[i].next_u32(), one.next_u32());
                        ++compared;
                    }
                }
    EXPECT_EQ(compared, 3 * 2 * 4 * 210);
}

// Many more environment gamma-tons, one long run: 200,000 per kind.
TEST(Sources, EmitRunMatchesEmitOnALongRun) {
    Config c;
    c.add_ton_type(1, 0, 0, {});
    c.add_source("sphere", 0, 1);
    c.add_source("hemisphere", 0, 1);
    const std::vector<SourceRt> rt = build_sources(c, unit_frame());
    const size_t n = 200000;
    std::vector<PhiloxStream> rng(n);
    std::vector<V3> org(n), dir(n);
    for (const SourceRt& s : rt) {
        emit_run(s, 42, 1, 1000, n, rng.data(), org.data(), dir.data());
        size_t differ = 0;
        for (size_t i = 0; i < n; ++i) {
            PhiloxStream one(42, 1, 1000 + i);
            V3 o, d;
            emit(s, one, o, d);
            differ += std::memcmp(&o, &org[i], sizeof o) != 0 || std::memcmp(&d, &dir[i], sizeof d) != 0 ||
                      rng[i].next_u32() != one.next_u32();
        }
        EXPECT_EQ(differ, 0u);
    }
}
