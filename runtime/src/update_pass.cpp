// The update pass (see gamma/update_pass.h).
#include "gamma/update_pass.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <mutex>
#include <vector>

#include "gamma/threads.h"

namespace gammart {

void surfel_context(const SurfelState& state, const SceneFrame& frame, size_t i, int iteration, GammaContext& ctx) {
    for (int k = 0; k < 3; ++k) {
        ctx.position[k] = state.surf.position[3 * i + size_t(k)];
        ctx.normal[k] = state.surf.normal[3 * i + size_t(k)];
        ctx.direction[k] = 0.0f;
    }
    ctx.height = dot(V3{ctx.position[0], ctx.position[1], ctx.position[2]}, frame.up) - frame.min_up;
    ctx.iteration = iteration;
    ctx.interactions = 0;
    const SurfelMeasures& m = state.measures;
    ctx.uv[0] = m.uv.empty() ? 0.0f : m.uv[2 * i];
    ctx.uv[1] = m.uv.empty() ? 0.0f : m.uv[2 * i + 1];
    ctx.up[0] = frame.up.x; ctx.up[1] = frame.up.y; ctx.up[2] = frame.up.z;
    ctx.accessibility = m.accessibility.empty() ? 0.0f : m.accessibility[i];
    ctx.curvature = m.curvature.empty() ? 0.0f : m.curvature[i];
}

UpdateStats run_update_pass(const KernelTable& K, const SceneFrame& frame, SurfelState& state, int iteration,
                            uint64_t seed, int threads) {
    const auto t0 = std::chrono::steady_clock::now();
    UpdateStats result;
    if (!K.any_update()) {
        result.seconds = seconds_since(t0);
        return result;
    }
    const int W = state.width;
    float* rows = state.rows.data();
    const size_t n = state.size();
    const uint64_t iteration_key = mix64(mix64(seed ^ 0xA5A5A5A5A5A5A5A5ULL) ^ uint64_t(uint32_t(iteration)));
    std::mutex nonfinite_lock;
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<NonFinite> local;
            GammaContext ctx;
            for (size_t i = r.begin(); i < r.end(); ++i) {
                GammaUpdateKernel fn = K.update[size_t(state.surface[i])];
                if (!fn) continue;
                surfel_context(state, frame, i, iteration, ctx);
                set_random_key(ctx, mix64(iteration_key ^ uint64_t(i)));
                if (int32_t bad = fn(rows + i * size_t(W), &ctx))
                    count_nonfinite(local, -1, 0, state.surface[i], bad);
            }
            if (!local.empty()) {  // integer counts: the order of merging does not matter
                std::lock_guard<std::mutex> hold(nonfinite_lock);
                for (const NonFinite& nf : local)
                    count_nonfinite(result.nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
            }
        });
    });
    result.seconds = seconds_since(t0);
    return result;
}

}  // namespace gammart
