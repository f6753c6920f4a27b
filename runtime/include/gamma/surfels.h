#pragma once
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"

namespace gammart {

struct SurfelSet {
    std::vector<float> position;   // N*3
    std::vector<float> normal;     // N*3
    std::vector<int32_t> triangle; // N
    double r_max = 0;              // Yuksel's r_max for N samples on the mesh area
};

// Yuksel 2015 weighted sample elimination: 5N candidates uniform by area,
// eliminated down to exactly N.  Deterministic in `seed`.  Output is sorted
// along a Morton curve for memory locality.
SurfelSet sample_surfels(const Mesh& mesh, size_t n, uint64_t seed);

// Core of the elimination on an arbitrary 3D point set (exposed for tests).
// Returns the indices of the kept points (ascending order not guaranteed).
std::vector<uint32_t> eliminate_samples(const std::vector<float>& pts, size_t keep, double r_max);

}  // namespace gammart
