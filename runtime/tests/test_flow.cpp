// Flow that follows surfaces (SPEC §14.3): the step rule on its own against
// analytic geometry, and a γ-ton running off a tread and down its riser.
#include <gtest/gtest.h>

#include <cmath>
#include <mutex>
#include <vector>

#include "gamma/flow.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;
using gamma_test::Builder;

namespace {

const V3 kDown{0, -1, 0};
constexpr float kStep = 0.1f, kEps = 1e-5f;
const float kSin10 = std::sin(10.0f * 0.017453292f);

// Ray casts against axis-aligned rectangles: {point on plane, normal, axis
// extents}; the hit normal is turned toward the ray's origin.
struct Rect {
    V3 lo, hi;  // a degenerate box: one of its extents is zero (the plane)
};
bool cast_rects(const std::vector<Rect>& rects, V3 o, V3 d, float tfar, FlowHit& h) {
    bool hit = false;
    float best = tfar;
    for (const Rect& r : rects) {
        const float lo[3] = {r.lo.x, r.lo.y, r.lo.z}, hi[3] = {r.hi.x, r.hi.y, r.hi.z};
        const float oo[3] = {o.x, o.y, o.z}, dd[3] = {d.x, d.y, d.z};
        int axis = lo[0] == hi[0] ? 0 : lo[1] == hi[1] ? 1 : 2;
        if (dd[axis] == 0) continue;
        const float t = (lo[axis] - oo[axis]) / dd[axis];
        if (!(t > 0 && t <= best)) continue;
        bool inside = true;
        for (int k = 0; k < 3; ++k)
            if (k != axis) {
                const float x = oo[k] + dd[k] * t;
                inside = inside && x >= lo[k] && x <= hi[k];
            }
        if (!inside) continue;
        best = t;
        hit = true;
        h.p = o + d * t;
        V3 n{0, 0, 0};
        (axis == 0 ? n.x : axis == 1 ? n.y : n.z) = dd[axis] > 0 ? -1.0f : 1.0f;
        h.n = n;
    }
    return hit;
}

FlowResult step_on(const std::vector<Rect>& rects, V3 p, V3 n, V3 arriving, float sin_drip = kSin10,
                   float xi = 0.25f) {
    return flow_move(p, n, arriving, kDown, kStep, kEps, sin_drip,
                     [&](V3 o, V3 d, float tfar, FlowHit& h) { return cast_rects(rects, o, d, tfar, h); },
                     [&] { return xi; });
}

}  // namespace

// A tread (y = 1, z < 0) and its riser (z = 0, 0 <= y <= 1): a γ-ton near
// the nosing flowing toward +z goes round the edge onto the riser.
TEST(FlowStep, TreadNosingLeadsDownTheRiser) {
    std::vector<Rect> stair = {{{-1, 1, -1}, {1, 1, 0}}, {{-1, 0, 0}, {1, 1, 0}}, {{-1, 0, 0}, {1, 0, 2}}};
    const FlowResult r = step_on(stair, {0, 1, -0.03f}, {0, 1, 0}, {0, 0, 1});
    ASSERT_EQ(r.end, FlowEnd::Moved);
    EXPECT_NEAR(r.hit.p.z, 0.0f, 1e-5f);           // on the riser
    EXPECT_NEAR(r.hit.p.y, 1.0f - kStep / 2, 1e-5f);
    EXPECT_EQ(r.hit.n.z, 1.0f);
    // and from there straight down it, one step at a time
    const FlowResult down = step_on(stair, r.hit.p, r.hit.n, r.dir);
    ASSERT_EQ(down.end, FlowEnd::Moved);
    EXPECT_NEAR(down.hit.p.y, r.hit.p.y - kStep, 1e-5f);
    EXPECT_NEAR(down.hit.p.z, 0.0f, 1e-5f);
    EXPECT_NEAR(down.dir.y, -1.0f, 1e-6f);
}

// The foot of the riser is a concave corner: the step ends on the floor.
TEST(FlowStep, RiserFootEndsOnTheFloor) {
    std::vector<Rect> stair = {{{-1, 0, 0}, {1, 1, 0}}, {{-1, 0, 0}, {1, 0, 2}}};
    const FlowResult r = step_on(stair, {0, 0.05f, 0}, {0, 0, 1}, kDown);
    ASSERT_EQ(r.end, FlowEnd::Moved);
    EXPECT_NEAR(r.hit.p.y, 0.0f, 1e-5f);
    EXPECT_EQ(r.hit.n.y, 1.0f);
}

// A slab's front face ends at its underside: water drips instead of
// running onto a face that looks down.
TEST(FlowStep, DripsAtTheUndersideOfASlab) {
    std::vector<Rect> slab = {{{-1, 0.9f, 0}, {1, 1, 0}}, {{-1, 0.9f, -1}, {1, 0.9f, 0}}};
    const FlowResult r = step_on(slab, {0, 0.93f, 0}, {0, 0, 1}, kDown);
    EXPECT_EQ(r.end, FlowEnd::Drip);
    EXPECT_NEAR(r.drip_from.y, 0.93f - kStep, 1e-5f);
    // With a drip angle of 90 degrees water clings to every face, the
    // underside included.
    const FlowResult clings = step_on(slab, {0, 0.93f, 0}, {0, 0, 1}, kDown, 1.0f);
    EXPECT_EQ(clings.end, FlowEnd::Moved);
    EXPECT_NEAR(clings.hit.p.y, 0.9f, 1e-5f);
}

