// The update pass (SPEC §13.7): every surfel's update kernel, in place on its
// row, after tracing.  Surfels are independent, so the result does not depend
// on the thread count.
#pragma once
#include <cstdint>

#include "gamma/kernel_table.h"
#include "gamma/scene_index.h"
#include "gamma/stats.h"
#include "gamma/surfel_state.h"

namespace gammart {

// The context of surfel i as update rules see it (SPEC 12): its position and
// normal, height, iteration, uv, up, accessibility and curvature; no
// direction, no interactions, no random key (the caller sets it).
void surfel_context(const SurfelState& state, const SceneFrame& frame, size_t i, int iteration, GammaContext& ctx);

UpdateStats run_update_pass(const KernelTable& kernels, const SceneFrame& frame, SurfelState& state, int iteration,
                            uint64_t seed, int threads);

}  // namespace gammart
