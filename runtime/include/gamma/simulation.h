#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "gamma/config.h"
#include "gamma/mesh.h"
#include "gamma/surfels.h"

namespace gammart {

struct TraceStats {
    int64_t emitted = 0, settled = 0, escaped = 0, capped = 0, untraced = 0;
    int64_t interactions = 0, rays = 0;
    double trace_seconds = 0;
};

struct RaycastStats {
    int64_t rays = 0, hits = 0;
    double seconds = 0;
};

// Number of gamma-tons per parallel work item.  Never depends on thread count.
constexpr int64_t kChunkSize = 1024;

class Simulation {
public:
    // Validates config (throws gammart::Error), resamples surfels, builds the
    // Embree scene and the surfel kd-tree.
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
    double update(int iteration);
    RaycastStats raw_raycast(int64_t n_rays, int threads, uint64_t seed);
    // Out arrays are height*width.
    void render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                float* out_value, float* out_shade) const;

    // Index of the surfel nearest to p.
    uint32_t nearest_surfel(const float p[3]) const;

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
    int threads_for(int requested) const;
};

}  // namespace gammart
