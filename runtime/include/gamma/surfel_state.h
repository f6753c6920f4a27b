// The surfel state of a run: where the surfels are (positions, normals,
// triangles), which surface each belongs to, and their rows (N x W floats:
// the gamma-reflectance header, then the properties).
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"
#include "gamma/splat.h"
#include "gamma/surfel_measures.h"
#include "gamma/surfels.h"

namespace gammart {

struct SurfelState {
    SurfelSet surf;
    std::vector<int32_t> surface;  // N: surface id of each surfel
    std::vector<float> rows;       // N*W
    int width = 0;                 // W
    SplatKernel splat;             // where a surfel's deltas spread (SPEC §13.2); built at setup
    SurfelMeasures measures;       // accessibility, curvature, uv (those requested; SPEC §12)

    size_t size() const { return surface.size(); }
    float* row(size_t i) { return rows.data() + i * size_t(width); }
    const float* row(size_t i) const { return rows.data() + i * size_t(width); }

    // Samples n surfels on `mesh` (seeded) and gives each the initial row of
    // its triangle's surface (surface_rows[s], W floats each).
    static SurfelState sample(const Mesh& mesh, const std::vector<int32_t>& tri_surface, size_t n, uint64_t seed,
                              const std::vector<std::vector<float>>& surface_rows,
                              const CancelToken& cancel = CancelToken::never());
    // The same state from surfels sampled already (sample_surfels' result).
    static SurfelState of(SurfelSet surf, const std::vector<int32_t>& tri_surface,
                          const std::vector<std::vector<float>>& surface_rows);
};

// Surfels sampled before the simulation is set up: `gammac run` samples them
// while it is still importing, reading and checking the effect (the sampling
// needs only the mesh, the count and the seed; the binding of triangles to
// surfaces comes later).  A Simulation given one takes its surfels only when
// they are what it would sample itself: same count, same seed, a mesh with
// the same vertices, triangles and bounds (sample_surfels reads nothing
// else, and its result does not depend on the thread count); otherwise it
// samples as always.  Construction never throws for a bad count or mesh: a
// failed sample holds no surfels (`ok()` false), and the Simulation's own
// sampling reports the error where it always did.  `mesh` must outlive the
// sample (it is compared, not copied).
class SurfelSample {
public:
    // `cancel`: the sampling stops, and ok() is false (its owner left).
    SurfelSample(const Mesh& mesh, size_t n, uint64_t seed, int threads,
                 const CancelToken& cancel = CancelToken::never());
    bool ok() const { return ok_; }
    bool matches(const Mesh& mesh, size_t n, uint64_t seed) const;
    // The surfels, moved out: afterwards ok() is false.
    SurfelSet take();
    size_t count() const { return n_; }
    uint64_t seed() const { return seed_; }
    double seconds() const { return seconds_; }  // wall time of the sampling

private:
    const Mesh* mesh_;
    size_t n_ = 0;
    uint64_t seed_ = 0;
    SurfelSet surf_;
    bool ok_ = false;
    double seconds_ = 0;
};

}  // namespace gammart
