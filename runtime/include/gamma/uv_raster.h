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
// shares one neighbour search among a run of them).  On `threads` threads
// (0: all), with the same result.
UvRaster rasterise_uv(const double* uvs, size_t m, int size, int row0, int row1, int tile = 1, int threads = 0);

}  // namespace gammart

namespace gammart {

// The gutters of a chart atlas filled `passes` rings deep, in place
// (atlas.py's dilate): image is rows x cols x C floats, label the chart of
// each texel (-1: empty), updated as rings fill.  A ring is every empty texel
// with a filled 8-neighbour; each takes the chart most of its filled
// neighbours belong to (the lowest-numbered on a tie) and the mean of those
// neighbours' values (summed in double in the order (-1,-1), (-1,0), (-1,1),
// (0,-1), (0,1), (1,-1), (1,0), (1,1), divided by their count, rounded to
// float), all from the image as it was before the ring.  Colours of two
// charts are never mixed.
void dilate_charts(float* image, int32_t* label, size_t rows, size_t cols, size_t channels, int passes,
                   int threads);

}  // namespace gammart
