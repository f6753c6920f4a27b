// The Simulation facade: the parts it wires (surfel state, baker through the
// render scene) and the refusal of a surface that received no surfel.
#include <gtest/gtest.h>

#include <string>

#include "gamma/baker.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;
using gamma_test::expect_error;

namespace {

// A 10 x 10 floor (surface 0) and a tiny triangle of area 5e-5 far above it
// (the triangle's surface chosen by the caller).
Mesh floor_and_speck(gamma_test::Builder& b) {
    gamma_test::floor_quad(b, -5, 5, -5, 5);
    const int32_t i = b.vert({0, 3, 0}), j = b.vert({0.01f, 3, 0}), k = b.vert({0, 3, 0.01f});
    b.t.insert(b.t.end(), {i, k, j});
    return b.mesh("floor and speck");
}

Config two_surfaces(int64_t surfels) {
    Config c;
    c.surfels = surfels;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 1}, {0, 0, 0, 2}};
    return c;
}

}  // namespace

TEST(Facade, SurfaceWithoutSurfelsIsRefusedNotRunWithAnothersRules) {
    gamma_test::Builder b;
    const Mesh m = floor_and_speck(b);
    Config c = two_surfaces(200);
    c.triangle_surface = {0, 0, 1};
    const std::string msg = expect_error([&] { Simulation sim(m, c); });
    EXPECT_NE(msg.find("surface 1 has 1 triangle(s)"), std::string::npos) << msg;
    EXPECT_NE(msg.find("received no surfel at 200 surfels"), std::string::npos) << msg;
    EXPECT_NE(msg.find("raise the surfel count"), std::string::npos) << msg;
    // the count it suggests is a whole number above the one that failed
    const size_t about = msg.find("to about ");
    ASSERT_NE(about, std::string::npos) << msg;
    EXPECT_GT(std::stoll(msg.substr(about + 9)), 200) << msg;
    // The same speck on surface 0 is fine (surface 1 has no triangles: never hit).
    c.triangle_surface = {0, 0, 0};
    Simulation sim(m, c);
    EXPECT_EQ(sim.num_surfels(), 200u);
    for (int32_t s : sim.surfel_surfaces()) EXPECT_EQ(s, 0);
}

TEST(Facade, SurfelStateRowsFollowTheirSurface) {
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    b.quad({1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0});
    const Mesh m = b.mesh();
    Config c = two_surfaces(300);
    c.triangle_surface = {0, 0, 1, 1};
    Simulation sim(m, c);
    const SurfelState& st = sim.state();
    ASSERT_EQ(st.size(), 300u);
    EXPECT_EQ(st.width, 4);
    for (size_t i = 0; i < st.size(); ++i) {
        const int s = st.surface[i];
        EXPECT_EQ(s, st.surf.position[3 * i] < 1.0f ? 0 : 1);
        EXPECT_EQ(st.row(i)[3], float(s + 1));
    }
    EXPECT_EQ(sim.scene_index().geometry_builds(), 1);
    EXPECT_EQ(sim.scene_index().surfel_builds(), 1);
}

TEST(Facade, BakerGivesTheSmoothedRowAndNeutralAlbedo) {
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    const Mesh m = b.mesh();
    Config c = two_surfaces(400);
    c.surface_rows = {{0, 0, 0, 0.25f}};
    Simulation sim(m, c);
    std::vector<float> rows = sim.rows();
    for (size_t i = 0; i < sim.num_surfels(); ++i) rows[4 * i + 3] = sim.surfels().position[3 * i];  // x
    sim.set_rows(rows.data());
    const float pos[6] = {0.3f, 0.4f, 0, 0.7f, 0.2f, 0}, nrm[6] = {0, 0, 1, 0, 0, 1}, uv[4] = {0, 0, 0, 0};
    const int32_t tri[2] = {0, 1};
    float out_rows[8], look[2 * GAMMA_LOOK_WIDTH];
    sim.bake_points(2, pos, nrm, tri, uv, 1, 2, out_rows, look);
    for (int k = 0; k < 2; ++k) {
        float ref[4];
        sim.interpolate_row(0, pos + 3 * k, ref);
        for (int col = 0; col < 4; ++col) EXPECT_EQ(out_rows[4 * k + col], ref[col]);
        EXPECT_NEAR(out_rows[4 * k + 3], pos[3 * k], 0.05f);  // smoothing of x is about x
        for (int col = 0; col < 3; ++col) EXPECT_EQ(look[GAMMA_LOOK_WIDTH * k + col], kNeutralAlbedo);
        EXPECT_EQ(look[GAMMA_LOOK_WIDTH * k + GAMMA_LOOK_ROUGHNESS], GAMMA_LOOK_DEFAULT_ROUGHNESS);
        EXPECT_EQ(look[GAMMA_LOOK_WIDTH * k + GAMMA_LOOK_OCCLUSION], 1.0f);
    }
    const int32_t bad[1] = {2};
    EXPECT_NE(expect_error([&] { sim.bake_points(1, pos, nrm, bad, uv, 1, 1, out_rows, look); })
                  .find("triangle 2 out of range"),
              std::string::npos);
}

