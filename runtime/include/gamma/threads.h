// Thread control shared by every parallel part of the runtime: a fixed thread
// count per call (never TBB's default), the chunk size of gamma-ton work, and
// a wall-clock helper for the per-phase timings.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>

namespace gammart {

// Number of gamma-tons per parallel work item.  Never depends on thread count.
constexpr int64_t kChunkSize = 1024;
// Largest accepted thread count.
constexpr int kMaxThreads = 1024;

// Runs f inside a task arena of exactly `threads` threads (<= 0: all hardware
// threads); a global_control lifts TBB's default cap at the core count.
void run_with_threads(int threads, const std::function<void()>& f);
int resolve_threads(int threads);

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace gammart
