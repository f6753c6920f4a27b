#include "gamma/simulation.h"

#include <embree3/rtcore.h>
#include <nanoflann.hpp>
#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include "gamma/error.h"
#include "gamma/philox.h"
#include "gamma/vec.h"

namespace gammart {

namespace {

constexpr float kTwoPi = 6.28318530717958647692f;

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

enum class SourceKind { Point, Sphere, Hemisphere };

struct TransportSlot {
    GammaTransportKernel fn = nullptr;
    bool writes = false;
};

// Per-chunk log of surface deltas and counters; buffers are reused between
// iterations (cleared, capacity kept).
struct ChunkLog {
    std::vector<uint32_t> surfel;
    std::vector<float> delta;  // W floats per record
    TraceStats st;
};

inline V3 uniform_sphere(float u, float v) {
    float z = 1.0f - 2.0f * u;
    float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    float phi = kTwoPi * v;
    return {r * std::cos(phi), r * std::sin(phi), z};
}

// Cosine-weighted direction about unit n.
inline V3 cosine_hemisphere(V3 n, float u, float v) {
    float r = std::sqrt(u);
    float phi = kTwoPi * v;
    float z = std::sqrt(std::max(0.0f, 1.0f - u));
    V3 t, b;
    onb(n, t, b);
    return normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * z);
}

// Uniform direction over the hemisphere about unit n.
inline V3 uniform_hemisphere(V3 n, float u, float v) {
    float z = u;
    float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    float phi = kTwoPi * v;
    V3 t, b;
    onb(n, t, b);
    return normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * z);
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

struct Simulation::Impl {
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    Cloud cloud;
    std::unique_ptr<KDTree> kd;
    V3 centre;
    float radius = 1;   // environment source sphere radius
    float eps = 1e-5f;  // ray offset
    float sigma = 1;    // render kernel width (mean surfel spacing)
    int n_types = 0, n_surfaces = 0;
    std::vector<TransportSlot> transport;        // [event][type][surface]
    std::vector<GammaUpdateKernel> update;       // [surface]
    std::vector<SourceKind> kinds;
    std::vector<int64_t> source_start;           // prefix sums of counts
    size_t max_carry = 1;
    std::vector<ChunkLog> logs;
    std::vector<float> delta;                    // N*W merge buffer

    const TransportSlot& slot(int event, int type, int surface) const {
        return transport[(size_t(event) * n_types + type) * n_surfaces + surface];
    }

    ~Impl() {
        if (scene) rtcReleaseScene(scene);
        if (device) rtcReleaseDevice(device);
    }

