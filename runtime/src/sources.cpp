// Sources: validation, precomputation and emission (see gamma/sources.h).
#include "gamma/sources.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "gamma/error.h"
#include "gamma/kernel_table.h"
#include "gamma/gmath.h"
#include "gamma/sampling.h"
#include "gamma/threads.h"
#include "gamma/update_pass.h"

namespace gammart {

namespace {

V3 to_v3(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

V3 emit_dir(const SourceRt& s, PhiloxStream& rng) {
    switch (s.emission) {
        case Emission::Parallel: return s.dir;
        case Emission::Uniform: { float a = rng.next(), b = rng.next(); return uniform_hemisphere(s.dir, a, b); }
        case Emission::Cosine: { float a = rng.next(), b = rng.next(); return cosine_hemisphere(s.dir, a, b); }
    }
    return s.dir;
}

}  // namespace

namespace {

[[noreturn]] void fail(const std::string& m) { throw Error(m); }

SourceKind kind_of(const std::string& kind, const std::string& at) {
    if (kind == "point") return SourceKind::Point;
    if (kind == "spot") return SourceKind::Spot;
    if (kind == "rect") return SourceKind::Rect;
    if (kind == "disk") return SourceKind::Disk;
    if (kind == "directional") return SourceKind::Directional;
    if (kind == "sphere") return SourceKind::Sphere;
    if (kind == "hemisphere") return SourceKind::Hemisphere;
    if (kind == "surface") return SourceKind::Surface;
    fail(at + "unknown source kind '" + kind +
         "' (expected point, spot, rect, disk, directional, sphere, hemisphere or surface)");
}

Emission emission_of(const std::string& emission, const std::string& at) {
    if (emission == "parallel") return Emission::Parallel;
    if (emission == "uniform") return Emission::Uniform;
    if (emission == "cosine") return Emission::Cosine;
    fail(at + "unknown emission '" + emission + "' (expected parallel, uniform or cosine)");
}

// What every source must satisfy, whatever its kind.
void check_common(const Source& s, int ntypes, const std::string& at) {
    if (s.ton_type < 0 || s.ton_type >= ntypes)
        fail(at + "ton type index " + std::to_string(s.ton_type) + " out of range (" + std::to_string(ntypes) +
             " ton types)");
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
}

// The directional source's plane upstream of the scene: the bounding box's
// corners projected on it give the rectangle its origins cover.
void directional_plane(SourceRt& r, const SceneFrame& frame) {
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

// The parameters of the source's own kind, checked and precomputed.
void precompute_kind(SourceRt& r, const Source& s, const Config& c, const SceneFrame& frame, const std::string& at) {
    switch (r.kind) {
        case SourceKind::Spot:
            if (!(s.angle_deg > 0 && s.angle_deg <= 180)) {
                char buf[64];
                std::snprintf(buf, sizeof buf, "%g", double(s.angle_deg));
                fail(at + "angle_deg must be in (0, 180] (got " + buf + ")");
            }
            if (s.falloff < 0) fail(at + "falloff must be non-negative");
            r.cos_a = s.angle_deg >= 180 ? -1.0f : gm::cos(float(double(s.angle_deg) * M_PI / 180.0));
            r.falloff = s.falloff;
            return;
        case SourceKind::Rect:
            if (!(s.size[0] > 0 && s.size[1] > 0)) fail(at + "size must be positive");
            r.w = s.size[0];
            r.h = s.size[1];
            return;
        case SourceKind::Disk:
            if (!(s.radius > 0)) fail(at + "radius must be positive");
            r.radius = s.radius;
            return;
        case SourceKind::Surface:
            if (s.surface < 0 || s.surface >= int(c.surface_rows.size()))
                fail(at + "surface index " + std::to_string(s.surface) + " out of range");
            r.surface = s.surface;
            r.along_normal = s.along_normal;
            r.weight_kernel = s.weight_kernel;
            r.offset = 10.0f * frame.eps;   // off the surface, past the rays' own offset
            return;
        case SourceKind::Directional:
            directional_plane(r, frame);
            return;
        default:
            return;
    }
}

}  // namespace

std::vector<SourceRt> build_sources(const Config& c, const SceneFrame& frame) {
    const int ntypes = int(c.ton_types.size());
    std::vector<SourceRt> out;
    for (size_t i = 0; i < c.sources.size(); ++i) {
        const Source& s = c.sources[i];
        const std::string at = "config: source " + std::to_string(i) + ": ";
        SourceRt r;
        r.kind = kind_of(s.kind, at);
        r.emission = emission_of(s.emission, at);
        check_common(s, ntypes, at);
        const bool directed = r.kind == SourceKind::Spot || r.kind == SourceKind::Rect ||
                              r.kind == SourceKind::Disk || r.kind == SourceKind::Directional ||
                              (r.kind == SourceKind::Surface && !s.along_normal);
        if (directed && !nonzero3(s.direction)) fail(at + "direction is the zero vector");
        r.pos = to_v3(s.position);
        r.dir = directed ? unit(s.direction) : V3{0, -1, 0};
        plane_axes(r.dir, r.u, r.v);
        r.env_centre = frame.centre;
        r.env_radius = frame.radius;
        r.env_up = frame.up;
        precompute_kind(r, s, c, frame, at);
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

namespace {

// A point of surfel i's surface: within `spread` of it on its triangle (a disk
// by rejection, 8 tries at most, else the surfel itself), or anywhere on the
// triangle when the triangle is smaller than that disk.  So origins cover the
// surface, not only the surfels' points, and amounts do not depend on
// --surfels (SPEC 13.2); they stay near the surfel that was picked.
V3 point_near_surfel(const SourceRt& s, size_t i, V3 p, PhiloxStream& rng) {
    const int32_t* t = s.mesh_triangles + 3 * size_t(s.surfel_triangle[i]);
    auto vertex = [&](int k) {
        const float* v = s.mesh_vertices + 3 * size_t(t[k]);
        return V3{v[0], v[1], v[2]};
    };
    const V3 a = vertex(0), b = vertex(1), c = vertex(2);
    const V3 e1 = b - a, e2 = c - a;
    const V3 nt = cross(e1, e2);
    const float twice_area = length(nt);
    const float R = s.spread;
    if (!(twice_area > 0.0f) || !(R > 0.0f)) return p;
    if (0.5f * twice_area <= float(M_PI) * R * R) {
        float u = rng.next(), v = rng.next();
        if (u + v > 1.0f) { u = 1.0f - u; v = 1.0f - v; }
        return a + e1 * u + e2 * v;
    }
    const V3 n = nt * (1.0f / twice_area);
    const V3 x = normalize(e1), y = cross(n, x);
    for (int k = 0; k < 8; ++k) {
        const float r = R * std::sqrt(rng.next()), phi = 2.0f * float(M_PI) * rng.next();
        const V3 q = p + x * (r * gm::cos(phi)) + y * (r * gm::sin(phi));
        // inside the triangle: barycentric coordinates in [0, 1]
        const V3 d = q - a;
        const float d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2);
        const float d1 = dot(d, e1), d2 = dot(d, e2), det = d11 * d22 - d12 * d12;
        const float bu = (d22 * d1 - d12 * d2) / det, bv = (d11 * d2 - d12 * d1) / det;
        if (bu >= 0.0f && bv >= 0.0f && bu + bv <= 1.0f) return q;
    }
    return p;
}

// A surfel of the source's table, picked by one draw, a point of the
// surface near it, and a direction about its axis.
void emit_from_surface(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir) {
    const SurfaceEmitters& t = *s.table;
    const double x = double(rng.next()) * t.total();
    size_t k = size_t(std::upper_bound(t.cdf.begin(), t.cdf.end(), x) - t.cdf.begin());
    k = std::min(std::max<size_t>(k, 1), t.surfel.size()) - 1;
    while (k > 0 && !(t.cdf[k + 1] > t.cdf[k])) --k;     // never a surfel of weight 0
    const size_t i = t.surfel[k];
    const V3 p{s.positions[3 * i], s.positions[3 * i + 1], s.positions[3 * i + 2]};
    const V3 n{s.normals[3 * i], s.normals[3 * i + 1], s.normals[3 * i + 2]};
    const V3 axis = s.along_normal ? n : s.dir;
    // start on the surfel's side (outside a consistently wound solid): a gamma-ton
    // sent into the surface meets it at once, as a drip on the top of a link runs
    // over the link before it falls
    org = point_near_surfel(s, i, p, rng) + n * s.offset;
    switch (s.emission) {
        case Emission::Parallel: dir = axis; return;
        case Emission::Uniform: { float a = rng.next(), b = rng.next(); dir = uniform_hemisphere(axis, a, b); return; }
        case Emission::Cosine: { float a = rng.next(), b = rng.next(); dir = cosine_hemisphere(axis, a, b); return; }
    }
}

}  // namespace

void emit(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir) {
    switch (s.kind) {
        case SourceKind::Surface:
            emit_from_surface(s, rng, org, dir);
            return;
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
                    const float z = gm::pow(1.0f - a, inv);  // in (0, 1]
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
            org = s.pos + s.u * (r * gm::cos(phi)) + s.v * (r * gm::sin(phi));
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

namespace {

// emit_environment of gamma-tons first .. first + n - 1, their two angles'
// sines and cosines computed together (gm::sincos_n: eight at a time where
// the CPU can).  Each stream is drawn in emit_environment's order, and the
// sines and cosines are the same bits: the same origins and directions.
void emit_environment_run(const SourceRt& s, uint64_t seed, uint32_t iteration, int64_t first, size_t n,
                          PhiloxStream* rng, V3* org, V3* dir) {
    constexpr size_t kBatch = 32;
    const bool upper = s.kind == SourceKind::Hemisphere;
    float u[kBatch], z[kBatch], angle[2 * kBatch], sine[2 * kBatch], cosine[2 * kBatch];
    for (size_t b = 0; b < n; b += kBatch) {
        const size_t m = std::min(kBatch, n - b);
        for (size_t i = 0; i < m; ++i) {
            PhiloxStream& r = rng[b + i];
            r = PhiloxStream(seed, iteration, uint64_t(first) + b + i);
            u[i] = r.next();
            angle[i] = kTwoPi * r.next();                     // uniform_sphere's azimuth
            z[i] = std::sqrt(std::max(0.0f, 1.0f - r.next()));  // cosine_hemisphere's polar cos
            angle[m + i] = kTwoPi * r.next();                 // and azimuth
        }
        gm::sincos_n(angle, sine, cosine, 2 * m);
        for (size_t i = 0; i < m; ++i) {
            V3 o = uniform_sphere_sc(u[i], sine[i], cosine[i]);
            if (upper) {
                const float ou = dot(o, s.env_up);
                if (ou < 0) o = o - s.env_up * (2.0f * ou);
            }
            org[b + i] = s.env_centre + o * s.env_radius;
            dir[b + i] = around_sc(o * -1.0f, z[i], sine[m + i], cosine[m + i]);
        }
    }
}

}  // namespace

void emit_run(const SourceRt& s, uint64_t seed, uint32_t iteration, int64_t first, size_t n, PhiloxStream* rng,
              V3* org, V3* dir) {
    if (s.kind == SourceKind::Sphere || s.kind == SourceKind::Hemisphere) {
        emit_environment_run(s, seed, iteration, first, n, rng, org, dir);
        return;
    }
    for (size_t i = 0; i < n; ++i) {
        rng[i] = PhiloxStream(seed, iteration, uint64_t(first) + i);
        emit(s, rng[i], org[i], dir[i]);
    }
}

std::vector<SurfaceEmitters> surface_emitters(const std::vector<SourceRt>& sources, const SurfelState& state,
                                              const SceneFrame& frame, int iteration, uint64_t seed, int threads) {
    std::vector<SurfaceEmitters> tables(sources.size());
    const size_t n = state.size();
    const int W = state.width;
    for (size_t si = 0; si < sources.size(); ++si) {
        const SourceRt& s = sources[si];
        if (s.kind != SourceKind::Surface) continue;
        SurfaceEmitters& t = tables[si];
        t.surface_source = true;
        for (size_t i = 0; i < n; ++i)
            if (state.surface[i] == s.surface) t.surfel.push_back(uint32_t(i));
        std::vector<float> weight(t.surfel.size(), 1.0f);
        if (s.weight_kernel != 0) {
            const auto fn = reinterpret_cast<GammaUpdateKernel>(s.weight_kernel);
            const uint64_t key = mix64(mix64(seed ^ 0x5EED5EED5EED5EEDULL ^ uint64_t(si)) ^ uint64_t(uint32_t(iteration)));
            run_with_threads(threads, [&] {
                tbb::parallel_for(tbb::blocked_range<size_t>(0, t.surfel.size(), 4096),
                                  [&](const tbb::blocked_range<size_t>& r) {
                    std::vector<float> row(size_t(W) + 1);
                    GammaContext ctx;
                    for (size_t k = r.begin(); k < r.end(); ++k) {
                        const size_t i = t.surfel[k];
                        std::copy(state.row(i), state.row(i) + W, row.begin());
                        row[size_t(W)] = 0.0f;
                        surfel_context(state, frame, i, iteration, ctx);
                        set_random_key(ctx, mix64(key ^ uint64_t(i)));
                        fn(row.data(), &ctx);
                        const float w = row[size_t(W)];
                        weight[k] = std::isfinite(w) && w > 0.0f ? w : 0.0f;
                    }
                });
            });
        }
        t.cdf.resize(t.surfel.size() + 1);
        for (size_t k = 0; k < t.surfel.size(); ++k) t.cdf[k + 1] = t.cdf[k] + double(weight[k]);
    }
    return tables;
}

std::vector<uint8_t> silent_sources(const std::vector<SurfaceEmitters>& tables) {
    std::vector<uint8_t> silent(tables.size(), 0);
    for (size_t i = 0; i < tables.size(); ++i) silent[i] = tables[i].surface_source && !(tables[i].total() > 0.0);
    return silent;
}

EmissionSchedule schedule(const std::vector<Source>& sources, int iteration, const std::vector<uint8_t>& silent) {
    EmissionSchedule e;
    for (size_t i = 0; i < sources.size(); ++i) {
        const Source& s = sources[i];
        if (iteration < s.first_iteration || (s.last_iteration != 0 && iteration > s.last_iteration)) continue;
        if (i < silent.size() && silent[i]) continue;
        e.active.push_back(i);
        e.start.push_back(e.start.back() + s.count);
    }
    return e;
}

}  // namespace gammart
