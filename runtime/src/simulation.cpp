#include "gamma/simulation.h"

#include <mutex>
#include <embree3/rtcore.h>
#include <nanoflann.hpp>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

#include "gamma/error.h"
#include "gamma/philox.h"
#include "gamma/sampling.h"
#include "gamma/vec.h"
#include "gamma/flow.h"
#include "gamma/splat.h"

namespace gammart {

namespace {

struct Cloud {
    const float* p = nullptr;
    size_t n = 0;
    size_t kdtree_get_point_count() const { return n; }
    float kdtree_get_pt(size_t i, size_t d) const { return p[3 * i + d]; }
    template <class BBOX>
    bool kdtree_get_bbox(BBOX&) const { return false; }
};
using KDTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>,
                                                   Cloud, 3, uint32_t>;

// kd-tree over the surfels of one surface; `index` maps to global surfel ids.
struct SurfaceTree {
    std::vector<float> pos;
    std::vector<uint32_t> index;
    Cloud cloud;
    std::unique_ptr<KDTree> kd;
};

enum class SourceKind { Point, Spot, Rect, Disk, Directional, Sphere, Hemisphere };
enum class Emission { Parallel, Uniform, Cosine };

// Source with everything precomputed in scene units.
struct SourceRt {
    SourceKind kind = SourceKind::Point;
    Emission emission = Emission::Parallel;
    V3 pos, dir, u, v;          // dir normalised; u, v in-plane axes (plane_axes(dir))
    float cos_a = -1, falloff = 0, w = 0, h = 0, radius = 0;
    float u0 = 0, du = 0, v0 = 0, dv = 0;  // directional: projected bbox rectangle
};

struct TransportSlot {
    GammaTransportKernel fn = nullptr;
    bool writes = false;
    int event = 0, ton_type = 0, surface = 0;
};

// splitmix64's finaliser, with the constants of the generated header (the
// compiled random() uses the same function).
inline uint64_t mix64(uint64_t z) {
    z += GAMMA_RANDOM_GOLDEN;
    z = (z ^ (z >> 30)) * GAMMA_RANDOM_MIX0;
    z = (z ^ (z >> 27)) * GAMMA_RANDOM_MIX1;
    return z ^ (z >> 31);
}

inline void set_random_key(GammaContext& ctx, uint64_t key) {
    ctx.random_key[0] = uint32_t(key);
    ctx.random_key[1] = uint32_t(key >> 32);
}

// Per-chunk log of surface deltas (property columns only) and counters;
// buffers are reused between iterations (cleared, capacity kept).
struct ChunkLog {
    std::vector<uint32_t> surfel;
    std::vector<float> delta;  // W-3 floats per record
    TraceStats st;
};

}  // namespace

void count_nonfinite(std::vector<NonFinite>& list, int event, int ton_type, int surface,
                     int statement, int64_t count) {
    auto key = [](const NonFinite& n) { return std::make_tuple(n.event, n.ton_type, n.surface, n.statement); };
    NonFinite item{event, ton_type, surface, statement, count};
    auto at = std::lower_bound(list.begin(), list.end(), item,
                               [&](const NonFinite& a, const NonFinite& b) { return key(a) < key(b); });
    if (at != list.end() && key(*at) == key(item)) at->count += count;
    else list.insert(at, item);
}

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

V3 to_v3(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

bool finite3(const std::array<float, 3>& a) {
    return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

// Unit vector of a in double (a must be finite and non-zero).
V3 unit(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return {float(a[0] / l), float(a[1] / l), float(a[2] / l)};
}

bool nonzero3(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return std::isfinite(l) && l > 0;
}

}  // namespace

int resolve_threads(int threads) {
    if (threads <= 0) return std::max(1, tbb::info::default_concurrency());
    return std::min(threads, kMaxThreads);
}

void run_with_threads(int threads, const std::function<void()>& f) {
    const int n = resolve_threads(threads);
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(n));
    tbb::task_arena arena(n);
    arena.execute(f);
}

void parabola_landing(std::array<float, 3> p0a, std::array<float, 3> da, float D, std::array<float, 3> downa,
                      float floor_height, std::array<float, 3>& traced, std::array<float, 3>& analytic) {
    if (!finite3(p0a) || !nonzero3(da) || !nonzero3(downa) || !std::isfinite(floor_height))
        throw Error("parabola_landing: arguments must be finite, d and down non-zero");
    if (!(D > 0) || !std::isfinite(D)) throw Error("parabola_landing: D must be positive");
    const V3 p0 = to_v3(p0a), d = unit(da), down = unit(downa), up = down * -1.0f;
    const double h0 = double(dot(p0, up)) - floor_height;
    if (h0 < 0) throw Error("parabola_landing: p0 is below the floor");
    const double v = launch_speed(D);
    const V3 vel = d * float(v);
    // Analytic: h(t) = h0 + v*du*t - t^2/2 = 0.
    const double vu = v * double(dot(d, up));
    const double t_star = vu + std::sqrt(vu * vu + 2.0 * h0);
    const V3 a_pt = flight_point(p0, vel, down, t_star);
    analytic = {a_pt.x, a_pt.y, a_pt.z};
    V3 hit{};
    int64_t segments = 0;
    FlightEnd end = fly(
        p0, vel, down, flight_dt(D), segments,
        [&](V3 a, V3 b) {
            const double ha = double(dot(a, up)) - floor_height, hb = double(dot(b, up)) - floor_height;
            if (!(hb <= 0)) return false;
            const double s = ha > hb ? ha / (ha - hb) : 0.0;
            hit = a + (b - a) * float(s);
            return true;
        },
        [](V3, double) { return false; });
    if (end != FlightEnd::Landed) throw Error("parabola_landing: the flight never reaches the floor");
    traced = {hit.x, hit.y, hit.z};
}

struct Simulation::Impl {
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    Cloud cloud;
    std::unique_ptr<KDTree> kd;                 // all surfels (render, fallback)
    std::vector<SurfaceTree> trees;             // per surface id
    std::vector<int32_t> tri_surface;           // per kept triangle
    V3 centre, down, up;
    float radius = 1;   // environment source sphere radius (1.05 x half diagonal)
    float diag = 1;
    float eps = 1e-5f;  // ray offset
    float sigma = 1;    // render kernel width (mean surfel spacing)
    float min_up = 0;   // min over vertices of dot(v, up)
    SplatKernel splat;  // where a surfel's deltas spread (SPEC 13.2)
    std::vector<float> spread;  // the merged deltas after the splat
    int n_types = 0, n_surfaces = 0;
    std::vector<TransportSlot> transport;        // [event][type][surface]
    std::vector<GammaUpdateKernel> update;       // [surface]
    std::vector<GammaAppearanceKernel> appearance;  // [surface]
    size_t n_surfels = 0;
    std::vector<SourceRt> sources;
    size_t max_carry = 1;
    std::vector<ChunkLog> logs;
    std::vector<float> delta;                    // N*(W-3) merge buffer

