// The tracer's parts on their own: the per-mode motion table (which events
// move a gamma-ton, and how a single step behaves on simple geometry) and the
// tracer driven directly by a scene index and a surfel state.
#include <gtest/gtest.h>

#include "gamma/motion.h"
#include "gamma/tracer.h"
#include "helpers.h"

using namespace gammart;

TEST(MotionTable, OnlyReflectBounceAndFlowMove) {
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_HIT], nullptr);
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_SETTLE], nullptr);
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_REFLECT], &reflect_step);
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_BOUNCE], &bounce_step);
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_FLOW], &flow_step);
}

namespace {
struct FloorScene {
    Mesh mesh;
    SceneIndex index;
    SceneFrame frame;
    FloorScene(float slope) {
        gamma_test::Builder b;
        // A 10 x 10 floor through the origin, tilted about z by `slope` (rise per unit x).
        b.quad({-5, -5 * slope, -5}, {-5, -5 * slope, 5}, {5, 5 * slope, 5}, {5, 5 * slope, -5});
        mesh = b.mesh("floor");
        index.build_geometry(mesh, std::vector<int32_t>(mesh.num_triangles(), 0), 1);
        frame = SceneFrame::of(mesh, {0, -1, 0});
    }
};
}  // namespace

// A flat floor and a straight fall onto it: one step in a random direction
// (one number drawn), on the floor (SPEC §14.3).
TEST(MotionTable, FlowOnAFlatFloorSpreads) {
    FloorScene s(0.0f);
    TraceStats st;
    Walker w(s.index, s.frame, st);
    ASSERT_TRUE(w.straight(V3{0.5f, 1, 0.5f}, V3{0, -1, 0}, 0.0f));
    const V3 p = w.p;
    TonType tt;
    tt.flow_step = 0.1f;
    PhiloxStream rng(1, 1, 0);
    EXPECT_EQ(kMotionTable.step[GAMMA_EVENT_FLOW](w, rng, tt), FlightEnd::Landed);
    EXPECT_NEAR(length(w.p - p), 0.1f, 1e-5f);
    EXPECT_NEAR(w.p.y, p.y, 1e-6f);
    EXPECT_NEAR(length(w.dir), 1.0f, 1e-5f);
    EXPECT_EQ(rng.draws(), 1u);  // the direction
    EXPECT_EQ(st.flow_steps, 1);
}

TEST(MotionTable, FlowOnASlopeMovesDownhillByOneStep) {
    FloorScene s(0.5f);
    TraceStats st;
    Walker w(s.index, s.frame, st);
    ASSERT_TRUE(w.straight(V3{1, 5, 0}, V3{0, -1, 0}, 0.0f));
    const V3 p = w.p;
    TonType tt;
    tt.flow_step = 0.2f;
    PhiloxStream rng(1, 1, 0);
    ASSERT_EQ(flow_step(w, rng, tt), FlightEnd::Landed);
    EXPECT_LT(w.p.x, p.x);  // downhill is -x
    EXPECT_LT(w.p.y, p.y);
    EXPECT_NEAR(length(w.p - p), 0.2f, 1e-4f);
    EXPECT_LT(w.dir.y, 0.0f);
}

TEST(MotionTable, ReflectFromAnOpenFloorEscapes) {
    FloorScene s(0.0f);
    TraceStats st;
    Walker w(s.index, s.frame, st);
    ASSERT_TRUE(w.straight(V3{0, 1, 0}, V3{0, -1, 0}, 0.0f));
    TonType tt;
    for (uint64_t g = 0; g < 20; ++g) {
        PhiloxStream rng(3, 1, g);
        EXPECT_EQ(reflect_step(w, rng, tt), FlightEnd::Escaped);  // nothing above a single floor
        EXPECT_EQ(rng.draws(), 1u);
    }
}

TEST(Tracer, DrivenDirectlyByItsParts) {
    FloorScene s(0.0f);
    Config c;
    c.surfels = 500;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 0}};
    c.add_ton_type(0, 0, 0, {});  // settle at once
    c.add_source("rect", 0, 3000, {0, 1, 0});
    c.sources[0].direction = {0, -1, 0};
    c.sources[0].size = {2, 2};
    c.set_transport(GAMMA_EVENT_SETTLE, 0, 0,
                    uint64_t(reinterpret_cast<uintptr_t>(+[](float*, const float*, float* delta,
                                                             const GammaContext*) -> int32_t {
                        delta[3] = 1.0f;
                        return 0;
                    })),
                    true);
    const KernelTable K = KernelTable::from_config(c);
    const std::vector<SourceRt> src = build_sources(c, s.frame);
    SurfelState st = SurfelState::sample(s.mesh, std::vector<int32_t>(s.mesh.num_triangles(), 0), 500, 1,
                                         c.surface_rows);
    s.index.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), 0.4f);
    Tracer tracer(c, K, src);
    const TraceStats ts = tracer.trace(1, s.index, s.frame, st);
    EXPECT_EQ(ts.emitted, 3000);
    EXPECT_EQ(ts.settled, 3000);
    double sum = 0;
    for (size_t i = 0; i < st.size(); ++i) sum += st.row(i)[3];
    EXPECT_EQ(sum, 3000.0);  // every settle deposited exactly 1
}