    void cast(RTCRayHit& rh, V3 org, V3 dir, float tnear) const {
        rh.ray.org_x = org.x; rh.ray.org_y = org.y; rh.ray.org_z = org.z;
        rh.ray.dir_x = dir.x; rh.ray.dir_y = dir.y; rh.ray.dir_z = dir.z;
        rh.ray.tnear = tnear;
        rh.ray.tfar = std::numeric_limits<float>::infinity();
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

    // Environment-sphere emission (origin on the bounding sphere, cosine about
    // the inward normal); `upper` restricts origins to y >= centre.y.
    void emit_env(PhiloxStream& rng, bool upper, V3& org, V3& dir) const {
        float u = rng.next(), v = rng.next();
        V3 o = uniform_sphere(u, v);
        if (upper) o.y = std::fabs(o.y);
        org = centre + o * radius;
        float a = rng.next(), b = rng.next();
        dir = cosine_hemisphere(o * -1.0f, a, b);
    }

    uint32_t nearest(const float p[3]) const {
        uint32_t idx = 0;
        float d2 = 0;
        nanoflann::KNNResultSet<float, uint32_t> rs(1);
        rs.init(&idx, &d2);
        kd->findNeighbors(rs, p, nanoflann::SearchParams());
        return idx;
    }
};

int Simulation::threads_for(int requested) const {
    // <= 0: all hardware threads; more than the hardware offers is clamped
    // (results never depend on the thread count).
    const int hw = std::max(1, tbb::info::default_concurrency());
    if (requested <= 0) return hw;
    return std::min(requested, hw);
}

Simulation::Simulation(const Mesh& mesh, const Config& config)
    : impl_(std::make_unique<Impl>()), mesh_(mesh), cfg_(config) {
    const Config& c = cfg_;
    auto fail = [](const std::string& m) { throw Error(m); };
    if (c.surfels < 1) fail("config: surfels must be at least 1 (got " + std::to_string(c.surfels) + ")");
    if (c.surfels > 400000000) fail("config: surfels too large (" + std::to_string(c.surfels) + ")");
    if (c.max_interactions < 1)
        fail("config: max_interactions must be at least 1 (got " + std::to_string(c.max_interactions) + ")");
    if (c.row_width < GAMMA_ROW_HEADER)
        fail("config: row_width must be at least " + std::to_string(GAMMA_ROW_HEADER) + " (got " +
             std::to_string(c.row_width) + ")");
    if (c.surface_rows.empty()) fail("config: no surfaces (surface_rows is empty)");
    const int W = c.row_width;
    const int nsurf = int(c.surface_rows.size());
    for (int s = 0; s < nsurf; ++s) {
        if (int(c.surface_rows[s].size()) != W)
            fail("config: surface_rows[" + std::to_string(s) + "] has " +
                 std::to_string(c.surface_rows[s].size()) + " floats, row_width is " + std::to_string(W));
    }
    // Per-triangle surface ids (accept post- or pre-degenerate-removal length).
    const size_t m = mesh_.num_triangles();
    std::vector<int32_t> tri_surface(m, 0);
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
        if (!(std::isfinite(tt.ks) && std::isfinite(tt.kp) && std::isfinite(tt.kf)) || tt.ks < 0 ||
            tt.kp < 0 || tt.kf < 0)
            fail("config: ton type " + std::to_string(t) + " has invalid motion probabilities");
        impl_->max_carry = std::max(impl_->max_carry, tt.initial_carry.size());
    }
    impl_->source_start.push_back(0);
    for (size_t i = 0; i < c.sources.size(); ++i) {
        const Source& s = c.sources[i];
        const std::string at = "config: source " + std::to_string(i) + ": ";
        if (s.kind == "point") impl_->kinds.push_back(SourceKind::Point);
        else if (s.kind == "sphere") impl_->kinds.push_back(SourceKind::Sphere);
        else if (s.kind == "hemisphere") impl_->kinds.push_back(SourceKind::Hemisphere);
        else fail(at + "unknown source kind '" + s.kind + "' (expected point, sphere or hemisphere)");
        if (s.ton_type < 0 || s.ton_type >= ntypes)
            fail(at + "ton type index " + std::to_string(s.ton_type) + " out of range (" +
                 std::to_string(ntypes) + " ton types)");
        if (s.count < 0) fail(at + "negative count");
        for (float p : s.position)
            if (!std::isfinite(p)) fail(at + "non-finite position");
        impl_->source_start.push_back(impl_->source_start.back() + s.count);
    }
    impl_->n_types = std::max(ntypes, 1);
    impl_->n_surfaces = nsurf;
    impl_->transport.assign(size_t(GAMMA_EVENT_COUNT) * impl_->n_types * nsurf, TransportSlot{});
    for (const TransportEntry& e : c.transports) {
        if (e.event < 0 || e.event >= GAMMA_EVENT_COUNT)
            fail("config: transport event " + std::to_string(e.event) + " out of range");
        if (e.ton_type < 0 || e.ton_type >= ntypes)
            fail("config: transport ton type index " + std::to_string(e.ton_type) + " out of range (" +
                 std::to_string(ntypes) + " ton types)");
        if (e.surface < 0 || e.surface >= nsurf)
            fail("config: transport surface index " + std::to_string(e.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        TransportSlot& sl = impl_->transport[(size_t(e.event) * impl_->n_types + e.ton_type) * nsurf + e.surface];
        sl.fn = reinterpret_cast<GammaTransportKernel>(static_cast<uintptr_t>(e.address));
        sl.writes = e.writes_surface && sl.fn;
    }
    impl_->update.assign(nsurf, nullptr);
    for (const UpdateEntry& u : c.updates) {
        if (u.surface < 0 || u.surface >= nsurf)
            fail("config: update surface index " + std::to_string(u.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        impl_->update[u.surface] = reinterpret_cast<GammaUpdateKernel>(static_cast<uintptr_t>(u.address));
    }

    // Surfels.
    surf_ = sample_surfels(mesh_, size_t(c.surfels), c.seed);
    n_ = surf_.triangle.size();
    w_ = W;
    surfel_surface_.resize(n_);
    rows_.resize(n_ * size_t(W));
    for (size_t i = 0; i < n_; ++i) {
        int s = tri_surface[size_t(surf_.triangle[i])];
        surfel_surface_[i] = s;
        std::memcpy(&rows_[i * W], c.surface_rows[s].data(), sizeof(float) * W);
    }
    impl_->cloud = {surf_.position.data(), n_};
    impl_->kd = std::make_unique<KDTree>(3, impl_->cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));

    // Geometry constants.
    const float diag = mesh_.diagonal();
    impl_->centre = {0.5f * (mesh_.lo[0] + mesh_.hi[0]), 0.5f * (mesh_.lo[1] + mesh_.hi[1]),
                     0.5f * (mesh_.lo[2] + mesh_.hi[2])};
    impl_->radius = 1.05f * 0.5f * diag;
    impl_->eps = 1e-5f * diag;
    impl_->sigma = float(std::sqrt(mesh_.area() / double(n_)));

    // Embree scene.
    impl_->device = rtcNewDevice(nullptr);
    if (!impl_->device) throw std::runtime_error("embree: cannot create device");
    impl_->scene = rtcNewScene(impl_->device);
    rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_HIGH);
    float* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                            3 * sizeof(float), mesh_.num_vertices()));
    uint32_t* ib = static_cast<uint32_t*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), m));
    if (!vb || !ib) throw std::runtime_error("embree: cannot allocate geometry buffers");
    std::memcpy(vb, mesh_.vertices.data(), sizeof(float) * mesh_.vertices.size());
    for (size_t i = 0; i < 3 * m; ++i) ib[i] = uint32_t(mesh_.triangles[i]);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(impl_->scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(impl_->scene);
    if (rtcGetDeviceError(impl_->device) != RTC_ERROR_NONE)
        throw std::runtime_error("embree: scene build failed");
}

