// The simulation facade (see gamma/simulation.h): validates the config, wires
// the parts together and forwards each pass to its part.
#include "gamma/simulation.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

#include <tbb/task_group.h>

#include "gamma/baker.h"
#include "gamma/error.h"
#include "gamma/update_pass.h"

namespace gammart {

namespace {

// Refuses a surface that has triangles but received no surfel: its hits
// would touch another surface's surfel and run that surface's rules.  The
// areas are only for the message: summed once a surface is refused.
void require_surfels_on_every_surface(const Mesh& mesh, const SceneIndex& index, int64_t surfels) {
    const std::vector<size_t> per = index.surfels_per_surface();
    const std::vector<int32_t>& tri_surface = index.tri_surface();
    std::vector<size_t> triangles(per.size(), 0);
    for (const int32_t s : tri_surface) ++triangles[size_t(s)];
    for (size_t s = 0; s < per.size(); ++s) {
        if (triangles[s] == 0 || per[s] > 0) continue;
        double area = 0.0;
        for (size_t t = 0; t < tri_surface.size(); ++t) {
            if (size_t(tri_surface[t]) != s) continue;
            const float* a = &mesh.vertices[3 * size_t(mesh.triangles[3 * t])];
            const float* b = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + 1])];
            const float* c = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + 2])];
            const double u[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
            const double v[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
            const double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
            area += 0.5 * std::sqrt(x * x + y * y + z * z);
        }
        const double total = mesh.area();
        // the count printed as an integer (bounded): "%.0f" of a huge ratio could overflow the buffer
        const long long needed =
            static_cast<long long>(std::min(std::ceil(4.0 * total / std::max(area, 1e-300)), 1e18));
        char buf[512];
        std::snprintf(buf, sizeof buf,
                      "config: surface %zu has %zu triangle(s) (%.3g%% of the scene's area) but received no "
                      "surfel at %lld surfels, so its rules could never run on it; raise the surfel count to "
                      "about %lld or more, or assign those triangles to another surface",
                      s, triangles[s], 100.0 * area / total, static_cast<long long>(surfels), needed);
        throw Error(buf);
    }
}

// Surfel counts up to which the splat kernel is built beside the triangle
// lookup (their temporaries together stay far below the memory a 1.6M-surfel
// run peaks at).
constexpr size_t kSplatBesideMaxSurfels = 500000;

}  // namespace

