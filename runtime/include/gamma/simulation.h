#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "gamma/config.h"
#include "gamma/mesh.h"
#include "gamma/render.h"
#include "gamma/surfels.h"

namespace gammart {

// How often a kernel's statement produced NaN or infinity (the store was
// skipped).  event is GAMMA_EVENT_* for transport kernels, -1 for update.
struct NonFinite {
    int event = 0, ton_type = 0, surface = 0, statement = 0;
    int64_t count = 0;
};

// Adds one occurrence, keeping the list sorted (so merges are order-free).
void count_nonfinite(std::vector<NonFinite>& list, int event, int ton_type, int surface,
                     int statement, int64_t count = 1);

struct TraceStats {
    int64_t emitted = 0, settled = 0, escaped = 0, capped = 0;
    int64_t interactions = 0, rays = 0;
    int64_t flow_steps = 0, bounces = 0, drips = 0, segments = 0;
    std::vector<NonFinite> nonfinite;
    double trace_seconds = 0;
};

struct UpdateStats {
    std::vector<NonFinite> nonfinite;
    double seconds = 0;
};

// Counters of one render_appearance call.  nonfinite: event kAppearanceEvent,
// ton_type 0, surface, statement, count (per camera sample that hit).
struct RenderStats {
    int64_t rays = 0, kernel_calls = 0;
    std::vector<NonFinite> nonfinite;
    double seconds = 0;
};

struct RaycastStats {
    int64_t rays = 0, hits = 0;
    double seconds = 0;
};

// Number of gamma-tons per parallel work item.  Never depends on thread count.
constexpr int64_t kChunkSize = 1024;
// Largest accepted thread count.
constexpr int kMaxThreads = 1024;

// Runs f inside a task arena of exactly `threads` threads (<= 0: all hardware
// threads); a global_control lifts TBB's default cap at the core count.
void run_with_threads(int threads, const std::function<void()>& f);
int resolve_threads(int threads);

// Landing of a parabolic flight (g = 1, launch speed sqrt(D) along unit d) on
// the plane dot(x, up) = floor_height, up = -normalize(down): `traced` as the
// tracer's piecewise-linear chords meet the plane, `analytic` the exact
// parabola.  Throws gammart::Error if the flight never reaches the plane.
void parabola_landing(std::array<float, 3> p0, std::array<float, 3> d, float D, std::array<float, 3> down,
                      float floor_height, std::array<float, 3>& traced, std::array<float, 3>& analytic);

class Simulation {
public:
    // Validates config (throws gammart::Error), resamples surfels, builds the
    // Embree scene and the surfel kd-trees.
    Simulation(const Mesh& mesh, const Config& config);
    ~Simulation();
    Simulation(const Simulation&) = delete;
    Simulation& operator=(const Simulation&) = delete;

    size_t num_surfels() const { return n_; }
    int row_width() const { return w_; }
    const SurfelSet& surfels() const { return surf_; }
    const std::vector<int32_t>& surfel_surfaces() const { return surfel_surface_; }
    const std::vector<float>& rows() const { return rows_; }
    void set_rows(const float* data);  // N*W floats

    TraceStats trace(int iteration);
    UpdateStats update(int iteration);
    RaycastStats raw_raycast(int64_t n_rays, int threads, uint64_t seed);
    // Out arrays are height*width.
    void render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                float* out_value, float* out_shade) const;

    // Textures for the appearance kernels (kernel argument `textures`, 3
    // floats per texture in this order).  Throws gammart::Error.
    void set_textures(std::vector<Texture> textures);
    const std::vector<Texture>& textures() const { return textures_; }
    // Physically plausible preview: appearance kernels per camera sample,
    // sky ambient x AO + sun with shadows.  out_rgba: height*width*4.
    // Throws gammart::Error on bad parameters.
    RenderStats render_appearance(const AppearanceParams& params, float* out_rgba) const;

    // The property smoothing shared by both renders: the k = 8 nearest
    // surfels of `surface` to p (all surfels if the surface has none; the
    // nearest k of all if surface is out of range), Gaussian weights
    // exp(-d^2 / (2 sigma^2)), sigma = sqrt(A/N), normalised to sum 1; if
    // every weight underflows, the nearest surfel alone (weight 1).  Returns
    // the number of neighbours written to idx / w (nearest first).
    size_t smoothing_weights(int surface, const float p[3], uint32_t idx[kSmoothingNeighbours],
                             double w[kSmoothingNeighbours]) const;
    // The smoothed row (W floats): out[c] = float(sum_j w_j * row_j[c]).
    void interpolate_row(int surface, const float p[3], float* out) const;
    // The colour the surface's appearance kernel gives at point p of triangle
    // `triangle` (normal n, texture coordinates uv) with the smoothed row,
    // clamped to [0, 1]; the neutral albedo without a kernel.  `row` (W floats)
    // and `tex` (3 per texture) are scratch; returns the kernel's non-finite report.
    int32_t albedo_at(uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                      const float uv[2], int iteration, uint64_t random_key, float* row, float* tex,
                      float out_rgb[3]) const;
    // For baking and export: at each of k surface points (position, normal,
    // triangle, uv), the smoothed row (k x W) and the appearance colour (k x 3).
    void bake_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                     const float* uvs, int iteration, int threads, float* rows_out, float* rgb_out) const;
    float smoothing_sigma() const;

    // Filled by the Python binding after render_appearance (GIL held).
    RenderStats last_render;

    // Index of the surfel nearest to p (any surface).
    uint32_t nearest_surfel(const float p[3]) const;
    // Index of the surfel of `surface` nearest to p (any surfel if the
    // surface received none).
    uint32_t nearest_surfel_of(int surface, const float p[3]) const;

    struct Impl;

private:
    std::unique_ptr<Impl> impl_;
    Mesh mesh_;
    Config cfg_;
    size_t n_ = 0;
    int w_ = 0;
    SurfelSet surf_;
    std::vector<int32_t> surfel_surface_;
    std::vector<float> rows_;
    std::vector<Texture> textures_;
};

}  // namespace gammart
