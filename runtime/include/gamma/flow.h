// One flow step (SPEC §14.3): water runs downhill, slides on across flat
// faces, goes round convex edges onto faces below that hold water (a tread's
// riser), stops in concave corners and drips where the surface turns away.
// Header-only; the tracer supplies the ray cast and the random numbers.
#pragma once
#include <cmath>
#include <cstdint>

#include "gamma/sampling.h"
#include "gamma/vec.h"

namespace gammart {

struct FlowHit {
    V3 p, n;                // point and unit normal facing the ray's origin
    uint32_t prim = 0;
};

enum class FlowEnd { Moved, Drip };

struct FlowResult {
    FlowEnd end = FlowEnd::Drip;
    FlowHit hit;            // Moved: the next interaction
    V3 drip_from;           // Drip: where the fall starts
    V3 dir;                 // the flow direction t (the next `direction`)
    bool drew = false;      // a random direction was drawn
};

// A face holds water when its normal is at most the drip angle below the
// horizontal: dot(n, up) >= -sin(drip) (tolerance 1e-3).
inline bool holds_water(V3 n, V3 up, float sin_drip) { return dot(n, up) >= -sin_drip - 1e-3f; }

// `cast(org, dir, tfar, FlowHit&)` -> bool: first hit along the ray within
// tfar (normal turned toward the origin); `draw()` -> float in [0, 1).
template <class Cast, class Draw>
FlowResult flow_move(V3 p, V3 n, V3 arriving, V3 down, float step, float eps, float sin_drip, Cast&& cast,
                     Draw&& draw) {
    FlowResult r;
    const V3 up = down * -1.0f;
    if (!holds_water(n, up, sin_drip)) {  // overhang
        r.drip_from = p + n * eps;
        r.dir = down;
        return r;
    }
    // Gravity's pull along the face, plus a little momentum so flat faces
    // are crossed the way the gamma-ton came instead of sat on.
    const V3 g_t = down - n * dot(down, n);
    V3 m = arriving - n * dot(arriving, n);
    const float lm = length(m);
    m = lm > 0.1f ? m * (1.0f / lm) : V3{0, 0, 0};
    const V3 a = g_t + m * 0.01f;
    V3 t;
    if (length(a) >= 1e-3f) {
        t = normalize(a);
    } else {
        V3 u, v;
        plane_axes(n, u, v);
        const float phi = 6.2831853f * draw();
        float s, c;
        gm::sincos(phi, s, c);
        t = u * c + v * s;
        r.drew = true;
    }
    r.dir = t;
    const V3 q = p + t * step;
    FlowHit h;
    if (cast(p + n * eps, t, step, h)) {  // concave corner
        r.end = FlowEnd::Moved;
        r.hit = h;
        return r;
    }
    if (cast(q + n * (0.5f * step), n * -1.0f, step, h)) {  // the surface goes on
        r.end = FlowEnd::Moved;
        r.hit = h;
        return r;
    }
    // Round the edge: look back under it for the face below.
    if (cast(q - n * (0.5f * step), t * -1.0f, 2.0f * step, h) && holds_water(h.n, up, sin_drip)) {
        r.end = FlowEnd::Moved;
        r.hit = h;
        return r;
    }
    r.drip_from = q;
    return r;
}

}  // namespace gammart
