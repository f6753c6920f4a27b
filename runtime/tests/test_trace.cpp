#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <atomic>
#include <chrono>
#include <mutex>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "gamma/error.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;

namespace {

// Hand-written transport kernels (stand-ins for JIT'd ones).
extern "C" int32_t k_hit(float* ton, const float* surf, float* delta, const GammaContext* ctx) {
    delta[3] = ton[0] * 0.1f + surf[4] * 0.01f;
    delta[4] = ctx->position[0] * 1e-3f + float(ctx->interactions) * 1e-4f;
    ton[0] = ton[0] * 0.9f + surf[3] * 0.05f;
    return 0;
}
extern "C" int32_t k_settle(float* ton, const float*, float* delta, const GammaContext* ctx) {
    delta[3] += ton[0] * 0.33f;
    delta[4] += ctx->normal[1] * 1e-3f;
    return 0;
}
extern "C" int32_t k_update(float* surf, const GammaContext* ctx) {
    surf[4] = surf[4] * 0.5f + surf[3] * 0.25f + ctx->position[2] * 1e-3f;
    return 0;
}

uint64_t addr(void* f) { return uint64_t(reinterpret_cast<uintptr_t>(f)); }

Config base_config(int W, float ds) {
    Config c;
    c.surfels = 2000;
    c.seed = 5;
    c.threads = 1;
    c.row_width = W;
    std::vector<float> row(size_t(W), 0.0f);
    row[GAMMA_ROW_REFLECTANCE_STRAIGHT] = ds;
    c.surface_rows = {row};
    return c;
}

}  // namespace

TEST(Trace, PatinaMeanInteractions) {
    Mesh m = gamma_test::icosphere(4);
    Config c = base_config(3, 0.5f);
    c.threads = 2;
    int t = c.add_ton_type(1, 0, 0, {});
    c.add_source("point", t, 100000, {0, 0, 0});
    Simulation sim(m, c);
    TraceStats st = sim.trace(1);
    EXPECT_EQ(st.emitted, 100000);
    EXPECT_EQ(st.escaped, 0);
    EXPECT_EQ(st.capped, 0);
    EXPECT_EQ(st.settled, 100000);
    EXPECT_EQ(st.rays, st.interactions);
    const double mean = double(st.interactions) / double(st.emitted);
    EXPECT_NEAR(mean, 2.5, 0.02);
}

// A cancelled token stops the set-up and each pass before it changes
// anything (gamma/cancel.h): Cancelled, not Error, and the rows as they were;
// a token cancelled from another thread stops a long trace within its chunks.
TEST(Trace, ACancelledTokenStopsThePassesAndLeavesTheRows) {
    Mesh m = gamma_test::icosphere(4);
    Config c = base_config(5, 0.3f);
    c.threads = 2;
    const int t = c.add_ton_type(1, 0, 0, {});
    c.set_transport(GAMMA_EVENT_HIT, t, 0, addr(reinterpret_cast<void*>(&k_hit)), true);
    c.set_update(0, addr(reinterpret_cast<void*>(&k_update)));
    c.add_source("point", t, 2'000'000, {0, 0, 0});
    CancelToken stopped;
    stopped.cancel();
    EXPECT_THROW(Simulation(m, c, nullptr, nullptr, stopped), Cancelled);
    Simulation sim(m, c);
    const std::vector<float> before = sim.rows();
    EXPECT_THROW(sim.trace(1, stopped), Cancelled);
    EXPECT_THROW(sim.update(1, stopped), Cancelled);
    EXPECT_THROW(sim.shape(1, stopped), Cancelled);
    EXPECT_EQ(sim.rows(), before);
    try {
        sim.trace(1, stopped);
    } catch (const Cancelled& e) {
        EXPECT_EQ(std::string(e.what()), "cancelled: the trace was stopped before its end");
    }

    CancelToken later;
    const auto t0 = std::chrono::steady_clock::now();
    std::thread canceller([&] {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        later.cancel();
    });
    EXPECT_THROW(
        {
            for (int it = 1; it < 1000; ++it) sim.trace(it, later);
        },
        Cancelled);
    canceller.join();
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 30.0);
    sim.trace(1);   // the token stopped its own passes only
}

// The batched tracer (groups of gamma-tons cast, looked up and moved ahead
// of their rules) against the plain one (each gamma-ton to its end before
// the next): the same chunk logs, record for record, and the same counters,
// with every motion, rules on hit and settle, and a step budget small enough
// that paths go on past the group's rounds.
TEST(Trace, BatchedChunksEqualTheOneAtATimeTracer) {
    Mesh m = gamma_test::icosphere(3);
    for (int64_t budget : {int64_t(0), int64_t(7)}) {
        for (int threads : {1, 2}) {
            Config c = base_config(5, 0.2f);
            c.threads = threads;
            c.trace_step_budget = budget;
            const int t = c.add_ton_type(0.4f, 0.3f, 0.2f, {1.0f}, 0.3f, 0.2f);
            c.set_transport(GAMMA_EVENT_HIT, t, 0, addr(reinterpret_cast<void*>(&k_hit)), true);
            c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_settle)), true);
            c.add_source("point", t, 9000, {0, 0, 0});
            Simulation sim(m, c);
            const int64_t n = sim.num_chunks(1);
            const std::vector<ChunkLog> batched = sim.trace_chunks(1, 0, n);
            const std::vector<ChunkLog> plain = sim.trace_chunks(1, 0, n, /*one_at_a_time=*/true);
            ASSERT_EQ(batched.size(), plain.size());
            int64_t interactions = 0;
            for (size_t k = 0; k < batched.size(); ++k) {
                EXPECT_EQ(batched[k].surfel, plain[k].surfel) << "chunk " << k;
                EXPECT_EQ(batched[k].delta, plain[k].delta) << "chunk " << k;
#define GAMMA_EXPECT_SAME_COUNTER(name) EXPECT_EQ(batched[k].st.name, plain[k].st.name) << #name;
                GAMMA_TRACE_COUNTERS(GAMMA_EXPECT_SAME_COUNTER)
#undef GAMMA_EXPECT_SAME_COUNTER
                interactions += batched[k].st.interactions;
            }
            EXPECT_GT(interactions, 9000 * 2) << "budget " << budget << ", " << threads << " thread(s)";
        }
    }
}

