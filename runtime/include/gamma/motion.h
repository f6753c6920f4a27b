// The motion model (SPEC §14): how a gamma-ton moves from one interaction
// point to the next.  One step function per motion outcome, looked up in a
// table indexed by the event (GAMMA_EVENT_REFLECT / BOUNCE / FLOW), so a new
// or changed mode is one function and one table entry.  A step leaves the
// walker at the next interaction point (p, n, dir, prim) and returns
// Landed, or returns Escaped / Capped.
#pragma once
#include <cstdint>
#include <limits>
#include <vector>

#include <embree3/rtcore.h>

#include "gamma/config.h"
#include "gamma/philox.h"
#include "gamma/sampling.h"
#include "gamma/scene_index.h"
#include "gamma/stats.h"
#include "gamma/vec.h"
#include "gamma_abi.h"

namespace gammart {

// One ray the tracer cast, as it was cast (for the benchmark that replays
// the tracer's own rays through Embree alone).
struct RecordedRay {
    float org[3], dir[3], tnear, tfar;
};

// The interaction point of a cast ray org + t*d: false on a miss, else p,
// the unit normal turned toward the arriving ray, and the triangle.  The
// tracer's emission rays (cast ahead in groups) and Walker::straight land
// through this one function, so both give the same bits.
inline bool land(const RTCRayHit& rh, V3 org, V3 d, V3& p, V3& n, uint32_t& prim) {
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    p = org + d * rh.ray.tfar;
    n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
    if (dot(n, d) > 0) n = n * -1.0f;
    prim = rh.hit.primID;
    return true;
}

// One gamma-ton's position on the surface and the ray queries that move it.
struct Walker {
    const SceneIndex& index;
    const SceneFrame& frame;
    TraceStats& st;
    V3 p, n, dir;       // interaction point, normal facing the arriving ray, arriving direction
    uint32_t prim = 0;  // triangle of the interaction point
    RTCRayHit rh;
    std::vector<RecordedRay>* record = nullptr;  // if set, every cast ray is appended
    // sin of the drip angle of the ton type last flowed (flow_step: worked out
    // once per walker and ton type, not at every step)
    const TonType* drip_of = nullptr;
    float sin_drip = 0;

    Walker(const SceneIndex& i, const SceneFrame& f, TraceStats& s) : index(i), frame(f), st(s) {}

    // Straight ray; true if it hit (the interaction point is updated).
    bool straight(V3 org, V3 d, float tnear, float tfar = std::numeric_limits<float>::infinity());
    // Parabolic flight from p0 with velocity vel (g = 1 along frame.down),
    // chords of time dt.  A zero launch speed (a drip) is a straight fall
    // along `down`: one ray, no discretisation.
    FlightEnd flight(V3 p0, V3 vel, double dt);
};

// One motion step: draws from rng as SPEC §14 states for the mode.
using MotionStep = FlightEnd (*)(Walker& w, PhiloxStream& rng, const TonType& tt);

FlightEnd reflect_step(Walker& w, PhiloxStream& rng, const TonType& tt);  // §14.1 straight
FlightEnd bounce_step(Walker& w, PhiloxStream& rng, const TonType& tt);   // §14.2 parabolic
FlightEnd flow_step(Walker& w, PhiloxStream& rng, const TonType& tt);     // §14.3 flow (gamma/flow.h)

// The step of each event, indexed by GAMMA_EVENT_*; nullptr for events that
// do not move (hit, settle).
struct MotionTable {
    MotionStep step[GAMMA_EVENT_COUNT] = {};
    constexpr MotionTable() {
        step[GAMMA_EVENT_REFLECT] = reflect_step;
        step[GAMMA_EVENT_BOUNCE] = bounce_step;
        step[GAMMA_EVENT_FLOW] = flow_step;
    }
};
inline constexpr MotionTable kMotionTable{};

}  // namespace gammart
