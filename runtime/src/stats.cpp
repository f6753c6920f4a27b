// Merging of counters (see gamma/stats.h).
#include "gamma/stats.h"

#include <algorithm>
#include <tuple>

namespace gammart {

void count_nonfinite(std::vector<NonFinite>& list, int event, int ton_type, int surface,
                     int statement, int64_t count) {
    auto key = [](const NonFinite& n) { return std::make_tuple(n.event, n.ton_type, n.surface, n.statement); };
    NonFinite item{event, ton_type, surface, statement, count};
    auto at = std::lower_bound(list.begin(), list.end(), item,
                               [&](const NonFinite& a, const NonFinite& b) { return key(a) < key(b); });
    if (at != list.end() && key(*at) == key(item)) at->count += count;
    else list.insert(at, item);
}

void TraceStats::add(const TraceStats& o) {
#define GAMMA_COUNTER_ADD(name) name += o.name;
    GAMMA_TRACE_COUNTERS(GAMMA_COUNTER_ADD)
#undef GAMMA_COUNTER_ADD
    for (const NonFinite& nf : o.nonfinite)
        count_nonfinite(nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
    if (mass.size() < o.mass.size()) mass.resize(o.mass.size());
    for (size_t j = 0; j < o.mass.size(); ++j) mass[j].add(o.mass[j]);
}

}  // namespace gammart