    const TransportSlot& slot(int event, int type, int surface) const {
        return transport[(size_t(event) * n_types + type) * n_surfaces + surface];
    }

    ~Impl() {
        if (scene) rtcReleaseScene(scene);
        if (device) rtcReleaseDevice(device);
    }

    void cast(RTCRayHit& rh, V3 org, V3 dir, float tnear,
              float tfar = std::numeric_limits<float>::infinity()) const {
        rh.ray.org_x = org.x; rh.ray.org_y = org.y; rh.ray.org_z = org.z;
        rh.ray.dir_x = dir.x; rh.ray.dir_y = dir.y; rh.ray.dir_z = dir.z;
        rh.ray.tnear = tnear;
        rh.ray.tfar = tfar;
        rh.ray.time = 0;
        rh.ray.mask = 0xFFFFFFFFu;
        rh.ray.id = 0;
        rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        RTCIntersectContext ictx;
        rtcInitIntersectContext(&ictx);
        rtcIntersect1(scene, &ictx, &rh);
    }

    // Shadow / AO ray: true if anything lies between tnear and tfar.
    bool occluded(V3 org, V3 dir, float tnear, float tfar) const {
        RTCRay ray;
        ray.org_x = org.x; ray.org_y = org.y; ray.org_z = org.z;
        ray.dir_x = dir.x; ray.dir_y = dir.y; ray.dir_z = dir.z;
        ray.tnear = tnear;
        ray.tfar = tfar;
        ray.time = 0;
        ray.mask = 0xFFFFFFFFu;
        ray.id = 0;
        ray.flags = 0;
        RTCIntersectContext ictx;
        rtcInitIntersectContext(&ictx);
        rtcOccluded1(scene, &ictx, &ray);
        return ray.tfar < 0;  // Embree sets tfar = -inf on a hit
    }

    // See Simulation::smoothing_weights.
    size_t smooth(int surface, const float p[3], uint32_t* idx, double* w) const {
        constexpr size_t K = kSmoothingNeighbours;
        const KDTree* tree = kd.get();
        const uint32_t* map = nullptr;
        size_t count = n_surfels;
        if (surface >= 0 && surface < n_surfaces && trees[size_t(surface)].kd) {
            const SurfaceTree& t = trees[size_t(surface)];
            tree = t.kd.get();
            map = t.index.data();
            count = t.index.size();
        }
        float d2[K];
        nanoflann::KNNResultSet<float, uint32_t> rs(std::min(K, count));
        rs.init(idx, d2);
        tree->findNeighbors(rs, p, nanoflann::SearchParams());
        size_t got = rs.size();
        const double inv2s2 = 1.0 / (2.0 * double(sigma) * double(sigma));
        double sw = 0;
        for (size_t j = 0; j < got; ++j) {
            w[j] = std::exp(-double(d2[j]) * inv2s2);
            sw += w[j];
        }
        if (sw > 0) {
            for (size_t j = 0; j < got; ++j) w[j] /= sw;
        } else {  // every weight underflowed: the nearest surfel alone
            got = 1;
            w[0] = 1.0;
        }
        if (map)
            for (size_t j = 0; j < got; ++j) idx[j] = map[idx[j]];
        return got;
    }

    // Environment-sphere emission (origin on the bounding sphere, cosine about
    // the inward normal); `upper` reflects origins into the half dot(o, up) >= 0.
    void emit_env(PhiloxStream& rng, bool upper, V3& org, V3& dir) const {
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

    V3 emit_dir(const SourceRt& s, PhiloxStream& rng) const {
        switch (s.emission) {
            case Emission::Parallel: return s.dir;
            case Emission::Uniform: { float a = rng.next(), b = rng.next(); return uniform_hemisphere(s.dir, a, b); }
            case Emission::Cosine: { float a = rng.next(), b = rng.next(); return cosine_hemisphere(s.dir, a, b); }
        }
        return s.dir;
    }

    void emit(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir) const {
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
            case SourceKind::Sphere: emit_env(rng, false, org, dir); return;
            case SourceKind::Hemisphere: emit_env(rng, true, org, dir); return;
        }
    }