Simulation::~Simulation() = default;

void Simulation::set_rows(const float* data) { std::memcpy(rows_.data(), data, sizeof(float) * rows_.size()); }

uint32_t Simulation::nearest_surfel(const float p[3]) const { return impl_->nearest(p); }

TraceStats Simulation::trace(int iteration) {
    const auto t0 = std::chrono::steady_clock::now();
    Impl& I = *impl_;
    const Config& c = cfg_;
    const int W = w_;
    const int64_t total = I.source_start.back();
    const int64_t nchunks = (total + kChunkSize - 1) / kChunkSize;
    if (I.logs.size() < size_t(nchunks)) I.logs.resize(size_t(nchunks));
    const float* rows = rows_.data();
    const int32_t* surf_of = surfel_surface_.data();
    const int max_inter = c.max_interactions;
    const uint64_t seed = c.seed;
    const uint32_t iter_u = uint32_t(iteration);

    auto run_chunk = [&](int64_t ci) {
        ChunkLog& log = I.logs[size_t(ci)];
        log.surfel.clear();
        log.delta.clear();
        TraceStats st;
        std::vector<float> carry(I.max_carry, 0.0f);
        std::vector<float> delta(size_t(W), 0.0f);
        const int64_t begin = ci * kChunkSize, end = std::min(total, begin + kChunkSize);
        size_t src = size_t(std::upper_bound(I.source_start.begin(), I.source_start.end(), begin) -
                            I.source_start.begin()) - 1;
        auto call = [&](const TransportSlot& sl, uint32_t s, const GammaContext& ctx) {
            std::fill(delta.begin(), delta.end(), 0.0f);
            sl.fn(carry.data(), rows + size_t(s) * W, delta.data(), &ctx);
            if (sl.writes) {
                log.surfel.push_back(s);
                log.delta.insert(log.delta.end(), delta.begin(), delta.end());
            }
        };
        for (int64_t g = begin; g < end; ++g) {
            while (g >= I.source_start[src + 1]) ++src;
            const Source& so = c.sources[src];
            const TonType& tt = c.ton_types[size_t(so.ton_type)];
            PhiloxStream rng(seed, iter_u, uint64_t(g));
            float ks = tt.ks, kp = tt.kp, kf = tt.kf;
            std::copy(tt.initial_carry.begin(), tt.initial_carry.end(), carry.begin());
            V3 org, dir;
            switch (I.kinds[src]) {
                case SourceKind::Point: {
                    org = {so.position[0], so.position[1], so.position[2]};
                    float u = rng.next(), v = rng.next();
                    dir = uniform_sphere(u, v);
                    break;
                }
                case SourceKind::Sphere: I.emit_env(rng, false, org, dir); break;
                case SourceKind::Hemisphere: I.emit_env(rng, true, org, dir); break;
            }
            float tnear = 0.0f;
            int inter = 0;
            ++st.emitted;
            for (;;) {
                RTCRayHit rh;
                I.cast(rh, org, dir, tnear);
                ++st.rays;
                if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) { ++st.escaped; break; }
                ++inter;
                const float t = rh.ray.tfar;
                V3 p = org + dir * t;
                V3 ng = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                if (dot(ng, dir) > 0) ng = ng * -1.0f;
                const float pa[3] = {p.x, p.y, p.z};
                const uint32_t s = I.nearest(pa);
                const int surface = surf_of[s];
                GammaContext ctx;
                ctx.position[0] = p.x; ctx.position[1] = p.y; ctx.position[2] = p.z;
                ctx.normal[0] = ng.x; ctx.normal[1] = ng.y; ctx.normal[2] = ng.z;
                ctx.direction[0] = dir.x; ctx.direction[1] = dir.y; ctx.direction[2] = dir.z;
                ctx.iteration = iteration;
                ctx.interactions = inter;
                const float xi = rng.next();
                const float c1 = std::min(ks, 1.0f);
                const float c2 = std::min(c1 + kp, 1.0f);
                const float c3 = std::min(c2 + kf, 1.0f);
                const TransportSlot& hit = I.slot(GAMMA_EVENT_HIT, so.ton_type, surface);
                if (hit.fn) call(hit, s, ctx);
                if (!(xi < c1)) {
                    // Bounce and flow are not traced in this version: such a gamma-ton
                    // ends uncounted as settled and deposits nothing (the runner stops
                    // the run with an error rather than publish maps without them).
                    if (xi < c3) { ++st.untraced; break; }
                    const TransportSlot& se = I.slot(GAMMA_EVENT_SETTLE, so.ton_type, surface);
                    if (se.fn) call(se, s, ctx);
                    ++st.settled;
                    break;
                }
                if (inter >= max_inter) { ++st.capped; break; }
                const float* row = rows + size_t(s) * W;
                const float ds = row[GAMMA_ROW_DELTA_STRAIGHT], dp = row[GAMMA_ROW_DELTA_PARABOLIC],
                            df = row[GAMMA_ROW_DELTA_FLOW];
                const float kp_left = std::max(kp - dp, 0.0f);
                ks = std::max(ks - ds, 0.0f);
                kf = std::max(kf + kp_left - df, 0.0f);
                kp = kp_left;
                const float u = rng.next(), v = rng.next();
                dir = uniform_hemisphere(ng, u, v);
                org = p + ng * I.eps;
                tnear = I.eps;
            }
            st.interactions += inter;
        }
        log.st = st;
    };

    const int threads = threads_for(c.threads);
    tbb::task_arena arena(threads);
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, nchunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) run_chunk(ci);
        });
    });

    // Serial merge in chunk order (deterministic float sums).
    TraceStats total_st;
    bool any = false;
    for (int64_t ci = 0; ci < nchunks; ++ci) {
        const ChunkLog& log = I.logs[size_t(ci)];
        total_st.emitted += log.st.emitted;
        total_st.settled += log.st.settled;
        total_st.escaped += log.st.escaped;
        total_st.capped += log.st.capped;
        total_st.untraced += log.st.untraced;
        total_st.interactions += log.st.interactions;
        total_st.rays += log.st.rays;
        if (!log.surfel.empty()) any = true;
    }
    if (any) {
        I.delta.assign(rows_.size(), 0.0f);
        float* D = I.delta.data();
        for (int64_t ci = 0; ci < nchunks; ++ci) {
            const ChunkLog& log = I.logs[size_t(ci)];
            const float* rec = log.delta.data();
            for (size_t k = 0; k < log.surfel.size(); ++k, rec += W) {
                float* d = D + size_t(log.surfel[k]) * W;
                for (int j = 0; j < W; ++j) d[j] += rec[j];
            }
        }
        for (size_t i = 0; i < rows_.size(); ++i) rows_[i] += D[i];
    }
    total_st.trace_seconds = seconds_since(t0);
    return total_st;
}

