// Sources: validation, precomputation and emission (see gamma/sources.h).
#include "gamma/sources.h"

#include <cmath>
#include <cstdio>
#include <string>

#include "gamma/error.h"
#include "gamma/sampling.h"

namespace gammart {

namespace {

V3 to_v3(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

bool finite3(const std::array<float, 3>& a) {
    return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

V3 unit(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return {float(a[0] / l), float(a[1] / l), float(a[2] / l)};
}

bool nonzero3(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return std::isfinite(l) && l > 0;
}

V3 emit_dir(const SourceRt& s, PhiloxStream& rng) {
    switch (s.emission) {
        case Emission::Parallel: return s.dir;
        case Emission::Uniform: { float a = rng.next(), b = rng.next(); return uniform_hemisphere(s.dir, a, b); }
        case Emission::Cosine: { float a = rng.next(), b = rng.next(); return cosine_hemisphere(s.dir, a, b); }
    }
    return s.dir;
}

}  // namespace

std::vector<SourceRt> build_sources(const Config& c, const SceneFrame& frame) {
    auto fail = [](const std::string& m) { throw Error(m); };
    const int ntypes = int(c.ton_types.size());
    std::vector<SourceRt> out;
    for (size_t i = 0; i < c.sources.size(); ++i) {
        const Source& s = c.sources[i];
        const std::string at = "config: source " + std::to_string(i) + ": ";
        SourceRt r;
        if (s.kind == "point") r.kind = SourceKind::Point;
        else if (s.kind == "spot") r.kind = SourceKind::Spot;
        else if (s.kind == "rect") r.kind = SourceKind::Rect;
        else if (s.kind == "disk") r.kind = SourceKind::Disk;
        else if (s.kind == "directional") r.kind = SourceKind::Directional;
        else if (s.kind == "sphere") r.kind = SourceKind::Sphere;
        else if (s.kind == "hemisphere") r.kind = SourceKind::Hemisphere;
        else fail(at + "unknown source kind '" + s.kind +
                  "' (expected point, spot, rect, disk, directional, sphere or hemisphere)");
        if (s.emission == "parallel") r.emission = Emission::Parallel;
        else if (s.emission == "uniform") r.emission = Emission::Uniform;
        else if (s.emission == "cosine") r.emission = Emission::Cosine;
        else fail(at + "unknown emission '" + s.emission + "' (expected parallel, uniform or cosine)");
        if (s.ton_type < 0 || s.ton_type >= ntypes)
            fail(at + "ton type index " + std::to_string(s.ton_type) + " out of range (" +
                 std::to_string(ntypes) + " ton types)");
        if (s.count < 0) fail(at + "negative count");
        if (!finite3(s.position)) fail(at + "non-finite position");
        if (!finite3(s.direction)) fail(at + "non-finite direction");
        if (!std::isfinite(s.angle_deg) || !std::isfinite(s.falloff) || !std::isfinite(s.size[0]) ||
            !std::isfinite(s.size[1]) || !std::isfinite(s.radius))
            fail(at + "non-finite angle, falloff, size or radius");
        if (s.first_iteration < 1) fail(at + "first_iteration must be at least 1");
        if (s.last_iteration < 0) fail(at + "last_iteration must be 0 (no end) or at least 1");
        if (s.last_iteration != 0 && s.last_iteration < s.first_iteration)
            fail(at + "last_iteration " + std::to_string(s.last_iteration) + " is before first_iteration " +
                 std::to_string(s.first_iteration));
        const bool directed = r.kind == SourceKind::Spot || r.kind == SourceKind::Rect ||
                              r.kind == SourceKind::Disk || r.kind == SourceKind::Directional;
        if (directed && !nonzero3(s.direction)) fail(at + "direction is the zero vector");
        r.pos = to_v3(s.position);
        r.dir = directed ? unit(s.direction) : V3{0, -1, 0};
        plane_axes(r.dir, r.u, r.v);
        r.env_centre = frame.centre;
        r.env_radius = frame.radius;
        r.env_up = frame.up;
        if (r.kind == SourceKind::Spot) {
            if (!(s.angle_deg > 0 && s.angle_deg <= 180)) {
                char buf[64];
                std::snprintf(buf, sizeof buf, "%g", double(s.angle_deg));
                fail(at + "angle_deg must be in (0, 180] (got " + buf + ")");
            }
            if (s.falloff < 0) fail(at + "falloff must be non-negative");
            r.cos_a = s.angle_deg >= 180 ? -1.0f : float(std::cos(double(s.angle_deg) * M_PI / 180.0));
            r.falloff = s.falloff;
        }
        if (r.kind == SourceKind::Rect) {
            if (!(s.size[0] > 0 && s.size[1] > 0)) fail(at + "size must be positive");
            r.w = s.size[0];
            r.h = s.size[1];
        }
        if (r.kind == SourceKind::Disk) {
            if (!(s.radius > 0)) fail(at + "radius must be positive");
            r.radius = s.radius;
        }
        if (r.kind == SourceKind::Directional) {
            float umin = INFINITY, umax = -INFINITY, vmin = INFINITY, vmax = -INFINITY;
            for (int k = 0; k < 8; ++k) {
                const V3 corner{(k & 1) ? frame.hi[0] : frame.lo[0], (k & 2) ? frame.hi[1] : frame.lo[1],
                                (k & 4) ? frame.hi[2] : frame.lo[2]};
                const float pu = dot(corner - frame.centre, r.u), pv = dot(corner - frame.centre, r.v);
                umin = std::min(umin, pu); umax = std::max(umax, pu);
                vmin = std::min(vmin, pv); vmax = std::max(vmax, pv);
            }
            r.pos = frame.centre - r.dir * frame.radius;
            r.u0 = umin; r.du = umax - umin;
            r.v0 = vmin; r.dv = vmax - vmin;
        }
        out.push_back(r);
    }
    return out;
}

void emit_environment(V3 centre, float radius, V3 up, PhiloxStream& rng, bool upper, V3& org, V3& dir) {
    float u = rng.next(), v = rng.next();
    V3 o = uniform_sphere(u, v);
    if (upper) {
        const float ou = dot(o, up);
        if (ou < 0) o = o - up * (2.0f * ou);
    }
    org = centre + o * radius;
    float a = rng.next(), b = rng.next();
    dir = cosine_hemisphere(o * -1.0f, a, b);
}

void emit(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir) {
    switch (s.kind) {
        case SourceKind::Point: {
            org = s.pos;
            float a = rng.next(), b = rng.next();
            dir = uniform_sphere(a, b);
            return;
        }
        case SourceKind::Spot: {
            org = s.pos;
            if (s.falloff > 0) {
                const float inv = 1.0f / (s.falloff + 1.0f);
                for (int k = 0; k < kSpotMaxRedraws; ++k) {
                    float a = rng.next(), b = rng.next();
                    const float z = std::pow(1.0f - a, inv);  // in (0, 1]
                    if (z >= s.cos_a) { dir = around(s.dir, z, b); return; }
                }
            }
            float a = rng.next(), b = rng.next();
            dir = uniform_cone(s.dir, s.cos_a, a, b);
            return;
        }
        case SourceKind::Rect: {
            float a = rng.next(), b = rng.next();
            org = s.pos + s.u * ((a - 0.5f) * s.w) + s.v * ((b - 0.5f) * s.h);
            dir = emit_dir(s, rng);
            return;
        }
        case SourceKind::Disk: {
            float a = rng.next(), b = rng.next();
            const float r = s.radius * std::sqrt(a), phi = kTwoPi * b;
            org = s.pos + s.u * (r * std::cos(phi)) + s.v * (r * std::sin(phi));
            dir = emit_dir(s, rng);
            return;
        }
        case SourceKind::Directional: {
            float a = rng.next(), b = rng.next();
            org = s.pos + s.u * (s.u0 + a * s.du) + s.v * (s.v0 + b * s.dv);
            dir = s.dir;
            return;
        }
        case SourceKind::Sphere: emit_environment(s.env_centre, s.env_radius, s.env_up, rng, false, org, dir); return;
        case SourceKind::Hemisphere:
            emit_environment(s.env_centre, s.env_radius, s.env_up, rng, true, org, dir);
            return;
    }
}

EmissionSchedule schedule(const std::vector<Source>& sources, int iteration) {
    EmissionSchedule e;
    for (size_t i = 0; i < sources.size(); ++i) {
        const Source& s = sources[i];
        if (iteration < s.first_iteration || (s.last_iteration != 0 && iteration > s.last_iteration)) continue;
        e.active.push_back(i);
        e.start.push_back(e.start.back() + s.count);
    }
    return e;
}

}  // namespace gammart
