// The update pass on its own: each surfel's kernel runs once on its own row
// with its own position, normal and height; surfaces without a kernel are
// left alone.
#include <gtest/gtest.h>

#include "gamma/update_pass.h"
#include "helpers.h"

using namespace gammart;

namespace {
extern "C" int32_t k_height(float* surf, const GammaContext* ctx) {
    surf[3] = ctx->height;
    surf[4] += 1.0f;
    return ctx->position[0] < 0.5f ? 1 : 0;  // report "statement 1 was not finite" on the left half
}
}  // namespace

TEST(UpdatePass, RunsEachSurfelsKernelOnce) {
    gamma_test::Builder b;
    b.quad({0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0});  // surface 0 (upright, in z = 0)
    b.quad({1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0});  // surface 1
    const Mesh m = b.mesh();
    const std::vector<int32_t> ts = {0, 0, 1, 1};
    SurfelState st = SurfelState::sample(m, ts, 300, 9, {{0, 0, 0, 0, 0}, {0, 0, 0, 0, 7}});
    Config c;
    c.row_width = 5;
    c.surface_rows = {{0, 0, 0, 0, 0}, {0, 0, 0, 0, 7}};
    c.set_update(0, uint64_t(reinterpret_cast<uintptr_t>(&k_height)));
    const KernelTable K = KernelTable::from_config(c);
    const SceneFrame f = SceneFrame::of(m, {0, -1, 0});
    for (int threads : {1, 2}) {
        SurfelState s = st;
        const UpdateStats us = run_update_pass(K, f, s, 1, 1, threads);
        int64_t left = 0;
        for (size_t i = 0; i < s.size(); ++i) {
            if (s.surface[i] == 0) {
                EXPECT_EQ(s.row(i)[3], s.surf.position[3 * i + 1]);  // height above y = 0
                EXPECT_EQ(s.row(i)[4], 1.0f);
                left += s.surf.position[3 * i] < 0.5f;
            } else {
                EXPECT_EQ(s.row(i)[3], 0.0f);
                EXPECT_EQ(s.row(i)[4], 7.0f);
            }
        }
        ASSERT_EQ(us.nonfinite.size(), 1u);
        EXPECT_EQ(us.nonfinite[0].event, -1);
        EXPECT_EQ(us.nonfinite[0].surface, 0);
        EXPECT_EQ(us.nonfinite[0].count, left);
    }
}
