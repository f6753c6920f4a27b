// The baker: property rows and appearance colours at arbitrary surface points
// (texels mapped back to the surface, or vertices), for textures and export.
// Uses the renderer's smoothing and albedo, so a baked colour is what the
// appearance render shows at that point under unit light.
#pragma once
#include <cstddef>
#include <cstdint>

#include "gamma/renderer.h"

namespace gammart {

// At each of k surface points (position, normal, triangle, uv), the smoothed
// row (k x W) and the appearance colour (k x 3).  Throws gammart::Error for a
// triangle out of range.
void bake_points(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                 const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                 float* rgb_out);

}  // namespace gammart
