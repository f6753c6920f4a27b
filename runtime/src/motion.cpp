// The motion model's steps (see gamma/motion.h and SPEC §14).
#include "gamma/motion.h"

namespace gammart {

bool Walker::straight(V3 org, V3 d, float tnear, float tfar) {
    if (record) record->push_back(RecordedRay{{org.x, org.y, org.z}, {d.x, d.y, d.z}, tnear, tfar});
    index.cast(rh, org, d, tnear, tfar);
    ++st.rays;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    p = org + d * rh.ray.tfar;
    n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
    if (dot(n, d) > 0) n = n * -1.0f;
    dir = d;
    prim = rh.hit.primID;
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

FlightEnd flow_step(Walker& w, PhiloxStream&, const TonType& tt) {
    ++w.st.flow_steps;
    const float step = tt.flow_step, eps = w.frame.eps;
    const V3 down = w.frame.down;
    const V3 p = w.p, n = w.n;
    const V3 gt = down - n * dot(down, n);
    if (dot(n, w.frame.up) < 0) {
        ++w.st.drips;  // overhang: gravity pulls it off
        return w.flight(p + n * eps, V3{0, 0, 0}, flight_dt(tt.bounce_distance));
    }
    if (length(gt) < 1e-3f) {
        w.dir = V3{0, 0, 0};  // horizontal: no drift, interact again here
        return FlightEnd::Landed;
    }
    const V3 t = normalize(gt);
    const V3 q = p + t * step;
    if (w.straight(p + n * eps, t, 0.0f, step)) return FlightEnd::Landed;  // concave corner: where the ray hit
    if (w.straight(q + n * (0.5f * step), n * -1.0f, 0.0f, step)) {
        w.dir = t;  // re-attached (flat or convex bend)
        return FlightEnd::Landed;
    }
    ++w.st.drips;  // the surface fell away: an edge
    return w.flight(q, V3{0, 0, 0}, flight_dt(tt.bounce_distance));
}

}  // namespace gammart
