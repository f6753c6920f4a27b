// ThreadBeside (threads.h): the function runs beside the caller, wait()
// rethrows what it threw, and the destructor waits for it.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>

#include "gamma/threads.h"

using namespace gammart;

TEST(ThreadBeside, RunsBesideTheCallerAndWaitRethrowsWhatItThrew) {
    std::atomic<bool> started{false}, release{false};
    ThreadBeside beside([&] {
        started = true;
        while (!release) std::this_thread::yield();   // returns only once the caller has gone on
        throw std::runtime_error("from beside");
    });
    while (!started) std::this_thread::yield();
    release = true;
    try {
        beside.wait();
        ADD_FAILURE() << "wait() did not rethrow";
    } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "from beside");
    }
    EXPECT_NO_THROW(beside.wait());   // rethrown once
}

TEST(ThreadBeside, TheDestructorWaitsForTheFunction) {
    std::atomic<int> done{0};
    {
        ThreadBeside beside([&] {
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            done = 1;
        });
    }
    EXPECT_EQ(done.load(), 1);
}
