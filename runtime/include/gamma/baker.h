// The baker: property rows and appearance colours at arbitrary surface points
// (texels mapped back to the surface, or vertices), for textures and export.
// Uses the renderer's smoothing and albedo, so a baked colour is what the
// appearance render shows at that point under unit light.
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gamma/renderer.h"

namespace gammart {

// Points per shared neighbour search in bake_points.
constexpr size_t kBakeBlock = 64;

// At each of k surface points (position, normal, triangle, uv), the smoothed
// row (k x W) and the look (k x GAMMA_LOOK_WIDTH: abi.py's APPEARANCE_OUTPUTS).  Throws gammart::Error for a
// triangle out of range.
void bake_points(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                 const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                 float* look_out);

// A texture layout (export.py's Layout): its vertices (positions and unit
// normals, 3 floats each), its triangles' corners (3 vertex numbers each),
// per triangle the mesh's own texture coordinates (3 corners x 2 floats, for
// texture() lookups; null: none) and the scene triangle it is.
struct TexelLayout {
    const float* positions = nullptr;
    const float* normals = nullptr;
    const int32_t* corners = nullptr;
    const float* lookup_uvs = nullptr;
    const int32_t* scene_triangle = nullptr;
    size_t faces = 0;
};

// bake_points at k texels of a layout, each given by its layout triangle and
// barycentrics (double): the point, the normal (the vertices' interpolated,
// normalised) and the lookup uv interpolated in double, then rounded.
void bake_texels(const RenderScene& rs, const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                 int iteration, int threads, float* rows_out, float* look_out);

// Surface points baked again and again while the surfels stay (the live
// viewer's vertices, every iteration): their smoothing neighbours and
// weights are found once, so a bake is a weighted sum and the appearance
// kernels, with exactly bake_points' results.
struct BakePoints {
    std::vector<float> positions, normals, uvs;   // k*3, k*3, k*2
    std::vector<int32_t> triangles;               // k
    std::vector<uint32_t> neighbour;              // k*kSmoothingNeighbours
    std::vector<double> weight;                   // k*kSmoothingNeighbours
    std::vector<uint8_t> count;                   // k: neighbours used
    size_t size() const { return triangles.size(); }

    // Copies the points and finds their neighbours.  Throws gammart::Error
    // for a triangle out of range.
    static BakePoints prepare(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                              const int32_t* triangles, const float* uvs, int threads);
};
void bake_prepared(const RenderScene& rs, const BakePoints& points, int iteration, int threads, float* rows_out,
                   float* look_out);

}  // namespace gammart