TEST(Trace, CappedAtMaxInteractions) {
    Mesh m = gamma_test::icosphere(3);
    Config c = base_config(3, 0.0f);
    c.max_interactions = 25;
    int t = c.add_ton_type(1, 0, 0, {});
    c.add_source("point", t, 5000, {0.1f, 0.2f, -0.1f});
    Simulation sim(m, c);
    TraceStats st = sim.trace(1);
    EXPECT_EQ(st.capped, 5000);
    EXPECT_EQ(st.escaped, 0);
    EXPECT_EQ(st.settled, 0);
    EXPECT_EQ(st.interactions, 25 * 5000);
    EXPECT_EQ(st.rays, 25 * 5000);
}

TEST(Trace, EnvironmentSourcesOutsideSphere) {
    Mesh m = gamma_test::icosphere(3);
    Config c = base_config(3, 1.0f);
    int t = c.add_ton_type(0, 0, 0, {});
    c.add_source("sphere", t, 20000);
    c.add_source("hemisphere", t, 20000);
    Simulation sim(m, c);
    TraceStats st = sim.trace(1);
    EXPECT_EQ(st.emitted, 40000);
    EXPECT_EQ(st.settled + st.escaped, 40000);
    // Cosine-weighted inward from R = 1.05 * half diagonal (= 1.05*sqrt(3)):
    // fraction hitting the unit sphere = (1/R)^2.
    const double R = 1.05 * std::sqrt(3.0);
    EXPECT_NEAR(double(st.settled) / 40000.0, 1.0 / (R * R), 0.015);
}

// pieces > 0: each iteration traced as ranges of `pieces` chunks (as Ray
// workers do) and merged in chunk order: all at once, or (batched) each
// range added as it is traced (merge_begin / merge_add / merge_end), its
// largest batch's records in *peak.
static std::vector<float> run_threads(int threads, int pieces = 0, bool batched = false, int64_t* peak = nullptr) {
    Mesh m = gamma_test::icosphere(3);
    const int W = 5;
    Config c = base_config(W, 0.3f);
    c.surfels = 3000;
    c.threads = threads;
    std::vector<float> row2 = {0.2f, 0, 0, 0.5f, 0.25f};
    c.surface_rows.push_back(row2);
    c.surface_rows[0][3] = 1.0f;
    c.triangle_surface.resize(m.num_triangles());
    for (size_t i = 0; i < m.num_triangles(); ++i) c.triangle_surface[i] = int32_t(i % 2);
    int t0 = c.add_ton_type(1, 0, 0, {1.0f});
    int t1 = c.add_ton_type(0.7f, 0, 0, {0.5f});
    c.add_source("point", t0, 30000, {0.1f, 0, 0});
    c.add_source("point", t1, 20000, {-0.2f, 0.1f, 0});
    for (int ty : {t0, t1})
        for (int s : {0, 1}) {
            c.set_transport(GAMMA_EVENT_HIT, ty, s, addr(reinterpret_cast<void*>(&k_hit)), true);
            c.set_transport(GAMMA_EVENT_SETTLE, ty, s, addr(reinterpret_cast<void*>(&k_settle)), true);
        }
    c.set_update(0, addr(reinterpret_cast<void*>(&k_update)));
    Simulation sim(m, c);
    for (int it = 0; it < 3; ++it) {
        if (pieces == 0) {
            const TraceStats st = sim.trace(it + 1);
            if (peak) *peak = std::max(*peak, st.log_records_peak);
        } else if (batched) {
            const int64_t n = sim.num_chunks(it + 1);
            sim.merge_begin(it + 1);
            for (int64_t a = 0; a < n; a += pieces) sim.merge_add(sim.trace_chunks(it + 1, a, std::min<int64_t>(n, a + pieces)));
            const TraceStats st = sim.merge_end();
            EXPECT_EQ(st.emitted, 50000);
            if (peak) *peak = std::max(*peak, st.log_records_peak);
        } else {
            const int64_t n = sim.num_chunks(it + 1);
            std::vector<ChunkLog> logs;
            for (int64_t a = 0; a < n; a += pieces) {
                std::vector<ChunkLog> part = sim.trace_chunks(it + 1, a, std::min<int64_t>(n, a + pieces));
                for (ChunkLog& log : part) logs.push_back(std::move(log));
            }
            const TraceStats st = sim.merge_chunks(it + 1, logs);
            EXPECT_EQ(st.emitted, 50000);
        }
        sim.update(it + 1);
    }
    return sim.rows();
}