namespace {

void expect_same_state(const Simulation& a, const Simulation& b) {
    EXPECT_EQ(a.surfels().position, b.surfels().position);
    EXPECT_EQ(a.surfels().normal, b.surfels().normal);
    EXPECT_EQ(a.surfels().triangle, b.surfels().triangle);
    EXPECT_EQ(a.surfel_surfaces(), b.surfel_surfaces());
    EXPECT_EQ(a.rows(), b.rows());
    EXPECT_EQ(a.state().splat.offset, b.state().splat.offset);
    EXPECT_EQ(a.state().splat.source, b.state().splat.source);
    EXPECT_EQ(a.state().splat.weight, b.state().splat.weight);
}

}  // namespace

TEST(Facade, SurfelsSampledAheadAreUsedOnlyWhenTheyAreTheOnesTheSetupWouldSample) {
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    b.quad({1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0});
    const Mesh m = b.mesh();
    Config c = two_surfaces(500);
    c.seed = 7;
    c.threads = 2;
    c.triangle_surface = {0, 0, 1, 1};
    const Simulation plain(m, c);
    EXPECT_EQ(plain.setup_seconds().sample_ahead, 0.0);

    // the same mesh, count and seed, sampled at another thread count: taken, same state
    SurfelSample ahead(m, 500, 7, 1);
    ASSERT_TRUE(ahead.ok());
    EXPECT_TRUE(ahead.matches(m, 500, 7));
    const Simulation with(m, c, &ahead);
    EXPECT_GT(with.setup_seconds().sample_ahead, 0.0);
    expect_same_state(with, plain);
    // taken once: a second setup samples its own
    EXPECT_FALSE(ahead.ok());
    const Simulation again(m, c, &ahead);
    EXPECT_EQ(again.setup_seconds().sample_ahead, 0.0);
    expect_same_state(again, plain);
    // another Mesh object with the same contents is the same mesh
    const Mesh copy = m;
    SurfelSample of_copy(copy, 500, 7, 2);
    const Simulation from_copy(m, c, &of_copy);
    EXPECT_GT(from_copy.setup_seconds().sample_ahead, 0.0);
    expect_same_state(from_copy, plain);

    // another seed, another count, another mesh: not taken, and the state is the setup's own
    SurfelSample other_seed(m, 500, 8, 2), other_count(m, 499, 7, 2);
    gamma_test::Builder moved;
    moved.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    moved.quad({1, 0, 0}, {2, 0, 0}, {2, 1.5f, 0}, {1, 1, 0});
    const Mesh m2 = moved.mesh();
    SurfelSample other_mesh(m2, 500, 7, 2);
    for (SurfelSample* s : {&other_seed, &other_count, &other_mesh}) {
        ASSERT_TRUE(s->ok());
        EXPECT_FALSE(s->matches(m, 500, 7));
        const Simulation sim(m, c, s);
        EXPECT_EQ(sim.setup_seconds().sample_ahead, 0.0);
        expect_same_state(sim, plain);
        EXPECT_TRUE(s->ok());   // not taken
    }
}

TEST(Facade, ASampleThatFailedLeavesTheErrorToTheSetup) {
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});
    const Mesh m = b.mesh();
    SurfelSample none(m, 0, 1, 2);  // sample_surfels refuses 0 surfels: no exception here
    EXPECT_FALSE(none.ok());
    EXPECT_FALSE(none.matches(m, 0, 1));
    Config c = two_surfaces(0);
    c.surface_rows = {{0, 0, 0, 1}};
    const std::string plain = expect_error([&] { Simulation sim(m, c); });
    EXPECT_FALSE(plain.empty());
    EXPECT_EQ(expect_error([&] { Simulation sim(m, c, &none); }), plain);
    // an error of the config comes first, as without a sample
    c.surfels = 200;
    c.triangle_surface = {0, 5};
    SurfelSample fine(m, 200, 1, 2);
    const std::string bad = expect_error([&] { Simulation sim(m, c); });
    EXPECT_NE(bad.find("has surface id 5"), std::string::npos) << bad;
    EXPECT_EQ(expect_error([&] { Simulation sim(m, c, &fine); }), bad);
}

TEST(Facade, SettingTheShadingTheSetupUsedKeepsItsNormalsAndAnotherRecomputesThem) {
    const Mesh m = gamma_test::icosphere(2);
    Config c = two_surfaces(300);
    c.surface_rows = {{0, 0, 0, 1}};
    Simulation sim(m, c);
    const std::vector<float> setup = *sim.corner_normals();
    const std::shared_ptr<const std::vector<float>> held = sim.corner_normals();
    EXPECT_EQ(setup, corner_normals(m, {}, kDefaultCreaseDeg));
    sim.set_shading({}, kDefaultCreaseDeg);          // what the setup computed them for: not again
    EXPECT_EQ(sim.corner_normals(), held);
    EXPECT_EQ(*sim.corner_normals(), setup);
    sim.set_shading({}, 0.0f);                        // all flat: recomputed
    EXPECT_EQ(*sim.corner_normals(), corner_normals(m, {}, 0.0f));
    EXPECT_NE(*sim.corner_normals(), setup);
    EXPECT_EQ(*held, setup);                          // what a render still holds is left as it was
    sim.set_shading({}, kDefaultCreaseDeg);           // and back
    EXPECT_EQ(*sim.corner_normals(), setup);
}
