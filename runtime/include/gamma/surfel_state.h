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
                              const std::vector<std::vector<float>>& surface_rows);
};

}  // namespace gammart