    static uint32_t query(const KDTree& kd, const float p[3]) {
        uint32_t idx = 0;
        float d2 = 0;
        nanoflann::KNNResultSet<float, uint32_t> rs(1);
        rs.init(&idx, &d2);
        kd.findNeighbors(rs, p, nanoflann::SearchParams());
        return idx;
    }
    uint32_t nearest(const float p[3]) const { return query(*kd, p); }
    uint32_t nearest_of(int surface, const float p[3]) const {
        const SurfaceTree& t = trees[size_t(surface)];
        if (!t.kd) return nearest(p);
        return t.index[query(*t.kd, p)];
    }
};

Simulation::Simulation(const Mesh& mesh, const Config& config)
    : impl_(std::make_unique<Impl>()), mesh_(mesh), cfg_(config) {
    const Config& c = cfg_;
    Impl& I = *impl_;
    auto fail = [](const std::string& m) { throw Error(m); };
    if (c.surfels < 1) fail("config: surfels must be at least 1 (got " + std::to_string(c.surfels) + ")");
    if (c.surfels > 400000000) fail("config: surfels too large (" + std::to_string(c.surfels) + ")");
    if (c.max_interactions < 1)
        fail("config: max_interactions must be at least 1 (got " + std::to_string(c.max_interactions) + ")");
    if (c.threads > kMaxThreads)
        fail("config: threads must be at most " + std::to_string(kMaxThreads) + " (got " +
             std::to_string(c.threads) + ")");
    if (c.row_width < GAMMA_ROW_HEADER)
        fail("config: row_width must be at least " + std::to_string(GAMMA_ROW_HEADER) + " (got " +
             std::to_string(c.row_width) + ")");
    if (!finite3(c.down)) fail("config: down has a non-finite component");
    if (!nonzero3(c.down)) fail("config: down is the zero vector");
    if (c.surface_rows.empty()) fail("config: no surfaces (surface_rows is empty)");
    const int W = c.row_width;
    const int nsurf = int(c.surface_rows.size());
    for (int s = 0; s < nsurf; ++s) {
        if (int(c.surface_rows[s].size()) != W)
            fail("config: surface_rows[" + std::to_string(s) + "] has " +
                 std::to_string(c.surface_rows[s].size()) + " floats, row_width is " + std::to_string(W));
        for (float x : c.surface_rows[s])
            if (!std::isfinite(x)) fail("config: surface_rows[" + std::to_string(s) + "] has a non-finite value");
    }
    // Per-triangle surface ids (accept post- or pre-degenerate-removal length).
    const size_t m = mesh_.num_triangles();
    std::vector<int32_t>& tri_surface = I.tri_surface;
    tri_surface.assign(m, 0);
    if (!c.triangle_surface.empty()) {
        if (c.triangle_surface.size() == m) {
            tri_surface = c.triangle_surface;
        } else if (c.triangle_surface.size() == mesh_.input_triangles) {
            for (size_t t = 0; t < m; ++t) tri_surface[t] = c.triangle_surface[size_t(mesh_.original_triangle[t])];
        } else {
            fail("config: triangle_surface has " + std::to_string(c.triangle_surface.size()) +
                 " entries, mesh has " + std::to_string(m) + " triangles");
        }
        for (size_t t = 0; t < m; ++t)
            if (tri_surface[t] < 0 || tri_surface[t] >= nsurf)
                fail("config: triangle " + std::to_string(t) + " has surface id " +
                     std::to_string(tri_surface[t]) + ", only " + std::to_string(nsurf) + " surfaces");
    }
    const int ntypes = int(c.ton_types.size());
    for (int t = 0; t < ntypes; ++t) {
        const TonType& tt = c.ton_types[t];
        const std::string at = "config: ton type " + std::to_string(t) + ": ";
        if (!(std::isfinite(tt.ks) && std::isfinite(tt.kp) && std::isfinite(tt.kf)) || tt.ks < 0 ||
            tt.kp < 0 || tt.kf < 0)
            fail(at + "motion probabilities must be finite and non-negative");
        for (float x : tt.initial_carry)
            if (!std::isfinite(x)) fail(at + "initial_carry has a non-finite value");
        if (!std::isfinite(tt.bounce_distance) || !(tt.bounce_distance > 0))
            fail(at + "bounce_distance must be positive and finite");
        if (!std::isfinite(tt.flow_step) || !(tt.flow_step > 0))
            fail(at + "flow_step must be positive and finite");
        if (!(tt.drip_angle_deg >= 0 && tt.drip_angle_deg <= 90))
            fail(at + "drip_angle_deg must be in [0, 90]");
        I.max_carry = std::max(I.max_carry, tt.initial_carry.size());
    }

    // Geometry constants.
    const float diag = mesh_.diagonal();
    I.diag = diag;
    I.centre = {0.5f * (mesh_.lo[0] + mesh_.hi[0]), 0.5f * (mesh_.lo[1] + mesh_.hi[1]),
                0.5f * (mesh_.lo[2] + mesh_.hi[2])};
    I.radius = 1.05f * 0.5f * diag;
    I.eps = 1e-5f * diag;
    I.down = unit(c.down);
    I.up = I.down * -1.0f;
    {
        double mu = INFINITY;
        for (size_t i = 0; i < 3 * m; ++i) {
            const float* v = &mesh_.vertices[3 * size_t(mesh_.triangles[i])];
            mu = std::min(mu, double(v[0]) * I.up.x + double(v[1]) * I.up.y + double(v[2]) * I.up.z);
        }
        I.min_up = float(mu);
    }

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
        if (r.kind == SourceKind::Spot) {
            if (!(s.angle_deg > 0 && s.angle_deg <= 180))
                {
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
                const V3 corner{(k & 1) ? mesh_.hi[0] : mesh_.lo[0], (k & 2) ? mesh_.hi[1] : mesh_.lo[1],
                                (k & 4) ? mesh_.hi[2] : mesh_.lo[2]};
                const float pu = dot(corner - I.centre, r.u), pv = dot(corner - I.centre, r.v);
                umin = std::min(umin, pu); umax = std::max(umax, pu);
                vmin = std::min(vmin, pv); vmax = std::max(vmax, pv);
            }
            r.pos = I.centre - r.dir * I.radius;
            r.u0 = umin; r.du = umax - umin;
            r.v0 = vmin; r.dv = vmax - vmin;
        }
        I.sources.push_back(r);
    }
    I.n_types = std::max(ntypes, 1);
    I.n_surfaces = nsurf;
    I.transport.assign(size_t(GAMMA_EVENT_COUNT) * I.n_types * nsurf, TransportSlot{});
    for (const TransportEntry& e : c.transports) {
        if (e.event < 0 || e.event >= GAMMA_EVENT_COUNT)
            fail("config: transport event " + std::to_string(e.event) + " out of range (0.." +
                 std::to_string(GAMMA_EVENT_COUNT - 1) + ")");
        if (e.ton_type < 0 || e.ton_type >= ntypes)
            fail("config: transport ton type index " + std::to_string(e.ton_type) + " out of range (" +
                 std::to_string(ntypes) + " ton types)");
        if (e.surface < 0 || e.surface >= nsurf)
            fail("config: transport surface index " + std::to_string(e.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        TransportSlot& sl = I.transport[(size_t(e.event) * I.n_types + e.ton_type) * nsurf + e.surface];
        sl.fn = reinterpret_cast<GammaTransportKernel>(static_cast<uintptr_t>(e.address));
        // Only property columns are logged; with none there is nothing to log.
        sl.writes = e.writes_surface && sl.fn && W > GAMMA_ROW_HEADER;
        sl.event = e.event;
        sl.ton_type = e.ton_type;
        sl.surface = e.surface;
    }
    I.update.assign(nsurf, nullptr);
    for (const UpdateEntry& u : c.updates) {
        if (u.surface < 0 || u.surface >= nsurf)
            fail("config: update surface index " + std::to_string(u.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        I.update[u.surface] = reinterpret_cast<GammaUpdateKernel>(static_cast<uintptr_t>(u.address));
    }
    I.appearance.assign(nsurf, nullptr);
    for (const AppearanceEntry& a : c.appearances) {
        if (a.surface < 0 || a.surface >= nsurf)
            fail("config: appearance surface index " + std::to_string(a.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        I.appearance[a.surface] = reinterpret_cast<GammaAppearanceKernel>(static_cast<uintptr_t>(a.address));
    }

    // Surfels.
    surf_ = sample_surfels(mesh_, size_t(c.surfels), c.seed);
    n_ = surf_.triangle.size();
    I.n_surfels = n_;
    w_ = W;
    surfel_surface_.resize(n_);
    rows_.resize(n_ * size_t(W));
    I.trees.resize(size_t(nsurf));
    for (size_t i = 0; i < n_; ++i) {
        int s = tri_surface[size_t(surf_.triangle[i])];
        surfel_surface_[i] = s;
        std::memcpy(&rows_[i * W], c.surface_rows[s].data(), sizeof(float) * W);
        SurfaceTree& t = I.trees[size_t(s)];
        t.index.push_back(uint32_t(i));
        t.pos.insert(t.pos.end(), &surf_.position[3 * i], &surf_.position[3 * i] + 3);
    }
    I.cloud = {surf_.position.data(), n_};
    I.kd = std::make_unique<KDTree>(3, I.cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
    for (SurfaceTree& t : I.trees) {
        if (t.index.empty()) continue;
        t.cloud = {t.pos.data(), t.index.size()};
        t.kd = std::make_unique<KDTree>(3, t.cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
    }
    I.sigma = float(std::sqrt(mesh_.area() / double(n_)));
    run_with_threads(c.threads, [&] {
        I.splat = build_splat_kernel(surf_.position.data(), surf_.normal.data(), surfel_surface_.data(), n_, I.sigma);
    });

    // Embree scene.
    I.device = rtcNewDevice(nullptr);
    if (!I.device) throw std::runtime_error("internal error: embree cannot create a device");
    I.scene = rtcNewScene(I.device);
    rtcSetSceneFlags(I.scene, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(I.scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry geom = rtcNewGeometry(I.device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_HIGH);
    float* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                            3 * sizeof(float), mesh_.num_vertices()));
    uint32_t* ib = static_cast<uint32_t*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), m));
    if (!vb || !ib) throw std::runtime_error("internal error: embree cannot allocate geometry buffers");
    std::memcpy(vb, mesh_.vertices.data(), sizeof(float) * mesh_.vertices.size());
    for (size_t i = 0; i < 3 * m; ++i) ib[i] = uint32_t(mesh_.triangles[i]);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(I.scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(I.scene);
    if (rtcGetDeviceError(I.device) != RTC_ERROR_NONE)
        throw std::runtime_error("internal error: embree scene build failed");
}

Simulation::~Simulation() = default;

void Simulation::set_rows(const float* data) { std::memcpy(rows_.data(), data, sizeof(float) * rows_.size()); }

uint32_t Simulation::nearest_surfel(const float p[3]) const { return impl_->nearest(p); }
uint32_t Simulation::nearest_surfel_of(int surface, const float p[3]) const {
    if (surface < 0 || surface >= impl_->n_surfaces) return impl_->nearest(p);
    return impl_->nearest_of(surface, p);
}

TraceStats Simulation::trace(int iteration) {
    const auto t0 = std::chrono::steady_clock::now();
    Impl& I = *impl_;
    const Config& c = cfg_;
    const int W = w_;
    const int P = W - GAMMA_ROW_HEADER;  // property columns
    // Active sources of this iteration, in declaration order.
    std::vector<size_t> active;
    std::vector<int64_t> start{0};
    for (size_t i = 0; i < c.sources.size(); ++i) {
        const Source& s = c.sources[i];
        if (iteration < s.first_iteration || (s.last_iteration != 0 && iteration > s.last_iteration)) continue;
        active.push_back(i);
        start.push_back(start.back() + s.count);
    }
    const int64_t total = start.back();
    // Weight of each active source's gamma-tons (SPEC 13.2): strength * n / N.
    std::vector<float> weight;
    for (size_t k = 0; k < active.size(); ++k) {
        const Source& s = c.sources[active[k]];
        weight.push_back(s.strength > 0 && s.count > 0 ? float(double(s.strength) * double(n_) / double(s.count))
                                                       : 1.0f);
    }
    const int64_t nchunks = (total + kChunkSize - 1) / kChunkSize;
    if (I.logs.size() < size_t(nchunks)) I.logs.resize(size_t(nchunks));
    const float* rows = rows_.data();
    const int32_t* surf_of = surfel_surface_.data();
    const int32_t* tri_surf = I.tri_surface.data();
    const int max_inter = c.max_interactions;
    const uint64_t seed = c.seed;
    const uint32_t iter_u = uint32_t(iteration);
    const V3 down = I.down, up = I.up;
    const float eps = I.eps;

    auto run_chunk = [&](int64_t ci) {
        ChunkLog& log = I.logs[size_t(ci)];
        log.surfel.clear();
        log.delta.clear();
        TraceStats st;
        std::vector<float> carry(I.max_carry, 0.0f);
        std::vector<float> delta(size_t(W), 0.0f), scratch(size_t(W), 0.0f);
        const int64_t begin = ci * kChunkSize, end = std::min(total, begin + kChunkSize);
        size_t a = size_t(std::upper_bound(start.begin(), start.end(), begin) - start.begin()) - 1;
        // interaction_key: mixed from (seed, iteration, gamma-ton, interaction);
        // each event's kernel gets its own random() key from it.
        float ton_weight = 1.0f;
        auto call = [&](const TransportSlot& sl, uint32_t s, GammaContext& ctx, uint64_t interaction_key) {
            set_random_key(ctx, mix64(interaction_key ^ uint64_t(sl.event)));
            int32_t bad;
            if (!sl.writes) {
                bad = sl.fn(carry.data(), rows + size_t(s) * W, scratch.data(), &ctx);
            } else {
                std::fill(delta.begin() + GAMMA_ROW_HEADER, delta.end(), 0.0f);
                bad = sl.fn(carry.data(), rows + size_t(s) * W, delta.data(), &ctx);
                if (ton_weight != 1.0f)
                    for (int j = GAMMA_ROW_HEADER; j < W; ++j) delta[size_t(j)] *= ton_weight;
                log.surfel.push_back(s);
                log.delta.insert(log.delta.end(), delta.begin() + GAMMA_ROW_HEADER, delta.end());
            }
            if (bad) count_nonfinite(st.nonfinite, sl.event, sl.ton_type, sl.surface, bad);
        };
        // Current interaction point.
        V3 p, n, dir;
        uint32_t prim = 0;
        RTCRayHit rh;
        auto take_hit = [&](V3 org, V3 d) {
            p = org + d * rh.ray.tfar;
            n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
            if (dot(n, d) > 0) n = n * -1.0f;
            dir = d;
            prim = rh.hit.primID;
        };
        // Straight ray; true if it hit (interaction point updated).
        auto straight = [&](V3 org, V3 d, float tnear, float tfar) {
            I.cast(rh, org, d, tnear, tfar);
            ++st.rays;
            if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
            take_hit(org, d);
            return true;
        };
        // Parabolic flight from p0 with velocity vel.  A zero launch speed (a
        // drip) is a straight fall along `down`: one ray, no discretisation.
        auto flight = [&](V3 p0, V3 vel, double dt) -> FlightEnd {
            if (vel.x == 0 && vel.y == 0 && vel.z == 0) {
                ++st.segments;
                return straight(p0, down, 0.0f, std::numeric_limits<float>::infinity()) ? FlightEnd::Landed
                                                                                          : FlightEnd::Escaped;
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
                    return (dot(sb, up) < I.min_up - eps && double(dot(vel, up)) - t < 0) ||
                           length(sb - I.centre) > 4.0f * I.diag;
                });
        };

        for (int64_t g = begin; g < end; ++g) {
            while (g >= start[a + 1]) ++a;
            const size_t src = active[a];
            const Source& so = c.sources[src];
            const int type = so.ton_type;
            const TonType& tt = c.ton_types[size_t(type)];
            ton_weight = weight[a];
            const float sin_drip = std::sin(tt.drip_angle_deg * 0.017453292519943295f);
            PhiloxStream rng(seed, iter_u, uint64_t(g));
            float ks = tt.ks, kp = tt.kp, kf = tt.kf;
            std::copy(tt.initial_carry.begin(), tt.initial_carry.end(), carry.begin());
            V3 org, d0;
            I.emit(I.sources[src], rng, org, d0);
            int inter = 0;
            ++st.emitted;
            if (!straight(org, d0, 0.0f, std::numeric_limits<float>::infinity())) {
                ++st.escaped;
                continue;
            }
            for (;;) {
                ++inter;
                const float pa[3] = {p.x, p.y, p.z};
                const uint32_t s = I.nearest_of(tri_surf[prim], pa);
                const int surface = surf_of[s];
                GammaContext ctx;
                ctx.position[0] = p.x; ctx.position[1] = p.y; ctx.position[2] = p.z;
                ctx.normal[0] = n.x; ctx.normal[1] = n.y; ctx.normal[2] = n.z;
                ctx.direction[0] = dir.x; ctx.direction[1] = dir.y; ctx.direction[2] = dir.z;
                ctx.height = dot(p, up) - I.min_up;
                ctx.iteration = iteration;
                ctx.interactions = inter;
                const float xi = rng.next();
                const float c1 = std::min(ks, 1.0f);
                const float c2 = std::min(c1 + kp, 1.0f);
                const float c3 = std::min(c2 + kf, 1.0f);
                const int event = xi < c1 ? GAMMA_EVENT_REFLECT
                                : xi < c2 ? GAMMA_EVENT_BOUNCE
                                : xi < c3 ? GAMMA_EVENT_FLOW
                                          : GAMMA_EVENT_SETTLE;
                const TransportSlot& hit = I.slot(GAMMA_EVENT_HIT, type, surface);
                const TransportSlot& ev = I.slot(event, type, surface);
                if (hit.fn || ev.fn) {
                    const uint64_t key = mix64(mix64(mix64(seed ^ uint64_t(iter_u)) ^ uint64_t(g)) ^ uint64_t(inter));
                    if (hit.fn) call(hit, s, ctx, key);
                    if (ev.fn) call(ev, s, ctx, key);
                }
                if (event == GAMMA_EVENT_SETTLE) { ++st.settled; break; }
                if (inter >= max_inter) { ++st.capped; break; }
                const float* row = rows + size_t(s) * W;
                const float ds = row[GAMMA_ROW_REFLECTANCE_STRAIGHT], dp = row[GAMMA_ROW_REFLECTANCE_PARABOLIC],
                            df = row[GAMMA_ROW_REFLECTANCE_FLOW];
                const float kp_left = std::max(kp - dp, 0.0f);
                ks = std::max(ks - ds, 0.0f);
                kf = std::max(kf + kp_left - df, 0.0f);
                kp = kp_left;
                FlightEnd fe = FlightEnd::Landed;
                if (event == GAMMA_EVENT_REFLECT) {
                    const float u = rng.next(), v = rng.next();
                    const V3 nd = uniform_hemisphere(n, u, v);
                    if (!straight(p + n * eps, nd, eps, std::numeric_limits<float>::infinity()))
                        fe = FlightEnd::Escaped;
                } else if (event == GAMMA_EVENT_BOUNCE) {
                    ++st.bounces;
                    const float u = rng.next(), v = rng.next();
                    const V3 ld = uniform_hemisphere(n, u, v);
                    const double D = tt.bounce_distance;
                    fe = flight(p + n * eps, ld * float(launch_speed(D)), flight_dt(D));
                } else {  // flow
                    ++st.flow_steps;
                    auto probe = [&](V3 org, V3 d, float tfar, FlowHit& h) {
                        I.cast(rh, org, d, 0.0f, tfar);
                        ++st.rays;
                        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
                        h.p = org + d * rh.ray.tfar;
                        h.n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                        if (dot(h.n, d) > 0) h.n = h.n * -1.0f;
                        h.prim = rh.hit.primID;
                        return true;
                    };
                    const FlowResult fr = flow_step(p, n, dir, down, tt.flow_step, eps, sin_drip, probe,
                                                    [&] { return rng.next(); });
                    if (fr.end == FlowEnd::Moved) {
                        p = fr.hit.p;
                        n = fr.hit.n;
                        prim = fr.hit.prim;
                        dir = fr.dir;
                    } else {
                        ++st.drips;  // an overhang, or the surface fell away beneath it
                        fe = flight(fr.drip_from, V3{0, 0, 0}, flight_dt(tt.bounce_distance));
                    }
                }
                if (fe == FlightEnd::Escaped) { ++st.escaped; break; }
                if (fe == FlightEnd::Capped) { ++st.capped; break; }
            }
            st.interactions += inter;
        }
        log.st = st;
    };

    run_with_threads(c.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, nchunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) run_chunk(ci);
        });
    });

    TraceStats total_st;
    bool any = false;
    for (int64_t ci = 0; ci < nchunks; ++ci) {
        const ChunkLog& log = I.logs[size_t(ci)];
        total_st.emitted += log.st.emitted;
        total_st.settled += log.st.settled;
        total_st.escaped += log.st.escaped;
        total_st.capped += log.st.capped;
        total_st.interactions += log.st.interactions;
        total_st.rays += log.st.rays;
        total_st.flow_steps += log.st.flow_steps;
        total_st.bounces += log.st.bounces;
        total_st.drips += log.st.drips;
        total_st.segments += log.st.segments;
        for (const NonFinite& nf : log.st.nonfinite)
            count_nonfinite(total_st.nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
        if (!log.surfel.empty()) any = true;
    }
    if (any && P > 0) {
        // Parallel merge over surfel ranges: every task scans the chunk logs in
        // chunk order and applies only the records of its own surfels, so each
        // surfel's sum has the same order for any partition (bit-identical).
        const size_t nranges = size_t(resolve_threads(c.threads));
        const size_t per = (n_ + nranges - 1) / nranges;
        I.delta.resize(n_ * size_t(P));
        float* D = I.delta.data();
        float* R = rows_.data();
        run_with_threads(c.threads, [&] {
            tbb::parallel_for(size_t(0), nranges, [&](size_t ri) {
                const uint32_t lo = uint32_t(std::min(n_, ri * per)), hi = uint32_t(std::min(n_, (ri + 1) * per));
                if (lo >= hi) return;
                std::fill(D + size_t(lo) * P, D + size_t(hi) * P, 0.0f);
                for (int64_t ci = 0; ci < nchunks; ++ci) {
                    const ChunkLog& log = I.logs[size_t(ci)];
                    const uint32_t* sv = log.surfel.data();
                    const size_t nrec = log.surfel.size();
                    for (size_t k = 0; k < nrec; ++k) {
                        const uint32_t s = sv[k];
                        if (s < lo || s >= hi) continue;
                        const float* rec = log.delta.data() + k * size_t(P);
                        float* d = D + size_t(s) * P;
                        for (int j = 0; j < P; ++j) d[j] += rec[j];
                    }
                }
            });
            // Spread every surfel's summed delta over its neighbourhood, then add.
            I.spread.resize(I.delta.size());
            apply_splat(I.splat, D, I.spread.data(), n_, P);
            const float* S = I.spread.data();
            tbb::parallel_for(tbb::blocked_range<size_t>(0, n_, 4096), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t s = r.begin(); s < r.end(); ++s)
                    for (int j = 0; j < P; ++j) R[s * W + GAMMA_ROW_HEADER + j] += S[s * P + j];
            });
        });
    }
    total_st.trace_seconds = seconds_since(t0);
    return total_st;
}