TEST(Trace, ChunksTracedInPiecesAndMergedInOrderEqualTrace) {
    std::vector<float> whole = run_threads(2), pieces = run_threads(1, 7), singles = run_threads(2, 1);
    ASSERT_EQ(whole.size(), pieces.size());
    EXPECT_EQ(0, std::memcmp(whole.data(), pieces.data(), whole.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(whole.data(), singles.data(), whole.size() * sizeof(float)));
}

// A driver that merges each batch of chunks as it arrives holds one batch's
// logs at a time and gets trace()'s rows bit for bit, whatever the batches.
TEST(Trace, MergeInBatchesEqualsTraceAndHoldsOneBatch) {
    int64_t whole_peak = 0, one_peak = 0, five_peak = 0;
    std::vector<float> whole = run_threads(2, 0, false, &whole_peak), ones = run_threads(1, 1, true, &one_peak),
                       fives = run_threads(2, 5, true, &five_peak), all = run_threads(1, 1000, true);
    ASSERT_EQ(whole.size(), ones.size());
    EXPECT_EQ(0, std::memcmp(whole.data(), ones.data(), whole.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(whole.data(), fives.data(), whole.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(whole.data(), all.data(), whole.size() * sizeof(float)));
    // 50,000 gamma-tons in 49 chunks, traced in one batch (the default is 64
    // chunks): batches of one chunk hold about 1/49 of the records, of five 5/49.
    EXPECT_GT(one_peak, 0);
    EXPECT_LE(one_peak, 3 * whole_peak / 49);
    EXPECT_LE(five_peak, 3 * 5 * whole_peak / 49);
    EXPECT_GT(five_peak, one_peak);
}

TEST(Trace, MergeInBatchesRefusesBatchesThatDoNotFit) {
    Mesh m = gamma_test::icosphere(2);
    Config c = base_config(5, 0.3f);
    int t = c.add_ton_type(1, 0, 0, {1.0f});
    c.add_source("point", t, 3000, {0, 0, 0});
    c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_settle)), true);
    Simulation sim(m, c);
    const std::vector<float> before = sim.rows();
    std::vector<ChunkLog> logs = sim.trace_chunks(1, 0, 3);
    std::vector<ChunkLog> first(logs.begin(), logs.begin() + 2), last(logs.begin() + 2, logs.end());
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_add(first); }).find("no merge begun"), std::string::npos);
    sim.merge_begin(1);
    sim.merge_add(first);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_end(); }).find("has 3 chunks, not 2"), std::string::npos);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_end(); }).find("abandoned"), std::string::npos);
    sim.merge_begin(1);
    sim.merge_add(first);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_add(first); }).find("has 3 chunks, not 4 or more"),
              std::string::npos);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_add(last); }).find("abandoned"), std::string::npos);
    sim.merge_begin(1);
    std::vector<ChunkLog> bad = last;
    bad[0].surfel.push_back(uint32_t(sim.num_surfels()));
    bad[0].delta.resize(bad[0].delta.size() + 2);
    sim.merge_add(first);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_add(bad); }).find("out of range"), std::string::npos);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_end(); }).find("abandoned"), std::string::npos);
    EXPECT_EQ(sim.rows(), before);  // nothing reached the rows
    sim.merge_begin(1);
    sim.merge_add(first);
    sim.merge_add(last);
    EXPECT_EQ(sim.merge_end().emitted, 3000);
    EXPECT_NE(sim.rows(), before);
}

TEST(Trace, MergeRefusesLogsThatDoNotFit) {
    Mesh m = gamma_test::icosphere(2);
    Config c = base_config(5, 0.3f);
    int t = c.add_ton_type(1, 0, 0, {1.0f});
    c.add_source("point", t, 3000, {0, 0, 0});
    c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_settle)), true);
    Simulation sim(m, c);
    ASSERT_EQ(sim.num_chunks(1), 3);
    EXPECT_NE(gamma_test::expect_error([&] { sim.trace_chunks(1, 2, 4); }).find("not within the 3 chunks"), std::string::npos);
    std::vector<ChunkLog> logs = sim.trace_chunks(1, 0, 3);
    std::vector<ChunkLog> two(logs.begin(), logs.begin() + 2);
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_chunks(1, two); }).find("has 3 chunks, not 2"), std::string::npos);
    logs[0].surfel.push_back(uint32_t(sim.num_surfels()));
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_chunks(1, logs); }).find("do not match"), std::string::npos);
    logs[0].surfel.pop_back();
    logs[1].st.mass.push_back(MassBooks{});  // books of a property this config does not account
    EXPECT_NE(gamma_test::expect_error([&] { sim.merge_chunks(1, logs); }).find("mass books for 1 properties, not 0"),
              std::string::npos);
    logs[1].st.mass.clear();
    EXPECT_EQ(sim.merge_chunks(1, logs).emitted, 3000);
}

