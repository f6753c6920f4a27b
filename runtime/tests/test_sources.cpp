// Sources on their own: validation messages, the emission schedule of an
// iteration and where emitted gamma-tons start.
#include <gtest/gtest.h>

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