UpdateStats Simulation::update(int iteration) {
    const auto t0 = std::chrono::steady_clock::now();
    const Impl& I = *impl_;
    UpdateStats result;
    bool any = false;
    for (auto fn : I.update) any = any || fn;
    if (!any) {
        result.seconds = seconds_since(t0);
        return result;
    }
    const int W = w_;
    float* rows = rows_.data();
    const uint64_t iteration_key = mix64(mix64(cfg_.seed ^ 0xA5A5A5A5A5A5A5A5ULL) ^ uint64_t(uint32_t(iteration)));
    std::mutex nonfinite_lock;
    run_with_threads(cfg_.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n_, 4096), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<NonFinite> local;
            GammaContext ctx;
            for (size_t i = r.begin(); i < r.end(); ++i) {
                GammaUpdateKernel fn = I.update[size_t(surfel_surface_[i])];
                if (!fn) continue;
                for (int k = 0; k < 3; ++k) {
                    ctx.position[k] = surf_.position[3 * i + k];
                    ctx.normal[k] = surf_.normal[3 * i + k];
                    ctx.direction[k] = 0.0f;
                }
                ctx.height = dot(V3{ctx.position[0], ctx.position[1], ctx.position[2]}, I.up) - I.min_up;
                ctx.iteration = iteration;
                ctx.interactions = 0;
                set_random_key(ctx, mix64(iteration_key ^ uint64_t(i)));
                if (int32_t bad = fn(rows + i * W, &ctx))
                    count_nonfinite(local, -1, 0, surfel_surface_[i], bad);
            }
            if (!local.empty()) {  // integer counts: the order of merging does not matter
                std::lock_guard<std::mutex> hold(nonfinite_lock);
                for (const NonFinite& nf : local)
                    count_nonfinite(result.nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
            }
        });
    });
    result.seconds = seconds_since(t0);
    return result;
}