// Overhangs: a face turned down 20 degrees past vertical holds water only
// when the drip angle is larger than 20 degrees.
TEST(FlowStep, OverhangDripsPastTheDripAngle) {
    const float a = 20.0f * 0.017453292f;
    const V3 n{0, -std::sin(a), std::cos(a)};
    std::vector<Rect> none;
    EXPECT_EQ(step_on(none, {0, 1, 0}, n, kDown, std::sin(10.0f * 0.017453292f)).end, FlowEnd::Drip);
    const FlowResult r = step_on(none, {0, 1, 0}, n, kDown, std::sin(30.0f * 0.017453292f));
    EXPECT_GT(r.dir.y, -1.0f);  // it did not drip from the face itself: it looked for one to flow on
    EXPECT_NEAR(r.drip_from.y, 1.0f + kStep * r.dir.y, 1e-5f);
}

// Flat faces: a γ-ton keeps sliding the way it came; one that fell on it
// straight picks a direction from its random number.
TEST(FlowStep, FlatFacesMomentumOrRandomDirection) {
    std::vector<Rect> floor = {{{-5, 0, -5}, {5, 0, 5}}};
    const FlowResult slide = step_on(floor, {0, 0, 0}, {0, 1, 0}, normalize(V3{1, -1, 0}));
    ASSERT_EQ(slide.end, FlowEnd::Moved);
    EXPECT_FALSE(slide.drew);
    EXPECT_NEAR(slide.hit.p.x, kStep, 1e-5f);
    EXPECT_NEAR(slide.hit.p.z, 0.0f, 1e-6f);
    const FlowResult a = step_on(floor, {0, 0, 0}, {0, 1, 0}, kDown, kSin10, 0.0f);
    const FlowResult b = step_on(floor, {0, 0, 0}, {0, 1, 0}, kDown, kSin10, 0.25f);
    EXPECT_TRUE(a.drew && b.drew);
    EXPECT_NEAR(dot(a.dir, b.dir), 0.0f, 1e-5f);      // a quarter turn apart
    EXPECT_NEAR(length(a.hit.p), kStep, 1e-5f);
    // on a 1:50 slope gravity wins over momentum pointing uphill
    const V3 n = normalize(V3{0, 1, 0.02f});
    std::vector<Rect> none;
    const FlowResult s = step_on(none, {0, 0, 0}, n, V3{0, 0, -1});
    EXPECT_GT(s.dir.z, 0.0f);
}

namespace {
std::mutex g_mu;
std::vector<std::array<float, 7>> g_flow;  // position, normal, interaction
extern "C" int32_t rec_flow_step(float*, const float*, float*, const GammaContext* c) {
    std::lock_guard<std::mutex> lk(g_mu);
    g_flow.push_back({c->position[0], c->position[1], c->position[2], c->normal[0], c->normal[1], c->normal[2],
                      float(c->interactions)});
    return 0;
}
}  // namespace

// Rain on a step whose tread falls 1:50 toward its nosing: the water that
// lands on the tread runs off it and down the riser (it drips only later,
// off the far edges of the floor).
TEST(Flow, RainRunsOverTheNosingAndDownTheRiser) {
    Builder b;
    b.quad({-1, 1.02f, -1}, {-1, 1.0f, 0}, {1, 1.0f, 0}, {1, 1.02f, -1});  // tread, normal ~ +y
    b.quad({-1, 0, 0}, {1, 0, 0}, {1, 1.0f, 0}, {-1, 1.0f, 0});           // riser, +z
    b.quad({-1, 0, 0}, {-1, 0, 2}, {1, 0, 2}, {1, 0, 0});                 // floor, +y
    Mesh m = b.mesh();
    Config c;
    c.surfels = 2000;
    c.seed = 3;
    c.threads = 1;
    c.row_width = GAMMA_ROW_HEADER;
    c.surface_rows = {std::vector<float>(GAMMA_ROW_HEADER, 0.0f)};
    c.max_interactions = 60;
    const int t = c.add_ton_type(0, 0, 1, {}, 0.5f, 0.05f);
    Source s;
    s.kind = "rect";
    s.ton_type = t;
    s.count = 300;
    s.position = {0, 2, -0.5f};
    s.direction = {0, -1, 0};
    s.size = {0.8f, 1.5f};  // along -z, along x
    c.add_source(s);
    c.set_transport(GAMMA_EVENT_FLOW, t, 0, uint64_t(reinterpret_cast<uintptr_t>(&rec_flow_step)), false);
    g_flow.clear();
    Simulation sim(m, c);
    const TraceStats st = sim.trace(1);
    EXPECT_EQ(st.emitted, 300);
    size_t on_riser = 0, on_floor = 0;
    for (const auto& r : g_flow) {
        if (std::fabs(r[2]) < 1e-4f && r[5] > 0.99f && r[1] > 1e-4f) ++on_riser;
        if (r[1] < 1e-4f && r[4] > 0.99f) ++on_floor;
    }
    EXPECT_GT(on_riser, 300u * 5);  // ~20 steps of 0.05 down a riser 1 high, per gamma-ton
    EXPECT_GT(on_floor, 0u);
}