TEST(Trace, BitIdenticalAcrossThreadCounts) {
    std::vector<float> a = run_threads(1), b = run_threads(2), c4 = run_threads(4);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(a.data(), c4.data(), a.size() * sizeof(float)));
    // The kernels actually changed something.
    double s = 0;
    for (size_t i = 0; i < a.size(); i += 5) s += a[i + 3];
    EXPECT_GT(s, 3000.0 * 0.5);
}

TEST(Trace, NearestSurfelIsNearest) {
    Mesh m = gamma_test::icosphere(3);
    Config c = base_config(3, 0.0f);
    Simulation sim(m, c);
    const auto& P = sim.surfels().position;
    for (int q = 0; q < 50; ++q) {
        float p[3] = {std::sin(q * 1.3f), std::cos(q * 0.7f), std::sin(q * 0.31f)};
        uint32_t got = sim.nearest_surfel(p);
        float best = 1e30f;
        for (size_t i = 0; i < sim.num_surfels(); ++i) {
            float d = 0;
            for (int k = 0; k < 3; ++k) d += (P[3 * i + k] - p[k]) * (P[3 * i + k] - p[k]);
            best = std::min(best, d);
        }
        float dg = 0;
        for (int k = 0; k < 3; ++k) dg += (P[3 * got + k] - p[k]) * (P[3 * got + k] - p[k]);
        EXPECT_EQ(dg, best);
    }
}

TEST(Config, Errors) {
    Mesh m = gamma_test::icosphere(1);
    auto expect_fail = [&](Config c, const char* needle) {
        try {
            Simulation sim(m, c);
            ADD_FAILURE() << "no error for " << needle;
        } catch (const Error& e) {
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    Config c = base_config(3, 0);
    c.surfels = 100;
    int t = c.add_ton_type(1, 0, 0, {});
    Config bad = c;
    bad.add_source("laser", t, 10, {0, 0, 0});
    expect_fail(bad, "unknown source kind");
    bad = c;
    bad.add_source("point", 3, 10, {0, 0, 0});
    expect_fail(bad, "ton type index");
    bad = c;
    bad.row_width = 2;
    expect_fail(bad, "row_width");
    bad = c;
    bad.set_transport(GAMMA_EVENT_HIT, 0, 4, 0, false);
    expect_fail(bad, "surface index");
}

TEST(Render, BackgroundIsNaN) {
    Mesh m = gamma_test::icosphere(3);
    Config c = base_config(3, 0);
    Simulation sim(m, c);
    std::vector<float> values(sim.num_surfels(), 2.0f);
    const int W = 32, H = 24;
    std::vector<float> val(W * H), shade(W * H);
    sim.render(values.data(), {0, 0, 4}, {0, 0, 0}, {0, 1, 0}, 40.0f, W, H, 2, val.data(), shade.data());
    EXPECT_TRUE(std::isnan(val[0]));
    const float centre = val[(H / 2) * W + W / 2];
    EXPECT_NEAR(centre, 2.0f, 1e-5);
    EXPECT_GE(shade[(H / 2) * W + W / 2], 0.25f);
    EXPECT_LE(shade[(H / 2) * W + W / 2], 1.0f);
}

// threads = n runs n threads even above the core count (no clamping). Each
// task spins until all n have arrived, so n distinct threads must take one
// each. The wait is long because on a loaded 2-core machine a sleeping TBB
// worker was once seen to take over 5 s to be scheduled; a wrong thread
// count still fails, only later.
TEST(Threads, ExactlyRequested) {
    for (int n : {1, 2, 4}) {
        std::atomic<int> arrived{0};
        std::mutex mu;
        std::set<std::thread::id> ids;
        gammart::run_with_threads(n, [&] {
            tbb::parallel_for(0, n, 1, [&](int) {
                {
                    std::lock_guard<std::mutex> lk(mu);
                    ids.insert(std::this_thread::get_id());
                }
                arrived++;
                const auto t0 = std::chrono::steady_clock::now();
                while (arrived.load() < n && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(60))
                    std::this_thread::yield();
            });
        });
        EXPECT_EQ(int(ids.size()), n);
        EXPECT_EQ(arrived.load(), n);
    }
}

// A run_with_threads inside another's body with the same count runs there
// (one arena, no second one to join), isolated: a thread waiting inside it
// never runs an outer task; another count gets an arena of its own; the
// marker of the entered arena is restored after an exception.
TEST(Threads, NestedCallsShareTheArenaIsolated) {
    gammart::run_with_threads(2, [&] {
        EXPECT_EQ(tbb::this_task_arena::max_concurrency(), 2);
        gammart::run_with_threads(2, [&] { EXPECT_EQ(tbb::this_task_arena::max_concurrency(), 2); });
        gammart::run_with_threads(1, [&] { EXPECT_EQ(tbb::this_task_arena::max_concurrency(), 1); });
        // outer tasks that each wait inside a nested call: with isolation no
        // thread takes a second outer task while it waits, so none finds its
        // own thread already inside an outer task
        thread_local int inside_outer = 0;
        std::atomic<int> nested_outer{0};
        tbb::parallel_for(0, 64, 1, [&](int) {
            ++inside_outer;
            if (inside_outer > 1) ++nested_outer;
            gammart::run_with_threads(2, [&] { tbb::parallel_for(0, 256, 1, [](int) { std::this_thread::yield(); }); });
            --inside_outer;
        });
        EXPECT_EQ(nested_outer.load(), 0);
    });
    EXPECT_THROW(gammart::run_with_threads(2, [] { gammart::run_with_threads(2, [] { throw std::runtime_error("x"); }); }),
                 std::runtime_error);
    // after the exception this thread is in no arena: a nested call with the same count makes its own
    gammart::run_with_threads(2, [&] { EXPECT_EQ(tbb::this_task_arena::max_concurrency(), 2); });
}

namespace {
extern "C" int32_t k_always_bad(float*, const float*, float*, const GammaContext*) { return 2; }
extern "C" int32_t k_update_bad(float*, const GammaContext* ctx) { return ctx->random_key[0] & 1 ? 1 : 0; }
}

// A kernel's non-finite report (its return value) is counted per statement,
// identically at any thread count; update kernels get distinct random keys.
TEST(Trace, NonFiniteStatementsAreCounted) {
    Mesh m = gamma_test::icosphere(2);
    std::vector<std::pair<int64_t, int64_t>> seen;
    for (int threads : {1, 2}) {
        Config c = base_config(3, 0.5f);
        c.threads = threads;
        const int t = c.add_ton_type(1, 0, 0, {1.0f});
        c.add_source("point", t, 3000, {0, 0, 0});
        c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_always_bad)), false);
        c.set_update(0, addr(reinterpret_cast<void*>(&k_update_bad)));
        Simulation sim(m, c);
        const TraceStats st = sim.trace(1);
        ASSERT_EQ(st.nonfinite.size(), 1u);
        EXPECT_EQ(st.nonfinite[0].event, GAMMA_EVENT_SETTLE);
        EXPECT_EQ(st.nonfinite[0].statement, 2);
        EXPECT_EQ(st.nonfinite[0].count, st.settled);
        const UpdateStats up = sim.update(1);
        ASSERT_EQ(up.nonfinite.size(), 1u);
        EXPECT_EQ(up.nonfinite[0].event, -1);
        // about half the surfels have an odd key
        EXPECT_GT(up.nonfinite[0].count, int64_t(sim.num_surfels() / 3));
        EXPECT_LT(up.nonfinite[0].count, int64_t(2 * sim.num_surfels() / 3));
        seen.push_back({st.nonfinite[0].count, up.nonfinite[0].count});
    }
    EXPECT_EQ(seen[0], seen[1]);
}