RaycastStats Simulation::raw_raycast(int64_t n_rays, int threads, uint64_t seed) {
    const auto t0 = std::chrono::steady_clock::now();
    const Impl& I = *impl_;
    const int64_t nchunks = (n_rays + kChunkSize - 1) / kChunkSize;
    std::vector<int64_t> hits(size_t(std::max<int64_t>(nchunks, 0)), 0);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, nchunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) {
                int64_t h = 0;
                const int64_t b = ci * kChunkSize, e = std::min(n_rays, b + kChunkSize);
                for (int64_t g = b; g < e; ++g) {
                    PhiloxStream rng(seed, 0, uint64_t(g));
                    V3 org, dir;
                    I.emit_env(rng, false, org, dir);
                    RTCRayHit rh;
                    I.cast(rh, org, dir, 0.0f);
                    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) ++h;
                }
                hits[size_t(ci)] = h;
            }
        });
    });
    RaycastStats st;
    st.rays = std::max<int64_t>(n_rays, 0);
    for (int64_t h : hits) st.hits += h;
    st.seconds = seconds_since(t0);
    return st;
}
namespace {

// Pinhole camera, vertical field of view fov_deg, row 0 = top.  dir(px, py)
// is the ray through image position (px, py) in pixels ((x + 0.5, y + 0.5) =
// the centre of pixel (x, y)).
struct Camera {
    V3 eye, fwd, right, camup;
    float th = 1, aspect = 1, w = 1, h = 1;
    Camera(std::array<float, 3> e, std::array<float, 3> target, std::array<float, 3> up, float fov_deg, int width,
           int height) {
        eye = V3{e[0], e[1], e[2]};
        fwd = normalize(V3{target[0], target[1], target[2]} - eye);
        right = normalize(cross(fwd, V3{up[0], up[1], up[2]}));
        if (!(length(right) > 0.5f)) {
            V3 t, b;
            onb(fwd, t, b);
            right = t;
        }
        camup = cross(right, fwd);
        th = std::tan(0.5f * fov_deg * 3.14159265358979f / 180.0f);
        w = float(width);
        h = float(std::max(height, 1));
        aspect = float(width) / h;
    }
    V3 dir(float px, float py) const {
        const float sx = (2.0f * px / w - 1.0f) * th * aspect;
        const float sy = (1.0f - 2.0f * py / h) * th;
        return normalize(fwd + right * sx + camup * sy);
    }
};

// Fixed Philox key and stream of the appearance render (independent of the
// simulation seed: the picture's noise does not change between runs).
constexpr uint64_t kRenderKey = 0x47414D4D41524E44ULL;  // "GAMMARND"
constexpr uint32_t kRenderStream = 0xFFFFFFFEu;         // sampling uses 0xFFFFFFFF

inline float clamp01(float x) { return x > 0.0f ? (x < 1.0f ? x : 1.0f) : 0.0f; }  // NaN -> 0

}  // namespace

