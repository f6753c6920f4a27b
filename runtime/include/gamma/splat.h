// The splat kernel (SPEC §13.2): a rule's surface deltas at a surfel are
// spread over its neighbourhood -- surfels of the same surface within 2σ
// whose normals are within 60° and that lie within σ/2 of its tangent plane
// -- with Gaussian weights of width σ
// normalised to 1, so amounts are conserved and cover about the same
// number of surfels at any resolution.  Built once at setup; applied to the
// merged per-surfel deltas after every tracing pass.
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gamma/float_points.h"
#include "gamma/huge_pages.h"

namespace gammart {

struct SplatKernel {
    // Gather form: the deltas reaching surfel j come from the surfels
    // source[offset[j] .. offset[j+1]) with those weights, in ascending
    // source order (a fixed summation order: bit-identical at any thread
    // count).  Large arrays (huge_pages.h: on 2 MiB pages, a few page
    // faults, not thousands).
    std::vector<uint32_t, HugePageAllocator<uint32_t>> offset, source;
    std::vector<float, HugePageAllocator<float>> weight;
    double mean_neighbours = 0;  // average neighbourhood size (for reports and tests)
};

// `position`, `normal`: n*3 floats; `surface`: n surface numbers; `sigma`:
// the mean surfel spacing.  Runs on the calling thread's TBB arena.
SplatKernel build_splat_kernel(const float* position, const float* normal, const int32_t* surface, size_t n,
                               float sigma);

// The same surfels moved a little (riding on their triangles, SPEC §13.12):
// every neighbourhood keeps its surfels, and the weights are recomputed from
// the new positions and `sigma` exactly as build_splat_kernel computes them
// (same metric, same summation order), so a kernel whose neighbourhoods
// would not change is reproduced bit for bit.
void reweight_splat_kernel(SplatKernel& k, const float* position, size_t n, float sigma);

// After a local re-tiling replaced the surfels `replaced` (their new
// positions and normals are in place; every other surfel rode): the
// replaced surfels, the surfels whose neighbourhood held one, and every
// surfel within the kernel radius of a replaced one get their neighbourhood
// afresh (as build_splat_kernel); every other keeps its neighbourhood with
// the weights of reweight_splat_kernel (SPEC §13.12).  When `old` was built
// afresh at the kept surfels' present positions and normals with this
// sigma, the result is build_splat_kernel's bit for bit.  `old` of another
// size: built afresh.  `tree`: a kd-tree over exactly these n positions
// (the scene index's, SceneIndex::surfel_tree) for the radius searches;
// null: one is built here.
SplatKernel update_splat_kernel(const SplatKernel& old, const float* position, const float* normal,
                                const int32_t* surface, size_t n, float sigma, const std::vector<uint32_t>& replaced,
                                const FloatPointsKdTree* tree = nullptr);

// out[j*P + c] = sum over sources s of weight * in[s*P + c] (n rows of P).
void apply_splat(const SplatKernel& k, const float* in, float* out, size_t n, int P);

}  // namespace gammart