// A pass traced in batches of chunks (Config::trace_batch_chunks) holds the
// deposit logs of one batch at a time, and gives the rows and statistics of
// the pass in one go, bit for bit, at any thread count.
TEST(Trace, BatchesBoundTheLogsAndNeverChangeResults) {
    auto run = [](int threads, int64_t batch, int64_t& peak) {
        Mesh m = gamma_test::icosphere(3);
        Config c = base_config(5, 0.3f);
        c.surfels = 3000;
        c.threads = threads;
        c.trace_batch_chunks = batch;
        c.surface_rows[0][3] = 1.0f;
        int t = c.add_ton_type(1, 0, 0, {1.0f});
        c.add_source("point", t, 40 * int64_t(kChunkSize) + 17, {0.1f, 0, 0});   // 41 chunks
        c.set_transport(GAMMA_EVENT_HIT, t, 0, addr(reinterpret_cast<void*>(&k_hit)), true);
        c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_settle)), true);
        Simulation sim(m, c);
        TraceStats st = sim.trace(1);
        peak = st.log_records_peak;
        std::vector<double> counts = {double(st.emitted), double(st.settled), double(st.interactions)};
        std::vector<float> rows = sim.rows();
        rows.insert(rows.end(), counts.begin(), counts.end());
        return rows;
    };
    int64_t whole = 0, one = 0, three = 0, three2 = 0;
    const std::vector<float> a = run(1, 1000, whole), b = run(1, 1, one), c3 = run(1, 3, three),
                             d = run(2, 3, three2);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(a.data(), c3.data(), a.size() * sizeof(float)));
    EXPECT_EQ(0, std::memcmp(a.data(), d.data(), a.size() * sizeof(float)));
    // Every gamma-ton hits (a point source inside a closed sphere) and writes
    // at least twice: the whole pass holds all its records, a batch of one
    // chunk about 1/41 of them.
    EXPECT_GE(whole, 2 * (40 * kChunkSize + 17));
    EXPECT_LE(one, 3 * whole / 41);
    EXPECT_LE(three, 3 * (3 * whole / 41));
    EXPECT_EQ(three, three2);
    EXPECT_GT(one, 0);
}