void Simulation::render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                        std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                        float* out_value, float* out_shade) const {
    const Impl& I = *impl_;
    const Camera cam(eye, target, up, fov_deg, width, height);
    const V3 light = normalize(cam.fwd * -1.0f + cam.camup * 0.35f - cam.right * 0.35f);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    constexpr size_t K = kSmoothingNeighbours;
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, height, 1), [&](const tbb::blocked_range<int>& r) {
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < width; ++x) {
                    const V3 dir = cam.dir(float(x) + 0.5f, float(y) + 0.5f);
                    RTCRayHit rh;
                    I.cast(rh, cam.eye, dir, 0.0f);
                    const size_t px = size_t(y) * size_t(width) + size_t(x);
                    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
                        out_value[px] = nan;
                        out_shade[px] = nan;
                        continue;
                    }
                    const V3 p = cam.eye + dir * rh.ray.tfar;
                    const float q[3] = {p.x, p.y, p.z};
                    uint32_t idx[K];
                    double w[K];
                    const size_t k = I.smooth(I.tri_surface[rh.hit.primID], q, idx, w);
                    double sv = 0;
                    for (size_t j = 0; j < k; ++j) sv += w[j] * values[idx[j]];
                    out_value[px] = float(sv);
                    const V3 n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                    out_shade[px] = 0.25f + 0.75f * std::fabs(dot(n, light));
                }
        });
    });
}

