// Counters returned by the runtime's passes (trace, update, renders, raw ray
// benchmark) and the sorted non-finite report they share.
#pragma once
#include <cstdint>
#include <vector>

#include "gamma_abi.h"  // GAMMA_TRACE_COUNTERS, GAMMA_MASS_BOOKS (abi.py's STATISTICS, MASS_BOOKS)

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
#define GAMMA_BOOK_FIELD(name) double name = 0;
    GAMMA_MASS_BOOKS(GAMMA_BOOK_FIELD)
#undef GAMMA_BOOK_FIELD
    void add(const MassBooks& o) {
#define GAMMA_BOOK_ADD(name) name += o.name;
        GAMMA_MASS_BOOKS(GAMMA_BOOK_ADD)
#undef GAMMA_BOOK_ADD
    }
};

// The counters (abi.py's STATISTICS): emitted, settled, escaped, missed (the
// emission ray missed the mesh; also counted in escaped), capped,
// interactions, rays, bounces, flow_steps, drips, segments, and silent
// (gamma-tons of surface sources not emitted because their weights were all 0
// this iteration: set for the whole pass by Tracer::trace / merge_end, 0 in a
// chunk's counters).
struct TraceStats {
#define GAMMA_COUNTER_FIELD(name) int64_t name = 0;
    GAMMA_TRACE_COUNTERS(GAMMA_COUNTER_FIELD)
#undef GAMMA_COUNTER_FIELD
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
