// What the setup-cache and setup-snapshot tests share: a deposit kernel, a
// config that traces the bunny with it, and the checks that two simulations
// have the same setup and trace the same rows.
#pragma once
#include <gtest/gtest.h>

#include <cstdint>
#include <initializer_list>

#include "gamma/simulation.h"

namespace gamma_test {

// Deposits 1 in row column 3 at every event it is bound to (spread by the splat kernel).
extern "C" inline int32_t deposit_one_in_column_3(float*, const float*, float* delta, const GammaContext*) {
    delta[3] = 1.0f;
    return 0;
}

// 20,000 gamma-tons from a sphere around the scene, deposit_one_in_column_3
// bound to `events` on each of `surfaces` surfaces (rows of width 4).
inline gammart::Config deposit_config(int64_t surfels, uint64_t seed, int threads, int surfaces,
                                      std::initializer_list<int> events) {
    gammart::Config c;
    c.surfels = surfels;
    c.seed = seed;
    c.threads = threads;
    c.row_width = 4;
    c.surface_rows.assign(size_t(surfaces), {0, 0, 0, 0});
    const int t = c.add_ton_type(0, 0, 0, {}, 1.0f, 0.1f);
    gammart::Source s;
    s.kind = "sphere";
    s.ton_type = t;
    s.count = 20000;
    c.add_source(s);
    for (int surface = 0; surface < surfaces; ++surface)
        for (int event : events)
            c.set_transport(event, t, surface, uint64_t(reinterpret_cast<uintptr_t>(&deposit_one_in_column_3)),
                            true);
    return c;
}

// The same surfels, splat kernel and triangle lookup.
inline void expect_same_setup(const gammart::Simulation& a, const gammart::Simulation& b) {
    EXPECT_EQ(a.surfels().position, b.surfels().position);
    EXPECT_EQ(a.surfels().normal, b.surfels().normal);
    EXPECT_EQ(a.surfels().triangle, b.surfels().triangle);
    EXPECT_EQ(a.surfels().r_max, b.surfels().r_max);
    EXPECT_EQ(a.surfel_surfaces(), b.surfel_surfaces());
    EXPECT_EQ(a.state().splat.offset, b.state().splat.offset);
    EXPECT_EQ(a.state().splat.source, b.state().splat.source);
    EXPECT_EQ(a.state().splat.weight, b.state().splat.weight);
    EXPECT_EQ(a.state().splat.mean_neighbours, b.state().splat.mean_neighbours);
    EXPECT_TRUE(a.scene_index().same_lookup(b.scene_index()));
    EXPECT_EQ(a.scene_index().lookup_candidates(), b.scene_index().lookup_candidates());
}

// Both traced and updated for `iterations` iterations: the same counts per
// iteration and the same rows at the end.
inline void expect_same_iterations(gammart::Simulation& a, gammart::Simulation& b, int iterations = 2) {
    for (int it = 1; it <= iterations; ++it) {
        const gammart::TraceStats sa = a.trace(it), sb = b.trace(it);
        EXPECT_EQ(sa.interactions, sb.interactions);
        EXPECT_EQ(sa.emitted, sb.emitted);
        a.update(it);
        b.update(it);
    }
    EXPECT_EQ(a.rows(), b.rows());
}

}  // namespace gamma_test