double Simulation::update(int iteration) {
    const auto t0 = std::chrono::steady_clock::now();
    const Impl& I = *impl_;
    bool any = false;
    for (auto fn : I.update) any = any || fn;
    if (!any) return seconds_since(t0);
    const int W = w_;
    float* rows = rows_.data();
    tbb::task_arena arena(threads_for(cfg_.threads));
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n_, 4096), [&](const tbb::blocked_range<size_t>& r) {
            GammaContext ctx;
            for (size_t i = r.begin(); i < r.end(); ++i) {
                GammaUpdateKernel fn = I.update[size_t(surfel_surface_[i])];
                if (!fn) continue;
                for (int k = 0; k < 3; ++k) {
                    ctx.position[k] = surf_.position[3 * i + k];
                    ctx.normal[k] = surf_.normal[3 * i + k];
                    ctx.direction[k] = 0.0f;
                }
                ctx.iteration = iteration;
                ctx.interactions = 0;
                fn(rows + i * W, &ctx);
            }
        });
    });
    return seconds_since(t0);
}

RaycastStats Simulation::raw_raycast(int64_t n_rays, int threads, uint64_t seed) {
    const auto t0 = std::chrono::steady_clock::now();
    const Impl& I = *impl_;
    const int64_t nchunks = (n_rays + kChunkSize - 1) / kChunkSize;
    std::vector<int64_t> hits(size_t(std::max<int64_t>(nchunks, 0)), 0);
    tbb::task_arena arena(threads_for(threads));
    arena.execute([&] {
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

void Simulation::render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                        std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                        float* out_value, float* out_shade) const {
    const Impl& I = *impl_;
    const V3 E{eye[0], eye[1], eye[2]};
    const V3 fwd = normalize(V3{target[0], target[1], target[2]} - E);
    V3 right = normalize(cross(fwd, V3{up[0], up[1], up[2]}));
    if (!(length(right) > 0.5f)) {
        V3 t, b;
        onb(fwd, t, b);
        right = t;
    }
    const V3 camup = cross(right, fwd);
    const V3 light = normalize(fwd * -1.0f + camup * 0.35f - right * 0.35f);
    const float th = std::tan(0.5f * fov_deg * 3.14159265358979f / 180.0f);
    const float aspect = float(width) / float(std::max(height, 1));
    const float inv2s2 = 1.0f / (2.0f * I.sigma * I.sigma);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    constexpr size_t K = 8;
    tbb::task_arena arena(threads_for(threads));
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, height, 1), [&](const tbb::blocked_range<int>& r) {
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < width; ++x) {
                    const float sx = (2.0f * (float(x) + 0.5f) / float(width) - 1.0f) * th * aspect;
                    const float sy = (1.0f - 2.0f * (float(y) + 0.5f) / float(height)) * th;
                    const V3 dir = normalize(fwd + right * sx + camup * sy);
                    RTCRayHit rh;
                    I.cast(rh, E, dir, 0.0f);
                    const size_t px = size_t(y) * size_t(width) + size_t(x);
                    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
                        out_value[px] = nan;
                        out_shade[px] = nan;
                        continue;
                    }
                    const V3 p = E + dir * rh.ray.tfar;
                    const float q[3] = {p.x, p.y, p.z};
                    uint32_t idx[K];
                    float d2[K];
                    const size_t k = std::min(K, n_);
                    nanoflann::KNNResultSet<float, uint32_t> rs(k);
                    rs.init(idx, d2);
                    I.kd->findNeighbors(rs, q, nanoflann::SearchParams());
                    double sw = 0, sv = 0;
                    for (size_t j = 0; j < rs.size(); ++j) {
                        double wj = std::exp(-double(d2[j]) * inv2s2);
                        sw += wj;
                        sv += wj * values[idx[j]];
                    }
                    out_value[px] = sw > 0 ? float(sv / sw) : values[idx[0]];
                    const V3 n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                    out_shade[px] = 0.25f + 0.75f * std::fabs(dot(n, light));
                }
        });
    });
}

}  // namespace gammart
