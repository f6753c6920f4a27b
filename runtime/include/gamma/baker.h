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

// Where k texels lie in a band of a texture, for bake_texels' lattice:
// texel[i] = row * width + column within the band (rows rows of width
// texels), first_row the band's first row in the whole texture (the lattice
// is aligned to the whole texture's rows and columns, so a texel's rows do
// not depend on how the texture is cut into bands).
struct TexelGrid {
    const int64_t* texel = nullptr;
    size_t width = 0, rows = 0, first_row = 0;
};

// Texels between lattice points (every kLatticeStride-th row and column).
constexpr int kLatticeStride = 4;
// A texel takes its smoothed row from the lattice points around it when they
// all lie within this many smoothing lengths (SceneIndex::sigma, about a
// surfel spacing) of it, on its surface: the lattice is then about a quarter
// of a surfel spacing apart or closer.  The interpolated rows are as close to
// the field the surfels sample as the smoothing at every texel is (tested
// against an analytic field in tests/test_export.py); where the smoothing
// itself jumps (a point's 8 nearest surfels change) they spread the jump
// over a lattice cell.
constexpr float kLatticeReach = 0.375f;

// The texture channels of a texel, C = kTextureChannels + P floats: base
// colour (3), occlusion, roughness, metallic, the displacement, then P
// properties: property p of a texel on surface s is its smoothed row's slot
// slots[s * P + p], or 0 where that is -1 (the surface has no such
// property).  surface_of_triangle: the surface of each scene triangle.
constexpr size_t kTextureChannels = 7;
struct ChannelSlots {
    const int32_t* surface_of_triangle = nullptr;
    size_t triangles = 0;
    const int32_t* slots = nullptr;
    size_t surfaces = 0, properties = 0;
};

// The texture channels (k x C) at k texels of a layout, each given by its
// layout triangle and barycentrics (double): the point, the normal (the
// vertices' interpolated, normalised) and the lookup uv interpolated in
// double, then rounded; the smoothed row and look there as bake_points makes
// them.  With a grid, a texel whose lattice points around it are near enough
// (see kLatticeReach) takes the bilinear interpolation of their smoothed
// rows (in double, rounded once) instead of a neighbour search of its own;
// its look is still the appearance kernel's at the texel.  Throws
// gammart::Error for a triangle or texel out of range.
void bake_texels(const RenderScene& rs, const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                 const TexelGrid* grid, const ChannelSlots& slots, int iteration, int threads, float* channels_out);

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
