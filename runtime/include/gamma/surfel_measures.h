// Per-surfel measures of the geometry that rules can read (SPEC §12):
// accessibility (ambient-occlusion openness), mean curvature and texture
// coordinates.  Computed once when the surfels are placed (at setup, and
// again when a shape step re-samples them), in parallel; every value depends
// only on its own surfel and the geometry, so the result is the same at any
// thread count.
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"
#include "gamma/scene_index.h"
#include "gamma/surfels.h"

namespace gammart {

// Accessibility: the fraction of kAccessibilityRays cosine-weighted rays over
// a hemisphere of the surfel (stratified kAccessibilityStrata^2,
// jittered by Philox keyed by (seed, surfel)) that meet nothing within
// kAoLengthFraction x the scene diagonal (the renders' ambient-occlusion
// length, render.h); on both sides: the normal's (front) and the other (back),
// as an open mesh can be seen from either.
constexpr int kAccessibilityStrata = 8;
constexpr int kAccessibilityRays = kAccessibilityStrata * kAccessibilityStrata;
// Philox iteration value of the accessibility stream (not an iteration number).
constexpr uint32_t kAccessibilityIteration = 0xFFFFFFFEu;
// Curvature: a quadric fitted to the surfels within this many surfel
// spacings (sqrt(area / N)) of the surfel, any surface; neighbours whose
// normal is turned more than 120 degrees away (the far side of a thin
// sheet) are left out.
constexpr float kCurvatureRadiusInSpacings = 3.0f;
constexpr float kCurvatureMinNormalDot = -0.5f;

struct SurfelMeasures {
    std::vector<float> accessibility;       // N, in [0, 1], on the normal's side
    std::vector<float> accessibility_back;  // N, on the other side
    std::vector<float> curvature;           // N, mean curvature in 1/scene units, convex seen from the normal > 0
    std::vector<float> uv;             // N*2, the mesh's texture coordinates (0 without)
};

struct MeasureRequest {
    bool accessibility = false, curvature = false, uv = false;
    bool any() const { return accessibility || curvature || uv; }
};

// The requested measures of `surf` on `mesh` (the BVH of `index` for the
// accessibility rays); the others stay empty.  `threads` <= 0: all.
SurfelMeasures measure_surfels(const MeasureRequest& want, const Mesh& mesh, const SceneIndex& index,
                               const SurfelSet& surf, float ao_length, uint64_t seed, int threads);

}  // namespace gammart
