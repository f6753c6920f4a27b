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

// The books of one conserved property in one iteration (double sums, formed
// in chunk order: the same at any thread count).  removed / deposited: what
// transport rules took from / left on surfaces; emitted: what gamma-tons
// carried when emitted; created: what rules made (> 0) or destroyed (< 0),
// i.e. the change of surface + carry in one kernel call; escaped: what
// gamma-tons carried when they escaped or were capped; dropped: what they
// still carried when they settled; in_flight: carried at the iteration's end
// (every gamma-ton ends within its iteration, so 0 in this version).
// removed + emitted + created = deposited + escaped + dropped + in_flight.
struct MassBooks {
    double removed = 0, deposited = 0, emitted = 0, created = 0, escaped = 0, dropped = 0, in_flight = 0;
    void add(const MassBooks& o) {
        removed += o.removed;
        deposited += o.deposited;
        emitted += o.emitted;
        created += o.created;
        escaped += o.escaped;
        dropped += o.dropped;
        in_flight += o.in_flight;
    }
};

struct TraceStats {
    int64_t emitted = 0, settled = 0, escaped = 0, capped = 0;
    int64_t interactions = 0, rays = 0;
    int64_t missed = 0;  // emission ray missed the mesh (also counted in escaped)
    int64_t flow_steps = 0, bounces = 0, drips = 0, segments = 0;
    // gamma-tons of surface sources not emitted: their weights were all 0 this iteration
    // (set for the whole pass by Tracer::trace / merge_end; 0 in a chunk's counters)
    int64_t silent = 0;
    std::vector<NonFinite> nonfinite;
    std::vector<MassBooks> mass;  // per Config::mass_properties entry
    double trace_seconds = 0;
    // Most deposit records held at once during the pass (one batch of chunks'
    // logs, tracer.h); set by Tracer::trace, not by add().
    int64_t log_records_peak = 0;

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