size_t Simulation::smoothing_weights(int surface, const float p[3], uint32_t idx[kSmoothingNeighbours],
                                     double w[kSmoothingNeighbours]) const {
    return impl_->smooth(surface, p, idx, w);
}

void Simulation::interpolate_row(int surface, const float p[3], float* out) const {
    uint32_t idx[kSmoothingNeighbours];
    double w[kSmoothingNeighbours];
    const size_t k = impl_->smooth(surface, p, idx, w);
    const float* rows = rows_.data();
    for (int c = 0; c < w_; ++c) {
        double acc = 0;
        for (size_t j = 0; j < k; ++j) acc += w[j] * rows[size_t(idx[j]) * size_t(w_) + size_t(c)];
        out[c] = float(acc);
    }
}

float Simulation::smoothing_sigma() const { return impl_->sigma; }

int32_t Simulation::albedo_at(uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                              const float uv[2], int iteration, uint64_t random_key, float* row,
                              float* tex, float out_rgb[3]) const {
    const Impl& I = *impl_;
    const int surface = I.tri_surface[triangle];
    GammaAppearanceKernel fn = I.appearance[size_t(surface)];
    if (!fn) {
        out_rgb[0] = out_rgb[1] = out_rgb[2] = kNeutralAlbedo;
        return 0;
    }
    interpolate_row(surface, p, row);
    GammaContext ctx;
    for (int c = 0; c < 3; ++c) {
        ctx.position[c] = p[c];
        ctx.normal[c] = n[c];
        ctx.direction[c] = dir[c];
    }
    ctx.height = dot(V3{p[0], p[1], p[2]}, I.up) - I.min_up;
    ctx.iteration = iteration;
    ctx.interactions = 0;
    set_random_key(ctx, random_key);
    ctx.uv[0] = uv[0];
    ctx.uv[1] = uv[1];
    for (size_t ti = 0; ti < textures_.size(); ++ti) sample_texture(textures_[ti], uv[0], uv[1], tex + 3 * ti);
    float rgb[3] = {0, 0, 0};
    const int32_t bad = fn(row, tex, rgb, &ctx);
    for (int c = 0; c < 3; ++c) out_rgb[c] = clamp01(rgb[c]);
    return bad;
}

void Simulation::bake_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                             const float* uvs, int iteration, int threads, float* rows_out, float* rgb_out) const {
    const Impl& I = *impl_;
    const int W = w_;
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= I.tri_surface.size())
            throw Error("bake_points: triangle " + std::to_string(triangles[i]) + " out of range");
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 1024), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<float> tex(3 * textures_.size() + 1, 0.0f), scratch(static_cast<size_t>(W), 0.0f);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const uint32_t tri = uint32_t(triangles[i]);
                float* row = rows_out + i * size_t(W);
                // The row as the surface holds it, whether or not it has an appearance.
                interpolate_row(I.tri_surface[tri], positions + 3 * i, row);
                albedo_at(tri, positions + 3 * i, normals + 3 * i, none, uvs + 2 * i, iteration,
                          mix64(kRenderKey ^ uint64_t(i)), scratch.data(), tex.data(), rgb_out + 3 * i);
            }
        });
    });
}

void Simulation::set_textures(std::vector<Texture> textures) {
    for (size_t i = 0; i < textures.size(); ++i) {
        const Texture& t = textures[i];
        const std::string at = "set_textures: texture " + std::to_string(i) + " ";
        if (t.width < 1 || t.height < 1) throw Error(at + "must have a positive width and height");
        if (t.rgb.size() != size_t(t.width) * size_t(t.height) * 3)
            throw Error(at + "must have height*width*3 floats");
        for (float x : t.rgb)
            if (!std::isfinite(x)) throw Error(at + "has a non-finite value");
    }
    textures_ = std::move(textures);
}

