#pragma once
#include <cstdint>
#include <vector>

#include "gamma/cancel.h"
#include "gamma/mesh.h"

namespace gammart {

struct SurfelSet {
    std::vector<float> position;   // N*3
    std::vector<float> normal;     // N*3
    std::vector<int32_t> triangle; // N
    double r_max = 0;              // Yuksel's r_max for N samples on the mesh area
};

// Exactly N surfels, evenly spaced over the mesh's area: 5N candidates
// uniform by area (surfel_candidates), then two greedy Poisson-disk passes
// over them in one random order, the first at 1.40 r_max, the second
// filling the gaps at 1.28 r_max until N are kept (surfels.cpp).
// Deterministic in `seed`, the same at any thread count.  Output is sorted
// along a Morton curve for memory locality.  `cancel` is checked between
// the candidates, the disk passes and the ordering (Cancelled).
SurfelSet sample_surfels(const Mesh& mesh, size_t n, uint64_t seed,
                         const CancelToken& cancel = CancelToken::never());

// The candidates sample_surfels chooses from (exposed for tests): 5n points
// uniform by area, the triangle of each, and the mesh's area.
struct SurfelCandidates {
    std::vector<float> position;    // 5n*3
    std::vector<int32_t> triangle;  // 5n
    double area = 0;
};
SurfelCandidates surfel_candidates(const Mesh& mesh, size_t n, uint64_t seed);

// The two greedy Poisson-disk passes of sample_surfels on an arbitrary 3D
// point set (exposed for tests): the indices of exactly `keep` points (in no
// particular order), or nothing if the passes fall short.  The neighbour
// lists are stored in `list_capacity` entries reserved per point, packed
// again when they need more; their filter takes its AVX-512 form where the
// CPU has it unless `allow_avx512` is false (the same answer either way).
constexpr size_t kDiskListCapacity = 12;
std::vector<uint32_t> poisson_disk_sample(const std::vector<float>& pts, size_t keep, double r_max, uint64_t seed,
                                          size_t list_capacity = kDiskListCapacity, bool allow_avx512 = true);

// Yuksel 2015 weighted sample elimination (tiled, see surfels.cpp) on an
// arbitrary 3D point set: what sample_surfels falls back on when the disk
// passes cannot keep N (exposed for tests).
// Returns the indices of the kept points (ascending order not guaranteed).
std::vector<uint32_t> eliminate_samples(const std::vector<float>& pts, size_t keep, double r_max);

}  // namespace gammart
