// Counters returned by the runtime's passes (trace, update, renders, raw ray
// benchmark) and the sorted non-finite report they share.
#pragma once
#include <cstdint>
#include <vector>

namespace gammart {

// How often a kernel's statement produced NaN or infinity (the store was
// skipped).  event is GAMMA_EVENT_* for transport kernels, -1 for update.
struct NonFinite {
    int event = 0, ton_type = 0, surface = 0, statement = 0;
    int64_t count = 0;
};

// Adds one occurrence, keeping the list sorted (so merges are order-free).
void count_nonfinite(std::vector<NonFinite>& list, int event, int ton_type, int surface,
                     int statement, int64_t count = 1);

struct TraceStats {
    int64_t emitted = 0, settled = 0, escaped = 0, capped = 0;
    int64_t interactions = 0, rays = 0;
    int64_t missed = 0;  // emission ray missed the mesh (also counted in escaped)
    int64_t flow_steps = 0, bounces = 0, drips = 0, segments = 0;
    std::vector<NonFinite> nonfinite;
    double trace_seconds = 0;

    // Adds another chunk's counters (integers: the order of adding is free).
    void add(const TraceStats& o);
};

struct UpdateStats {
    std::vector<NonFinite> nonfinite;
    double seconds = 0;
};

// Counters of one render_appearance call.  nonfinite: event kAppearanceEvent,
// ton_type 0, surface, statement, count (per camera sample that hit).
struct RenderStats {
    int64_t rays = 0, kernel_calls = 0;
    std::vector<NonFinite> nonfinite;
    double seconds = 0;
};

struct RaycastStats {
    int64_t rays = 0, hits = 0;
    double seconds = 0;
};

}  // namespace gammart