RenderStats Simulation::render_appearance(const AppearanceParams& P, float* out) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Impl& I = *impl_;
    auto fail = [](const std::string& m) { throw Error("render_appearance: " + m); };
    if (P.width < 1 || P.height < 1) fail("width and height must be positive");
    if (int64_t(P.width) * int64_t(P.height) > (int64_t(1) << 28)) fail("image too large");
    if (!(P.fov_deg > 0 && P.fov_deg < 180)) fail("fov_deg must be in (0, 180)");
    if (!finite3(P.eye) || !finite3(P.target) || !finite3(P.up) || !finite3(P.sun))
        fail("eye, target, up and sun_direction must be finite");
    if (P.eye == P.target) fail("eye and target must differ");
    if (P.samples < 1 || P.samples > kMaxRenderSamples)
        fail("samples must be in 1.." + std::to_string(kMaxRenderSamples));
    if (P.ao_samples < 0 || P.ao_samples > kMaxAoSamples)
        fail("ao_samples must be in 0.." + std::to_string(kMaxAoSamples));
    if (P.threads > kMaxThreads) fail("threads must be at most " + std::to_string(kMaxThreads));

    const Camera cam(P.eye, P.target, P.up, P.fov_deg, P.width, P.height);
    const bool sun_on = nonzero3(P.sun);
    const V3 sun = sun_on ? unit(P.sun) : V3{0, 0, 0};
    const float ambient = sun_on ? kAmbientWithSun : kAmbientWithoutSun;
    const float ao_len = kAoLengthFraction * I.diag;
    const float inv_gamma = 1.0f / kDisplayGamma;
    const float eps = I.eps;
    const V3 up = I.up;
    const int S = P.samples, A = P.ao_samples;
    int grid = 1;  // strata per axis: the smallest g with g*g >= S
    while (grid * grid < S) ++grid;
    const int W = w_;
    const size_t T = textures_.size();
    const bool has_uvs = mesh_.has_uvs();
    const float* uvs = mesh_.uvs.data();
    RenderStats stats;
    std::mutex merge;

    run_with_threads(P.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, P.height, 1), [&](const tbb::blocked_range<int>& r) {
            // Per-task buffers: nothing is allocated per pixel.
            std::vector<float> row(size_t(W), 0.0f), tex(3 * T + 1, 0.0f);
            std::vector<NonFinite> bad_local;
            int64_t rays = 0, calls = 0;
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < P.width; ++x) {
                    const uint64_t pix = uint64_t(y) * uint64_t(P.width) + uint64_t(x);
                    double acc[3] = {0, 0, 0};
                    int hits = 0;
                    for (int s = 0; s < S; ++s) {
                        PhiloxStream rng(kRenderKey, kRenderStream, pix * uint64_t(S) + uint64_t(s));
                        float jx = 0.5f, jy = 0.5f;
                        if (S > 1) {
                            const float a = rng.next(), b = rng.next();
                            jx = (float(s % grid) + a) / float(grid);
                            jy = (float(s / grid) + b) / float(grid);
                        }
                        const V3 dir = cam.dir(float(x) + jx, float(y) + jy);
                        RTCRayHit rh;
                        I.cast(rh, cam.eye, dir, 0.0f);
                        ++rays;
                        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
                            const float t = 0.5f + 0.5f * dot(dir, up);
                            for (int c = 0; c < 3; ++c)
                                acc[c] += kSkyHorizon[c] + t * (kSkyZenith[c] - kSkyHorizon[c]);
                            continue;
                        }
                        ++hits;
                        const uint32_t prim = rh.hit.primID;
                        const V3 p = cam.eye + dir * rh.ray.tfar;
                        V3 n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                        if (dot(n, dir) > 0) n = n * -1.0f;
                        const int surface = I.tri_surface[prim];
                        // Albedo.
                        float albedo[3];
                        {
                            float uv[2] = {0.0f, 0.0f};
                            if (has_uvs) {
                                const float bu = rh.hit.u, bv = rh.hit.v, bw = 1.0f - bu - bv;
                                const float* c3 = uvs + 6 * size_t(prim);
                                uv[0] = bw * c3[0] + bu * c3[2] + bv * c3[4];
                                uv[1] = bw * c3[1] + bu * c3[3] + bv * c3[5];
                            }
                            const float q[3] = {p.x, p.y, p.z}, nn[3] = {n.x, n.y, n.z};
                            const float dd[3] = {dir.x, dir.y, dir.z};
                            if (I.appearance[size_t(surface)]) ++calls;
                            if (int32_t bad = albedo_at(prim, q, nn, dd, uv, P.iteration,
                                                        mix64(mix64(kRenderKey ^ pix) ^ uint64_t(s)),
                                                        row.data(), tex.data(), albedo))
                                count_nonfinite(bad_local, kAppearanceEvent, 0, surface, bad);
                        }
                        // Lighting: sky ambient x (1 - occluded fraction) + sun.
                        float light = ambient;
                        if (A > 0) {
                            int open = 0;
                            const V3 o = p + n * eps;
                            for (int a = 0; a < A; ++a) {
                                const float u1 = rng.next(), u2 = rng.next();
                                if (!I.occluded(o, cosine_hemisphere(n, u1, u2), eps, ao_len)) ++open;
                            }
                            rays += A;
                            light = ambient * (float(open) / float(A));
                        }
                        if (sun_on) {
                            const float cs = dot(n, sun);
                            if (cs > 0) {
                                ++rays;
                                if (!I.occluded(p + n * eps, sun, eps, std::numeric_limits<float>::infinity()))
                                    light += kSunIntensity * cs;
                            }
                        }
                        const float enc = std::pow(light, inv_gamma);  // pow(1, x) == 1 exactly
                        for (int c = 0; c < 3; ++c) acc[c] += clamp01(albedo[c] * enc);
                    }
                    float* o = out + 4 * size_t(pix);
                    for (int c = 0; c < 3; ++c) o[c] = float(acc[c] / double(S));
                    o[3] = float(double(hits) / double(S));
                }
            std::lock_guard<std::mutex> hold(merge);  // integer counts: order-free
            stats.rays += rays;
            stats.kernel_calls += calls;
            for (const NonFinite& nf : bad_local)
                count_nonfinite(stats.nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
        });
    });
    stats.seconds = seconds_since(t0);
    return stats;
}

}  // namespace gammart