Simulation::Simulation(const Mesh& mesh, const Config& config, SurfelSample* ahead, SetupSnapshot* snapshot,
                       const CancelToken& cancel)
    : mesh_(mesh), cfg_(config) {
    cancel.check("the setup");
    const Config& c = cfg_;
    const std::vector<int32_t> tri_surface = validate_config(c, mesh_);
    frame_ = SceneFrame::of(mesh_, c.down);
    sources_ = build_sources(c, frame_);
    kernels_ = KernelTable::from_config(c);
    const int nsurf = int(c.surface_rows.size());

    // The renders' corner normals need the mesh only: they are computed beside
    // the sampling, the indices, the splat kernel and the measures, in one
    // arena of the configured threads (their result never depends on the
    // scheduling; their time is their own wall time, overlapping the others').
    // The splat kernel needs the surfels only: up to kSplatBesideMaxSurfels
    // it is built beside the kd-trees and the triangle lookup (each one's
    // tail and remaining serial stretches, e.g. the kernel's transposition,
    // leave a core to the other); above, after them: both hold large
    // temporaries, and together they lifted the peak of 1.6M surfels on the
    // bunny from 1,873 to 2,057 MiB.  The Embree BVH is built outside the
    // arena, with the threads it always had (its layout never depends on
    // the configured count): at one thread first, as before; at more, on a
    // thread of its own beside the sampling (nothing before the kd-trees
    // and the lookup needs it), so its serial stretches no longer hold up
    // the setup.
    // A snapshot of this setup (setup_snapshot.h) gives the surfels, the
    // lookup and the splat kernel; prepared, the BVH, the kd-trees and the
    // corner normals too.
    if (snapshot != nullptr && snapshot->matches(mesh_, size_t(c.surfels), c.seed, tri_surface, nsurf))
        from_snapshot_ = FromSnapshot::Setup;
    else if (snapshot != nullptr && snapshot->matches_surfels(mesh_, size_t(c.surfels), c.seed))
        from_snapshot_ = FromSnapshot::Surfels;
    const bool whole = from_snapshot_ == FromSnapshot::Setup;
    if (from_snapshot_ != FromSnapshot::Nothing && snapshot->made_ahead()) {
        setup_made_ahead_ = true;
        setup_seconds_.sample_ahead = snapshot->sample_seconds();
        if (whole) setup_seconds_.ahead = snapshot->seconds_ahead();
    }
    const bool prepared = whole && snapshot->prepared();
    auto t0 = std::chrono::steady_clock::now();
    auto build_geometry = [&] {
        const auto t = std::chrono::steady_clock::now();
        index_->build_geometry(mesh_, tri_surface, nsurf);
        setup_seconds_.geometry = seconds_since(t);
    };
    std::unique_ptr<ThreadBeside> geometry;
    if (prepared) {
        index_ = snapshot->take_index();
        corner_normals_ = std::make_shared<const std::vector<float>>(snapshot->take_corner_normals());
        setup_seconds_.geometry = seconds_since(t0);
    } else {
        index_ = std::make_unique<SceneIndex>();
        if (resolve_threads(c.threads) == 1)
            build_geometry();
        else
            geometry = std::make_unique<ThreadBeside>(build_geometry);
    }
    run_with_threads(c.threads, [&] {
        tbb::task_group beside;
        try {
            if (!prepared)
                beside.run([&] {
                    const auto t = std::chrono::steady_clock::now();
                    update_corner_normals();
                    setup_seconds_.normals = seconds_since(t);
                });
            t0 = std::chrono::steady_clock::now();
            if (from_snapshot_ != FromSnapshot::Nothing) {
                state_ = SurfelState::of(snapshot->take_surfels(), tri_surface, c.surface_rows);
            } else if (ahead != nullptr && ahead->matches(mesh, size_t(c.surfels), c.seed)) {
                setup_seconds_.sample_ahead = ahead->seconds();
                state_ = SurfelState::of(ahead->take(), tri_surface, c.surface_rows);
            } else {
                state_ = SurfelState::sample(mesh_, tri_surface, size_t(c.surfels), c.seed, c.surface_rows, cancel);
            }
            setup_seconds_.sample = seconds_since(t0);
            cancel.check("the setup");
            const float sigma = float(std::sqrt(mesh_.area() / double(state_.size())));
            auto splat = [&] {
                const auto t = std::chrono::steady_clock::now();
                state_.splat = build_splat_kernel(state_.surf.position.data(), state_.surf.normal.data(),
                                                  state_.surface.data(), state_.size(), sigma);
                setup_seconds_.splat = seconds_since(t);
            };
            const bool splat_beside = !whole && state_.size() <= kSplatBesideMaxSurfels;
            if (splat_beside) beside.run(splat);
            if (geometry) geometry->wait();
            cancel.check("the setup");
            t0 = std::chrono::steady_clock::now();
            if (whole) {
                if (!prepared)
                    snapshot->adopt_index(*index_, state_.surf.position.data(), state_.surface.data(), sigma);
                state_.splat = snapshot->take_splat();
            } else {
                index_->build_surfels(state_.surf.position.data(), state_.surface.data(), state_.size(), sigma,
                                      c.threads);
            }
            setup_seconds_.surfels = seconds_since(t0);
            require_surfels_on_every_surface(mesh_, *index_, c.surfels);
            cancel.check("the setup");
            if (!splat_beside && !whole) splat();
            cancel.check("the setup");
            t0 = std::chrono::steady_clock::now();
            state_.measures = measure_surfels({c.measure_accessibility, c.measure_curvature, c.measure_uv}, mesh_,
                                              *index_, state_.surf, kAoLengthFraction * frame_.diag, c.seed,
                                              c.threads);
            setup_seconds_.measures = seconds_since(t0);
            beside.wait();
            cancel.check("the setup");
        } catch (...) {
            beside.cancel();
            beside.wait();
            throw;
        }
    });
    tracer_ = std::make_unique<Tracer>(cfg_, kernels_, sources_);
    tracer_->set_mesh(&mesh_);
}

Simulation::~Simulation() = default;

