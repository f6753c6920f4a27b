// Fixed-size TBB arenas (see gamma/threads.h).
#include "gamma/threads.h"

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <utility>

namespace gammart {

int resolve_threads(int threads) {
    if (threads <= 0) return std::max(1, tbb::info::default_concurrency());
    return std::min(threads, kMaxThreads);
}

namespace {
// The thread count of the arena whose run_with_threads body this thread is
// running (0: none).
thread_local int entered_arena_threads = 0;
}  // namespace

ThreadBeside::ThreadBeside(const std::function<void()>& f)
    : thread_([this, f] {
          try {
              f();
          } catch (...) {
              error_ = std::current_exception();
          }
      }) {}

ThreadBeside::~ThreadBeside() {
    if (thread_.joinable()) thread_.join();
}

void ThreadBeside::wait() {
    if (thread_.joinable()) thread_.join();
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
}

void run_with_threads(int threads, const std::function<void()>& f) {
    const int n = resolve_threads(threads);
    // Called again from inside that body with the same count (a pass whose
    // steps each run_with_threads): the steps share the one arena instead of
    // each making its own and waiting for the workers to join it.  Isolated,
    // as an arena of its own was: a thread waiting inside f never takes an
    // outer task (which might, say, lock a mutex this thread holds).
    if (entered_arena_threads == n) {
        tbb::this_task_arena::isolate([&] { f(); });
        return;
    }
    tbb::global_control gc(tbb::global_control::max_allowed_parallelism, size_t(n));
    tbb::task_arena arena(n);
    arena.execute([&] {
        struct Restore {
            int outer;
            ~Restore() { entered_arena_threads = outer; }
        } restore{entered_arena_threads};
        entered_arena_threads = n;
        f();
    });
}

}  // namespace gammart