// A group's paths are stored up to Config::trace_step_budget interactions;
// the lives still going on then are finished one interaction at a time with
// their kernels run at once.  Long lives (a point source inside a closed
// sphere, reflectance barely wearing off, many capped) give the same rows,
// counters, mass books and rays (as a set) whatever the budget, at 1 and 2
// threads.
TEST(Trace, StepBudgetNeverChangesResults) {
    struct Outcome {
        std::vector<float> rows;
        TraceStats st;
        std::vector<RecordedRay> rays;
    };
    auto run = [](int threads, int64_t budget) {
        Mesh m = gamma_test::icosphere(3);
        Config c = base_config(5, 0.00005f);
        c.surfels = 1500;
        c.threads = threads;
        c.max_interactions = 300;
        c.trace_step_budget = budget;
        c.surface_rows[0][3] = 1.0f;
        const int t = c.add_ton_type(1, 0, 0, {1.0f});
        c.add_source("point", t, int64_t(kChunkSize) + 77, {0.1f, 0.05f, 0});   // 2 chunks
        c.set_transport(GAMMA_EVENT_HIT, t, 0, addr(reinterpret_cast<void*>(&k_hit)), true);
        c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<void*>(&k_settle)), true);
        c.mass_properties = {MassProperty{{3}, {0}}};
        Simulation sim(m, c);
        Outcome o;
        o.rays = sim.record_rays(1);
        o.st = sim.trace(1);
        o.rows = sim.rows();
        std::sort(o.rays.begin(), o.rays.end(), [](const RecordedRay& a, const RecordedRay& b) {
            return std::memcmp(&a, &b, sizeof(RecordedRay)) < 0;
        });
        return o;
    };
    const Outcome ref = run(1, 0);
    // lives long enough (~32 x 200 steps a group) that budgets 300 and 5000
    // stop a group's rounds midway, and both ends of a life (settled, capped)
    EXPECT_GT(ref.st.interactions, 100 * ref.st.emitted);
    EXPECT_GT(ref.st.capped, 0);
    EXPECT_GT(ref.st.settled, ref.st.capped);
    EXPECT_EQ(ref.st.escaped, 0);
    ASSERT_EQ(ref.st.mass.size(), 1u);
    EXPECT_GT(ref.st.mass[0].deposited, 0.0);
    EXPECT_EQ(int64_t(ref.rays.size()), ref.st.rays);
    for (int threads : {1, 2}) {
        for (int64_t budget : {int64_t(0), int64_t(1), int64_t(7), int64_t(300), int64_t(5000)}) {
            SCOPED_TRACE("threads " + std::to_string(threads) + ", budget " + std::to_string(budget));
            const Outcome o = run(threads, budget);
            ASSERT_EQ(o.rows.size(), ref.rows.size());
            EXPECT_EQ(0, std::memcmp(o.rows.data(), ref.rows.data(), ref.rows.size() * sizeof(float)));
            EXPECT_EQ(o.st.emitted, ref.st.emitted);
            EXPECT_EQ(o.st.settled, ref.st.settled);
            EXPECT_EQ(o.st.escaped, ref.st.escaped);
            EXPECT_EQ(o.st.capped, ref.st.capped);
            EXPECT_EQ(o.st.missed, ref.st.missed);
            EXPECT_EQ(o.st.interactions, ref.st.interactions);
            EXPECT_EQ(o.st.rays, ref.st.rays);
            EXPECT_EQ(o.st.segments, ref.st.segments);
            ASSERT_EQ(o.st.mass.size(), 1u);
            const MassBooks &a = o.st.mass[0], &b = ref.st.mass[0];
            for (auto f : {&MassBooks::removed, &MassBooks::deposited, &MassBooks::emitted, &MassBooks::created,
                           &MassBooks::escaped, &MassBooks::dropped, &MassBooks::in_flight})
                EXPECT_EQ(0, std::memcmp(&(a.*f), &(b.*f), sizeof(double)));
            ASSERT_EQ(o.rays.size(), ref.rays.size());
            EXPECT_EQ(0, std::memcmp(o.rays.data(), ref.rays.data(), ref.rays.size() * sizeof(RecordedRay)));
        }
    }
}

namespace {
// A hit rule that reads and writes nothing: it only makes every interaction
// one whose surfel the tracer must look up.
extern "C" int32_t k_hit_nothing(float*, const float*, float*, const GammaContext*) { return 0; }
// An update rule that makes surface 0's straight reflectance differ from
// surfel to surfel (from the second iteration on).
extern "C" int32_t k_update_reflectance(float* surf, const GammaContext* ctx) {
    surf[GAMMA_ROW_REFLECTANCE_STRAIGHT] = 0.2f + 0.3f * std::fabs(ctx->position[0]);
    return 0;
}
}  // namespace