std::vector<uint8_t> Simulation::setup_snapshot() const {
    std::shared_lock<std::shared_mutex> reading(setup_lock_);
    if (shape_.rebuilds() > 0) throw Error("setup snapshot: the shape of the scene changed since the setup");
    return SetupSnapshot::write(mesh_, cfg_.seed, state_.surf, *index_, state_.splat);
}

uint32_t Simulation::write_setup_snapshot(int fd) const {
    std::shared_lock<std::shared_mutex> reading(setup_lock_);
    if (shape_.rebuilds() > 0) throw Error("setup snapshot: the shape of the scene changed since the setup");
    return SetupSnapshot::write_fd(fd, mesh_, cfg_.seed, state_.surf, *index_, state_.splat);
}

size_t Simulation::setup_snapshot_bytes() const {
    return SetupSnapshot::bytes(mesh_, state_.surf, *index_, state_.splat);
}

void Simulation::reconfigure(const Config& config) {
    std::unique_lock<std::shared_mutex> changing(setup_lock_);
    auto refuse = [](const std::string& why) { throw Error("reconfigure: " + why); };
    if (shape_.rebuilds() > 0) refuse("the shape of the scene changed");
    if (config.surfels != cfg_.surfels || config.seed != cfg_.seed) refuse("another surfel count or seed");
    if (config.surface_rows.size() != cfg_.surface_rows.size()) refuse("another number of surfaces");
    std::vector<int32_t> tri_surface = validate_config(config, mesh_);
    if (tri_surface != index_->tri_surface()) refuse("another binding of triangles to surfaces");
    // Everything below is what the constructor derives from the config; the
    // surfels, the scene index and the splat kernel depend only on what was
    // just checked to be the same.
    SceneFrame frame = SceneFrame::of(mesh_, config.down);
    std::vector<SourceRt> sources = build_sources(config, frame);
    KernelTable kernels = KernelTable::from_config(config);
    const int W = config.surface_rows.empty() ? 0 : int(config.surface_rows[0].size());
    std::vector<float> rows(state_.size() * size_t(W));
    for (size_t i = 0; i < state_.size(); ++i)
        std::memcpy(&rows[i * size_t(W)], config.surface_rows[size_t(state_.surface[i])].data(),
                    sizeof(float) * size_t(W));
    // the per-surfel measures depend on the surfels and the mesh only: computed
    // again only if the new effect reads others (same values as a fresh run)
    if (config.measure_accessibility != cfg_.measure_accessibility ||
        config.measure_curvature != cfg_.measure_curvature || config.measure_uv != cfg_.measure_uv)
        state_.measures = measure_surfels({config.measure_accessibility, config.measure_curvature, config.measure_uv},
                                          mesh_, *index_, state_.surf, kAoLengthFraction * frame.diag, config.seed,
                                          config.threads);
    cfg_ = config;
    frame_ = frame;
    sources_ = std::move(sources);
    kernels_ = std::move(kernels);
    state_.rows = std::move(rows);
    state_.width = W;
    tracer_ = std::make_unique<Tracer>(cfg_, kernels_, sources_);
    tracer_->set_mesh(&mesh_);
}

void Simulation::set_shading(std::vector<uint8_t> flat, float crease_deg) {
    if (!flat.empty() && flat.size() != mesh_.num_triangles())
        throw Error("set_shading: flat has " + std::to_string(flat.size()) + " flags for " +
                    std::to_string(mesh_.num_triangles()) + " triangles");
    if (!std::isfinite(crease_deg)) throw Error("set_shading: crease_deg must be finite");
    // the driver sets the shading right after the setup, mostly to what the
    // setup computed the normals for (no flat parts, the default crease)
    bool unchanged;
    {
        std::lock_guard<std::mutex> lock(corner_normals_mutex_);
        unchanged = !corner_normals_stale_ && flat == shading_flat_ && crease_deg == crease_deg_;
    }
    shading_flat_ = std::move(flat);
    crease_deg_ = crease_deg;
    // A surface is flat after a re-tiling when all of its triangles are now.
    const std::vector<int32_t>& tri_surface = index_->tri_surface();
    flat_surface_.assign(size_t(index_->n_surfaces()), shading_flat_.empty() ? 0 : 1);
    if (!shading_flat_.empty())
        for (size_t t = 0; t < tri_surface.size(); ++t)
            if (!shading_flat_[t]) flat_surface_[size_t(tri_surface[t])] = 0;
    if (!unchanged) update_corner_normals();
}

