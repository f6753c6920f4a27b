// Per-surfel accessibility, curvature and uv (SPEC §12): analytic values on a
// plane and a sphere, the floor of a box, and bit-identical at 1 and 2 threads.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gamma/render.h"
#include "gamma/scene_index.h"
#include "gamma/surfel_measures.h"
#include "gamma/surfels.h"
#include "helpers.h"

using namespace gammart;

namespace {
struct Measured {
    SurfelSet surf;
    SurfelMeasures m;
};

Measured measure(const Mesh& mesh, size_t n, int threads, MeasureRequest want = {true, true, true}) {
    Measured out;
    out.surf = sample_surfels(mesh, n, 7);
    SceneIndex index;
    index.build_geometry(mesh, std::vector<int32_t>(mesh.num_triangles(), 0), 1);
    const SceneFrame frame = SceneFrame::of(mesh, {0, -1, 0});
    out.m = measure_surfels(want, mesh, index, out.surf, kAoLengthFraction * frame.diag, 7, threads);
    return out;
}

// An open box of width 1 and the given depth: floor at y = 0, normals inward.
Mesh open_box(float depth) {
    gamma_test::Builder b;
    gamma_test::floor_quad(b, -0.5f, 0.5f, -0.5f, 0.5f);
    const float w = 0.5f, h = depth;
    b.quad({w, 0, -w}, {w, 0, w}, {w, h, w}, {w, h, -w});      // x = +w, normal -x
    b.quad({-w, 0, -w}, {-w, h, -w}, {-w, h, w}, {-w, 0, w});  // x = -w, normal +x
    b.quad({-w, 0, w}, {-w, h, w}, {w, h, w}, {w, 0, w});      // z = +w, normal -z
    b.quad({-w, 0, -w}, {w, 0, -w}, {w, h, -w}, {-w, h, -w});  // z = -w, normal +z
    return b.mesh("box");
}

double floor_centre_accessibility(const Measured& r) {
    double sum = 0;
    int count = 0;
    for (size_t i = 0; i < r.surf.triangle.size(); ++i) {
        const float* p = &r.surf.position[3 * i];
        if (std::fabs(p[1]) < 1e-6f && std::fabs(p[0]) < 0.2f && std::fabs(p[2]) < 0.2f) {
            EXPECT_GT(r.surf.normal[3 * i + 1], 0.99f);
            sum += r.m.accessibility[i];
            ++count;
        }
    }
    EXPECT_GT(count, 10);
    return sum / count;
}
}  // namespace

TEST(SurfelMeasures, AnOpenPlaneIsFullyAccessibleAndFlat) {
    gamma_test::Builder b;
    gamma_test::floor_quad(b, -1, 1, -1, 1);
    const Measured r = measure(b.mesh(), 2000, 2);
    for (size_t i = 0; i < r.surf.triangle.size(); ++i) {
        EXPECT_EQ(r.m.accessibility[i], 1.0f);
        EXPECT_LT(std::fabs(r.m.curvature[i]), 1e-4f);
    }
    EXPECT_TRUE(std::all_of(r.m.uv.begin(), r.m.uv.end(), [](float x) { return x == 0.0f; }));  // no uvs
}

TEST(SurfelMeasures, BoxFloorsCloseUpWithDepth) {
    double last = 1.01;
    for (float depth : {0.25f, 1.0f, 4.0f}) {
        const double a = floor_centre_accessibility(measure(open_box(depth), 4000, 2, {true, false, false}));
        EXPECT_LT(a, last) << depth;
        last = a;
    }
    EXPECT_LT(last, 0.2);
}

TEST(SurfelMeasures, SphereCurvatureIsOneOverRadiusConvexPositive) {
    const float r = 2.0f;
    const Measured m = measure(gamma_test::icosphere(5, r), 20000, 2, {true, true, false});
    std::vector<float> c = m.m.curvature;
    std::nth_element(c.begin(), c.begin() + c.size() / 2, c.end());
    EXPECT_NEAR(c[c.size() / 2], 1.0f / r, 0.05f / r);
    for (float a : m.m.accessibility) EXPECT_EQ(a, 1.0f);  // a lone convex object: every ray escapes
}

TEST(SurfelMeasures, BitIdenticalAtOneAndTwoThreads) {
    const Mesh mesh = open_box(1.5f);
    const Measured a = measure(mesh, 3000, 1), b = measure(mesh, 3000, 2);
    EXPECT_EQ(a.m.accessibility, b.m.accessibility);
    EXPECT_EQ(a.m.curvature, b.m.curvature);
}