// The tracer looks an interaction's surfel up only where something needs it:
// a rule of the interaction's event or of every hit, or reflectances that
// differ between the surfels of the surface (Tracer::uniform_reflectance).
// Elsewhere it reads the surface's reflectances.  A hit rule that does
// nothing forces every lookup: with and without it, the rows and counters
// are the same bit for bit, on a surface whose reflectances are uniform and
// on one whose reflectances an update rule has made differ, at 1 and 2
// threads.
TEST(Trace, SurfelLookedUpOnlyWhereNeededSameResults) {
    struct Outcome {
        std::vector<float> rows;
        std::vector<int64_t> counts;
        std::vector<std::vector<uint8_t>> uniform;   // per iteration, per surface
    };
    auto run = [](int threads, bool every_lookup) {
        Mesh m = gamma_test::icosphere(3);
        const int W = 5;
        Config c = base_config(W, 0.3f);
        c.surfels = 3000;
        c.threads = threads;
        c.max_interactions = 3;
        c.surface_rows.push_back({0.15f, 0, 0, 0.5f, 0.25f});
        c.triangle_surface.resize(m.num_triangles());
        for (size_t i = 0; i < m.num_triangles(); ++i) c.triangle_surface[i] = int32_t(i % 2);
        int t0 = c.add_ton_type(1, 0, 0, {1.0f});
        int t1 = c.add_ton_type(0.8f, 0, 0, {0.5f});
        c.add_source("point", t0, 20000, {0.1f, 0, 0});
        c.add_source("sphere", t1, 20000);
        for (int ty : {t0, t1})
            for (int s : {0, 1}) {
                c.set_transport(GAMMA_EVENT_SETTLE, ty, s, addr(reinterpret_cast<void*>(&k_settle)), true);
                if (every_lookup)
                    c.set_transport(GAMMA_EVENT_HIT, ty, s, addr(reinterpret_cast<void*>(&k_hit_nothing)), false);
            }
        // reflections of ton type 1 on surface 1 run a rule too
        c.set_transport(GAMMA_EVENT_REFLECT, t1, 1, addr(reinterpret_cast<void*>(&k_hit)), true);
        c.set_update(0, addr(reinterpret_cast<void*>(&k_update_reflectance)));
        Simulation sim(m, c);
        Outcome out;
        for (int it = 1; it <= 3; ++it) {
            out.uniform.push_back(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform);
            const TraceStats st = sim.trace(it);
            sim.update(it);
            out.counts.insert(out.counts.end(), {st.emitted, st.missed, st.escaped, st.settled, st.capped,
                                                 st.interactions, st.rays});
        }
        out.rows = sim.rows();
        return out;
    };
    const Outcome base = run(1, false);
    // the first iteration finds both surfaces uniform, the later ones surface 0 no longer
    ASSERT_EQ(base.uniform.size(), 3u);
    EXPECT_EQ(base.uniform[0], (std::vector<uint8_t>{1, 1}));
    EXPECT_EQ(base.uniform[1], (std::vector<uint8_t>{0, 1}));
    EXPECT_EQ(base.uniform[2], (std::vector<uint8_t>{0, 1}));
    EXPECT_GT(base.counts[4], 0);   // some lives capped (at 3 interactions)
    for (int threads : {1, 2})
        for (bool every : {false, true}) {
            if (threads == 1 && !every) continue;
            const Outcome o = run(threads, every);
            EXPECT_EQ(o.counts, base.counts) << threads << " threads, every lookup " << every;
            ASSERT_EQ(o.rows.size(), base.rows.size());
            EXPECT_EQ(0, std::memcmp(o.rows.data(), base.rows.data(), o.rows.size() * sizeof(float)))
                << threads << " threads, every lookup " << every;
        }
}