void Simulation::set_base_colours(BaseColours base) {
    auto fail = [](const std::string& m) { throw Error("set_base_colours: " + m); };
    if (!base.triangle_material.empty() && base.triangle_material.size() != mesh_.num_triangles())
        fail("one material per triangle is needed");
    if (base.texture.size() != base.factor.size()) fail("one texture index per material is needed");
    for (int32_t m : base.triangle_material)
        if (m < -1 || m >= int32_t(base.factor.size())) fail("material " + std::to_string(m) + " out of range");
    if (!base.rough_metal.empty() && base.rough_metal.size() != base.factor.size())
        fail("one roughness and metallic per material is needed");
    if (!base.rough_metal_texture.empty() && base.rough_metal_texture.size() != base.factor.size())
        fail("one metallic-roughness texture index per material is needed");
    for (const std::vector<int32_t>* list : {&base.texture, &base.rough_metal_texture})
        for (int32_t t : *list)
            if (t < -1 || t >= int32_t(base.images.size())) fail("texture " + std::to_string(t) + " out of range");
    for (const auto& f : base.factor)
        for (float x : f)
            if (!std::isfinite(x)) fail("a factor is not finite");
    for (const auto& f : base.rough_metal)
        for (float x : f)
            if (!(x >= 0.0f && x <= 1.0f)) fail("a roughness or metallic factor is outside [0, 1]");
    validate_textures(base.images);
    const std::vector<int32_t>& tri_surface = index_->tri_surface();
    constexpr int32_t kUnset = -2;
    surface_material_.assign(size_t(index_->n_surfaces()), kUnset);
    for (size_t t = 0; t < base.triangle_material.size(); ++t) {
        int32_t& sm = surface_material_[size_t(tri_surface[t])];
        sm = sm == kUnset || sm == base.triangle_material[t] ? base.triangle_material[t] : -1;
    }
    for (int32_t& sm : surface_material_)
        if (sm == kUnset) sm = -1;
    base_ = std::move(base);
}

void Simulation::prepare_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                                const float* uvs, int threads, const CancelToken& cancel) {
    prepared_ = BakePoints::prepare(render_scene(cancel), k, positions, normals, triangles, uvs, threads);
}

void Simulation::bake_prepared(int iteration, int threads, float* rows_out, float* look_out,
                               const CancelToken& cancel) const {
    if (prepared_.size() == 0) throw Error("bake_prepared: no points prepared (or the shape changed since)");
    gammart::bake_prepared(render_scene(cancel), prepared_, iteration, threads, rows_out, look_out);
}

void Simulation::update_corner_normals() {
    std::lock_guard<std::mutex> lock(corner_normals_mutex_);
    refresh_corner_normals();
}

void Simulation::refresh_corner_normals() const {
    std::vector<float> fresh;
    run_with_threads(cfg_.threads, [&] { fresh = gammart::corner_normals(mesh_, shading_flat_, crease_deg_); });
    corner_normals_ = std::make_shared<const std::vector<float>>(std::move(fresh));
    corner_normals_stale_ = false;
}

std::shared_ptr<const std::vector<float>> Simulation::corner_normals() const {
    std::lock_guard<std::mutex> lock(corner_normals_mutex_);
    if (corner_normals_stale_) refresh_corner_normals();
    return corner_normals_;
}

void Simulation::set_rows(const float* data) {
    std::memcpy(state_.rows.data(), data, sizeof(float) * state_.rows.size());
}

uint32_t Simulation::nearest_surfel(const float p[3]) const { return index_->nearest(p); }
uint32_t Simulation::nearest_surfel_of(int surface, const float p[3]) const { return index_->nearest_of(surface, p); }

TraceStats Simulation::trace(int iteration, const CancelToken& cancel) {
    shape_.begin_iteration(state_);
    return tracer_->trace(iteration, *index_, frame_, state_, cancel);
}

