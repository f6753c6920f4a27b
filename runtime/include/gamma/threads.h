// Thread control shared by every parallel part of the runtime: a fixed thread
// count per call (never TBB's default), the chunk size of gamma-ton work, and
// a wall-clock helper for the per-phase timings.
#pragma once
#include <chrono>
#include <cstdint>
#include <exception>
#include <functional>
#include <thread>

namespace gammart {

// Number of gamma-tons per parallel work item.  Never depends on thread count.
constexpr int64_t kChunkSize = 1024;
// Largest accepted thread count.
constexpr int kMaxThreads = 1024;

// Runs f inside a task arena of exactly `threads` threads (<= 0: all hardware
// threads); a global_control lifts TBB's default cap at the core count.
void run_with_threads(int threads, const std::function<void()>& f);
int resolve_threads(int threads);

// Runs f on a thread of its own, outside every TBB arena, beside what the
// caller does next: TBB work that f starts finds the threads it would find
// called from the caller's thread before any arena (the Embree BVH build,
// whose threads the configured count never sets).  wait() joins it and
// rethrows what f threw; the destructor joins too, so an exception on the
// caller's side never leaves f running on what it references.
class ThreadBeside {
public:
    explicit ThreadBeside(const std::function<void()>& f);
    ~ThreadBeside();
    ThreadBeside(const ThreadBeside&) = delete;
    ThreadBeside& operator=(const ThreadBeside&) = delete;
    void wait();

private:
    std::exception_ptr error_;
    std::thread thread_;
};

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace gammart