// The same, where the skipped lookups would show: a hit rule that writes
// (ton type 1 on surface 1, no other rule there but settling), ton types
// that bounce and flow (the parabolic and flow reflectances read from the
// surface where no lookup is made), and the mass books.  Run B differs from
// run A only by one surfel per surface whose zero flow reflectance is -0
// (the same probabilities): its surfaces are not uniform, so B looks every
// interaction's surfel up; A skips every lookup no rule needs.  Both must
// give the same counters, mass books and rows, at 1 and 2 threads, traced
// whole or (as Ray workers do) in ranges of chunks merged in order.
TEST(Trace, SkippedLookupsChangeNothingWhereRulesWriteAndTonsBounceAndFlow) {
    struct Outcome {
        std::vector<int64_t> counts;
        std::vector<double> books;
        std::vector<float> rows;
        std::vector<std::vector<uint8_t>> uniform;
    };
    // pieces > 0: each iteration traced in ranges of `pieces` chunks and merged
    auto run = [](int threads, bool forced, int pieces = 0) {
        Mesh m = gamma_test::icosphere(3);
        const int W = 5;
        Config c = base_config(W, 0.5f);
        c.surfels = 3000;
        c.threads = threads;
        c.max_interactions = 6;
        c.surface_rows[0] = {0.5f, 0.4f, 0.0f, 0, 0};
        c.surface_rows.push_back({0.15f, 0.6f, 0.0f, 0.5f, 0.25f});
        c.triangle_surface.resize(m.num_triangles());
        for (size_t i = 0; i < m.num_triangles(); ++i) c.triangle_surface[i] = int32_t(i % 2);
        const int t0 = c.add_ton_type(1, 0, 0, {1.0f});
        const int t1 = c.add_ton_type(0.4f, 0.3f, 0.3f, {0.5f}, 0.3f, 0.05f);
        c.add_source("sphere", t0, 15000);
        c.add_source("sphere", t1, 15000);
        for (int ty : {t0, t1})
            for (int s : {0, 1}) c.set_transport(GAMMA_EVENT_SETTLE, ty, s, addr(reinterpret_cast<void*>(&k_settle)), true);
        c.set_transport(GAMMA_EVENT_HIT, t1, 1, addr(reinterpret_cast<void*>(&k_hit)), true);
        c.add_mass_property({3, 3}, {0, 0});      // column 3 of both surfaces, the tons' carry 0
        Simulation sim(m, c);
        std::vector<float> rows = sim.rows();
        if (forced) {
            for (int s : {0, 1}) {
                const std::vector<int32_t> surf = sim.surfel_surfaces();
                const size_t i = size_t(std::find(surf.begin(), surf.end(), s) - surf.begin());
                rows[i * size_t(W) + GAMMA_ROW_REFLECTANCE_FLOW] = -0.0f;
            }
            sim.set_rows(rows.data());
        }
        Outcome out;
        for (int it = 1; it <= 3; ++it) {
            out.uniform.push_back(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform);
            TraceStats st;
            if (pieces == 0) {
                st = sim.trace(it);
            } else {
                const int64_t n = sim.num_chunks(it);
                std::vector<ChunkLog> logs;
                for (int64_t a = 0; a < n; a += pieces)
                    for (ChunkLog& log : sim.trace_chunks(it, a, std::min<int64_t>(n, a + pieces)))
                        logs.push_back(std::move(log));
                st = sim.merge_chunks(it, logs);
            }
            sim.update(it);
            out.counts.insert(out.counts.end(), {st.emitted, st.missed, st.escaped, st.settled, st.capped,
                                                 st.interactions, st.rays, st.flow_steps, st.bounces, st.drips});
            for (const MassBooks& b : st.mass)
                out.books.insert(out.books.end(), {b.removed, b.deposited, b.emitted, b.created, b.escaped,
                                                   b.dropped, b.in_flight});
        }
        out.rows = sim.rows();
        return out;
    };
    const Outcome skipping = run(1, false), looking = run(1, true);
    EXPECT_EQ(skipping.uniform[0], (std::vector<uint8_t>{1, 1}));
    EXPECT_EQ(looking.uniform[0], (std::vector<uint8_t>{0, 0}));       // every interaction looked up
    // the rules wrote, and the tons bounced and flowed
    EXPECT_GT(skipping.counts[8], 0);
    EXPECT_GT(skipping.counts[7], 0);
    ASSERT_FALSE(skipping.books.empty());
    EXPECT_GT(skipping.books[1], 0.0);
    struct Variant {
        int threads;
        bool forced;
        int pieces;
    };
    for (const Variant v : {Variant{1, false, 0}, Variant{1, true, 0}, Variant{2, false, 0}, Variant{2, true, 0},
                            Variant{2, false, 3}, Variant{1, false, 1}}) {
        const Outcome o = v.threads == 1 && v.pieces == 0 ? (v.forced ? looking : skipping)
                                                          : run(v.threads, v.forced, v.pieces);
        const std::string which = std::to_string(v.threads) + " threads, forced " + std::to_string(v.forced) +
                                  ", pieces " + std::to_string(v.pieces);
        EXPECT_EQ(o.counts, looking.counts) << which;
        ASSERT_EQ(o.books.size(), looking.books.size());
        EXPECT_EQ(0, std::memcmp(o.books.data(), looking.books.data(), o.books.size() * sizeof(double))) << which;
        ASSERT_EQ(o.rows.size(), looking.rows.size());
        for (size_t k = 0; k < o.rows.size(); ++k)      // == (the forced run's -0 equals 0)
            ASSERT_TRUE(o.rows[k] == looking.rows[k] || (o.rows[k] != o.rows[k] && looking.rows[k] != looking.rows[k]))
                << k << ": " << which;
    }
}

// Tracer::uniform_reflectance: a surface is uniform when it has surfels and
// all of them hold the same reflectance columns, bit for bit (-0 and +0
// differ); a surface without surfels is not.
TEST(Trace, UniformReflectanceNeedsEqualColumnsAndSurfels) {
    Mesh m = gamma_test::icosphere(2);
    Config c = base_config(4, 0.3f);
    c.surfels = 500;
    c.surface_rows.push_back({0.1f, 0.2f, 0.3f, 0});
    c.surface_rows.push_back({0.1f, 0.2f, 0.3f, 0});
    c.triangle_surface.assign(m.num_triangles(), 0);
    for (size_t i = 0; i < m.num_triangles(); i += 2) c.triangle_surface[i] = 1;   // surface 2: no triangle
    int t = c.add_ton_type(1, 0, 0, {});
    c.add_source("point", t, 10, {0, 0, 0});
    Simulation sim(m, c);
    EXPECT_EQ(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform,
              (std::vector<uint8_t>{1, 1, 0}));
    std::vector<float> rows = sim.rows();
    const auto& surface = sim.state().surface;
    // surface 0 with a straight reflectance of +0 everywhere, then -0 in one surfel
    std::vector<float> zeroed = rows;
    for (size_t s = 0; s < surface.size(); ++s) {
        if (surface[s] != 0) continue;
        rows[s * 4 + GAMMA_ROW_REFLECTANCE_STRAIGHT] = 0.0f;
        zeroed[s * 4 + GAMMA_ROW_REFLECTANCE_STRAIGHT] = 0.0f;
    }
    for (size_t s = 0; s < surface.size(); ++s)
        if (surface[s] == 0) {
            zeroed[s * 4 + GAMMA_ROW_REFLECTANCE_STRAIGHT] = -0.0f;
            break;
        }
    sim.set_rows(rows.data());
    EXPECT_EQ(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform,
              (std::vector<uint8_t>{1, 1, 0}));
    sim.set_rows(zeroed.data());
    EXPECT_EQ(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform,
              (std::vector<uint8_t>{0, 1, 0}));
    // a property column that differs does not matter
    rows[3] = 7.0f;
    sim.set_rows(rows.data());
    EXPECT_EQ(Tracer::uniform_reflectance(sim.scene_index(), sim.state()).uniform,
              (std::vector<uint8_t>{1, 1, 0}));
}
