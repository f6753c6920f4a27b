// The texels a texture layout covers: triangles rasterised in UV space, for
// the export's bake (compiler/gamma/driver/export.py).
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

namespace gammart {

struct UvRaster {
    std::vector<int64_t> texels;  // flat texel index i * size + j, increasing
    std::vector<int32_t> tris;    // the triangle that covers it
    std::vector<double> bary;     // its barycentrics (3 per texel)
};

// The texels of rows [row0, row1) of a size x size texture whose centres lie
// inside triangles given by their corner uvs (m x 3 x 2 doubles, v up):
// texel (i, j) has its centre at u = (j + 0.5) / size, v = 1 - (i + 0.5) /
// size; a texel inside several triangles goes to the lowest-numbered one.
// Inside means each barycentric >= -1e-9, computed in double in the
// order export.py's reference writes it; triangles whose uv area is under
// 1e-18 texels squared, or with a non-finite corner, cover nothing.
// The texels come tile by tile (tiles of tile x tile texels in row-major
// order, row-major inside a tile; tile = 1: in increasing index order), so
// that consecutive texels lie close together on the surface (the baker
// shares one neighbour search among a run of them).
UvRaster rasterise_uv(const double* uvs, size_t m, int size, int row0, int row1, int tile = 1);

}  // namespace gammart
