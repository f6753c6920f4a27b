// Gamma-ton sources: validation of the configured sources, their
// precomputed form in scene units, the emission of one gamma-ton (origin and
// direction from Philox draws), and which sources emit in an iteration.
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/config.h"
#include "gamma/philox.h"
#include "gamma/scene_index.h"
#include "gamma/surfel_state.h"
#include "gamma/vec.h"

namespace gammart {

enum class SourceKind { Point, Spot, Rect, Disk, Directional, Sphere, Hemisphere, Surface };
enum class Emission { Parallel, Uniform, Cosine };

// Source with everything precomputed in scene units.
struct SourceRt {
    SourceKind kind = SourceKind::Point;
    Emission emission = Emission::Parallel;
    V3 pos, dir, u, v;          // dir normalised; u, v in-plane axes (plane_axes(dir))
    float cos_a = -1, falloff = 0, w = 0, h = 0, radius = 0;
    float u0 = 0, du = 0, v0 = 0, dv = 0;  // directional: projected bbox rectangle
    V3 env_centre, env_up;      // sphere / hemisphere: bbox centre and up
    float env_radius = 1;
    // surface: the emitting surface, the axis (each surfel's normal, or dir), the
    // weight kernel, how far off the surface gamma-tons start, and during a pass
    // the iteration's table of surfels (surface_emitters) and the surfels' places
    int surface = -1;
    bool along_normal = false;
    uint64_t weight_kernel = 0;
    float offset = 0;
    const struct SurfaceEmitters* table = nullptr;
    const float* positions = nullptr;
    const float* normals = nullptr;
    const int32_t* surfel_triangle = nullptr;   // each surfel's triangle
    const float* mesh_vertices = nullptr;       // n*3
    const int32_t* mesh_triangles = nullptr;    // m*3
    float spread = 0;                           // origins within spread of the surfel (half its spacing)
};

// A surface source's surfels in one iteration: surfel[k] is picked with
// probability (cdf[k + 1] - cdf[k]) / total (its weight; every surfel stands
// for the same area, SPEC 13.2).  total 0: the source is silent this iteration.
struct SurfaceEmitters {
    bool surface_source = false;        // false: the source is of another kind (no table)
    std::vector<uint32_t> surfel;
    std::vector<double> cdf{0.0};
    double total() const { return cdf.back(); }
};

// Every source's table for `iteration` (empty for the sources that are not
// surface sources): the weight kernels run on a copy of each surfel's row as
// it is at the iteration's start, in parallel; the sums are formed in surfel
// order, so the tables do not depend on the thread count.  A weight that is
// not a positive finite number counts as 0.
std::vector<SurfaceEmitters> surface_emitters(const std::vector<SourceRt>& sources, const SurfelState& state,
                                              const SceneFrame& frame, int iteration, uint64_t seed, int threads);
// Which sources emit nothing in `iteration` although active: surface sources whose weights are all 0.
std::vector<uint8_t> silent_sources(const std::vector<SurfaceEmitters>& tables);

// Validates c.sources (throws gammart::Error naming the source) and
// precomputes them for the scene frame.
std::vector<SourceRt> build_sources(const Config& c, const SceneFrame& frame);

// Environment-sphere emission (origin on the sphere of radius R about c,
// cosine about the inward normal); `upper` reflects origins into the half
// dot(o, up) >= 0.  4 draws.
void emit_environment(V3 centre, float radius, V3 up, PhiloxStream& rng, bool upper, V3& org, V3& dir);

// Origin and direction of one gamma-ton of source s.
void emit(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir);

// emit() for the n consecutive gamma-tons first .. first + n - 1 of source
// s, bit for bit: rng[i] = PhiloxStream(seed, iteration, first + i) as emit
// leaves it, org[i], dir[i].
void emit_run(const SourceRt& s, uint64_t seed, uint32_t iteration, int64_t first, size_t n, PhiloxStream* rng,
              V3* org, V3* dir);

// The sources active in an iteration, in declaration order, and the first
// global gamma-ton index of each: source active[k] emits indices
// start[k] .. start[k+1]-1; start.back() is the iteration's total.
struct EmissionSchedule {
    std::vector<size_t> active;
    std::vector<int64_t> start{0};
    int64_t total() const { return start.back(); }
};
// `silent` (per source, may be empty): sources that emit nothing this iteration.
EmissionSchedule schedule(const std::vector<Source>& sources, int iteration,
                          const std::vector<uint8_t>& silent = {});

}  // namespace gammart
