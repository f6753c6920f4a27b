// Fixed-size TBB arenas (see gamma/threads.h).
#include "gamma/threads.h"

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <algorithm>

namespace gammart {

int resolve_threads(int threads) {
    if (threads <= 0) return std::max(1, tbb::info::default_concurrency());
    return std::min(threads, kMaxThreads);
}

void run_with_threads(int threads, const std::function<void()>& f) {
    const int n = resolve_threads(threads);
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(n));
    tbb::task_arena arena(n);
    arena.execute(f);
}

}  // namespace gammart