ShapeStats Simulation::shape(int iteration, const CancelToken& cancel) {
    cancel.check("the shape step");
    std::unique_lock<std::shared_mutex> changing(setup_lock_);
    ShapeStats st = shape_.apply(iteration, mesh_, state_, index_, frame_);
    if (st.changed) {
        if (!base_.triangle_material.empty()) {
            const std::vector<int32_t>& tri_surface = index_->tri_surface();
            base_.triangle_material.resize(tri_surface.size());
            for (size_t t = 0; t < tri_surface.size(); ++t)
                base_.triangle_material[t] = surface_material_[size_t(tri_surface[t])];
        }
        if (!shading_flat_.empty()) {
            const std::vector<int32_t>& tri_surface = index_->tri_surface();
            shading_flat_.resize(tri_surface.size());
            for (size_t t = 0; t < tri_surface.size(); ++t) shading_flat_[t] = flat_surface_[size_t(tri_surface[t])];
        }
        {
            std::lock_guard<std::mutex> lock(corner_normals_mutex_);
            corner_normals_stale_ = true;   // recomputed by the next render or bake (corner_normals())
        }
        prepared_ = BakePoints{};      // new surfels and triangles: the caller prepares its points again
    }
    return st;
}

UpdateStats Simulation::update(int iteration, const CancelToken& cancel) {
    cancel.check("the update");
    return run_update_pass(kernels_, frame_, state_, iteration, cfg_.seed, cfg_.threads);
}

RaycastStats Simulation::raw_raycast(int64_t n_rays, int threads, uint64_t seed) {
    return gammart::raw_raycast(*index_, frame_, n_rays, threads, seed);
}

std::vector<RecordedRay> Simulation::record_rays(int iteration) {
    const std::vector<float> saved = state_.rows;
    tracer_->set_record_rays(true);
    try {
        tracer_->trace(iteration, *index_, frame_, state_);
    } catch (...) {
        tracer_->set_record_rays(false);
        state_.rows = saved;
        throw;
    }
    tracer_->set_record_rays(false);
    state_.rows = saved;
    return tracer_->take_recorded_rays();
}

RaycastStats Simulation::cast_rays(const std::vector<RecordedRay>& rays, int threads) const {
    return cast_recorded(*index_, rays, threads);
}

void Simulation::render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                        std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                        float* out_value, float* out_shade, const CancelToken& cancel) const {
    render_false_colour(render_scene(cancel), values, eye, target, up, fov_deg, width, height, threads, out_value,
                        out_shade);
}

FalseColourView Simulation::false_colour_view(std::array<float, 3> eye, std::array<float, 3> target,
                                              std::array<float, 3> up, float fov_deg, int width, int height,
                                              int threads, const CancelToken& cancel) const {
    return gammart::false_colour_view(render_scene(cancel), eye, target, up, fov_deg, width, height, threads);
}

size_t Simulation::smoothing_weights(int surface, const float p[3], uint32_t idx[kSmoothingNeighbours],
                                     double w[kSmoothingNeighbours]) const {
    return index_->smooth(surface, p, idx, w);
}

void Simulation::interpolate_row(int surface, const float p[3], float* out) const {
    gammart::interpolate_row(render_scene(), surface, p, out);
}

float Simulation::smoothing_sigma() const { return index_->sigma(); }

int32_t Simulation::look_at(uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                            const float uv[2], int iteration, uint64_t random_key, float* row, float* tex,
                            float out_look[GAMMA_LOOK_WIDTH]) const {
    return gammart::look_at(render_scene(), triangle, p, n, dir, uv, iteration, random_key, row, tex, out_look);
}

void Simulation::bake_texels(const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                             const TexelGrid* grid, const ChannelSlots& slots, int iteration, int threads,
                             float* channels_out, const CancelToken& cancel) const {
    gammart::bake_texels(render_scene(cancel), layout, k, tris, bary, grid, slots, iteration, threads, channels_out);
}

void Simulation::bake_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                             const float* uvs, int iteration, int threads, float* rows_out, float* look_out,
                             const CancelToken& cancel) const {
    gammart::bake_points(render_scene(cancel), k, positions, normals, triangles, uvs, iteration, threads, rows_out,
                         look_out);
}

void Simulation::set_textures(std::vector<Texture> textures) {
    validate_textures(textures);
    textures_ = std::move(textures);
}

RenderStats Simulation::render_appearance(const AppearanceParams& params, float* out_rgba,
                                          const CancelToken& cancel) const {
    return gammart::render_appearance(render_scene(cancel), params, out_rgba);
}

}  // namespace gammart
