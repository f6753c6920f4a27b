// Cooperative cancellation.  A caller hands a CancelToken to a long pass
// (the set-up and its surfel sampling, a trace, an update, a shape step, a
// render, a bake); the pass checks it between chunks of its work (a chunk of
// gamma-tons, a row of pixels, a block of points: well under 0.5 s each) and
// leaves with Cancelled once someone called cancel(), from any thread (the
// Python driver's signal watcher, the viewer dropping a stale run).  A token
// belongs to one run: nothing resets it, so no request can be taken by a
// later pass or lost before an earlier one.
#pragma once
#include <atomic>
#include <stdexcept>
#include <string>

namespace gammart {

// Thrown by a pass whose token was cancelled; what() starts "cancelled: ".
// Not an Error: bad input and a request to stop are told apart by type.
struct Cancelled : std::runtime_error {
    using std::runtime_error::runtime_error;
};

class CancelToken {
public:
    void cancel() noexcept { flag_.store(true, std::memory_order_relaxed); }
    bool cancelled() const noexcept { return flag_.load(std::memory_order_relaxed); }
    // Throws Cancelled ("cancelled: `pass` was stopped before its end") once cancelled.
    void check(const char* pass) const {
        if (cancelled()) throw Cancelled(std::string("cancelled: ") + pass + " was stopped before its end");
    }
    // The token of callers that never cancel (tests, Ray's workers).
    static const CancelToken& never() {
        static const CancelToken token;
        return token;
    }

private:
    std::atomic<bool> flag_{false};
};

}  // namespace gammart
