// The motion model's steps (see gamma/motion.h and SPEC §14).
#include "gamma/motion.h"

#include <cmath>

#include "gamma/flow.h"

namespace gammart {

bool Walker::straight(V3 org, V3 d, float tnear, float tfar) {
    if (record) record->push_back(RecordedRay{{org.x, org.y, org.z}, {d.x, d.y, d.z}, tnear, tfar});
    index.cast(rh, org, d, tnear, tfar);
    ++st.rays;
    if (!land(rh, org, d, p, n, prim)) return false;
    dir = d;
    return true;
}

FlightEnd Walker::flight(V3 p0, V3 vel, double dt) {
    const V3 down = frame.down, up = frame.up;
    if (vel.x == 0 && vel.y == 0 && vel.z == 0) {
        ++st.segments;
        return straight(p0, down, 0.0f) ? FlightEnd::Landed : FlightEnd::Escaped;
    }
    return fly(
        p0, vel, down, dt, st.segments,
        [&](V3 sa, V3 sb) {
            const V3 ch = sb - sa;
            const float len = length(ch);
            if (!(len > 0)) return false;
            return straight(sa, ch * (1.0f / len), 0.0f, len);
        },
        [&](V3 sb, double t) {
            // Below the lowest point of the scene and descending: nothing
            // can be hit any more.  Or far away (4 diagonals) from it.
            return (dot(sb, up) < frame.min_up - frame.eps && double(dot(vel, up)) - t < 0) ||
                   length(sb - frame.centre) > 4.0f * frame.diag;
        });
}

FlightEnd reflect_step(Walker& w, PhiloxStream& rng, const TonType&) {
    const float u = rng.next(), v = rng.next();
    const V3 nd = uniform_hemisphere(w.n, u, v);
    const float eps = w.frame.eps;
    return w.straight(w.p + w.n * eps, nd, eps) ? FlightEnd::Landed : FlightEnd::Escaped;
}

FlightEnd bounce_step(Walker& w, PhiloxStream& rng, const TonType& tt) {
    ++w.st.bounces;
    const float u = rng.next(), v = rng.next();
    const V3 ld = uniform_hemisphere(w.n, u, v);
    const double D = tt.bounce_distance;
    return w.flight(w.p + w.n * w.frame.eps, ld * float(launch_speed(D)), flight_dt(D));
}

FlightEnd flow_step(Walker& w, PhiloxStream& rng, const TonType& tt) {
    ++w.st.flow_steps;
    if (w.drip_of != &tt) {
        w.sin_drip = gm::sin(tt.drip_angle_deg * 0.017453292519943295f);
        w.drip_of = &tt;
    }
    const float sin_drip = w.sin_drip;
    auto probe = [&](V3 org, V3 d, float tfar, FlowHit& h) {
        if (w.record) w.record->push_back(RecordedRay{{org.x, org.y, org.z}, {d.x, d.y, d.z}, 0.0f, tfar});
        w.index.cast(w.rh, org, d, 0.0f, tfar);
        ++w.st.rays;
        if (w.rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
        h.p = org + d * w.rh.ray.tfar;
        h.n = normalize(V3{w.rh.hit.Ng_x, w.rh.hit.Ng_y, w.rh.hit.Ng_z});
        if (dot(h.n, d) > 0) h.n = h.n * -1.0f;
        h.prim = w.rh.hit.primID;
        return true;
    };
    const FlowResult r = flow_move(w.p, w.n, w.dir, w.frame.down, tt.flow_step, w.frame.eps, sin_drip, probe,
                                   [&] { return rng.next(); });
    if (r.end == FlowEnd::Moved) {
        w.p = r.hit.p;
        w.n = r.hit.n;
        w.prim = r.hit.prim;
        w.dir = r.dir;
        return FlightEnd::Landed;
    }
    ++w.st.drips;  // an overhang, or the surface fell away beneath it
    return w.flight(r.drip_from, V3{0, 0, 0}, flight_dt(tt.bounce_distance));
}

}  // namespace gammart
