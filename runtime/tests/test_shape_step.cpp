// The shape step: displacement from a property, re-tiling, transfer of the
// rows, rebuild, and the mass books of pick-up.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <string>

#include "gamma/gmath.h"
#include "gamma/shape_step.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;

namespace {

uint64_t addr(const void* f) { return uint64_t(reinterpret_cast<uintptr_t>(f)); }

extern "C" int32_t k_erode_one(float* surf, const GammaContext*) {
    surf[3] += 1.0f;  // one unit of `eroded` everywhere, every iteration
    return 0;
}
extern "C" int32_t k_erode_x(float* surf, const GammaContext* ctx) {
    surf[3] += 1.0f + ctx->position[0];  // more on +x
    return 0;
}

// Rows: header (3), eroded (3), dye (4).
Config sphere_config(int64_t surfels, float metres_per_unit, const void* update) {
    Config c;
    c.surfels = surfels;
    c.seed = 11;
    c.row_width = 5;
    c.surface_rows = {{0, 0, 0, 0, 0}};
    c.set_update(0, addr(update));
    c.add_shape_rate(0, 3, metres_per_unit);
    return c;
}

ShapeStats run_iteration(Simulation& sim, int it) {
    sim.trace(it);
    sim.update(it);
    return sim.shape(it);
}

void run_iterations(Simulation& sim, int n) {
    for (int it = 1; it <= n; ++it) {
        sim.trace(it);
        sim.update(it);
        sim.shape(it);
    }
}

}  // namespace

TEST(ShapeStep, UniformRemovalShrinksASphereByTheStatedAmount) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    const double v0 = measure(m).volume;
    ASSERT_GT(v0, 0.0);  // outward-wound
    Simulation sim(m, sphere_config(6000, -0.01f, reinterpret_cast<const void*>(&k_erode_one)));
    run_iterations(sim, 5);
    const MeshMeasures g = measure(sim.mesh());
    EXPECT_TRUE(g.closed);
    // Radius 1 - 5 x 0.01 = 0.95: the volume scales by 0.95^3 (within 1 %).
    EXPECT_NEAR(g.volume / v0, std::pow(0.95, 3), 0.01 * std::pow(0.95, 3));
    // Every vertex is at radius 0.95 (the faceted sphere's vertices were at 1).
    for (size_t v = 0; v < sim.mesh().num_vertices(); ++v) {
        const float* p = &sim.mesh().vertices[3 * v];
        EXPECT_NEAR(std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]), 0.95, 0.004);
    }
    EXPECT_EQ(sim.shape_rebuilds(), 5);
}

TEST(ShapeStep, RetilingKeepsTrianglesWellShapedAndTheMeshClosed) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    Simulation sim(m, sphere_config(6000, -0.02f, reinterpret_cast<const void*>(&k_erode_x)));
    for (int it = 1; it <= 4; ++it) {
        sim.trace(it);
        sim.update(it);
        const ShapeStats s = sim.shape(it);
        ASSERT_TRUE(s.changed);
        EXPECT_TRUE(s.geometry.closed) << "iteration " << it;
        EXPECT_GE(s.geometry.min_angle_deg, kMinRetiledAngleDeg) << "iteration " << it;
        for (float x : sim.mesh().vertices) ASSERT_TRUE(std::isfinite(x));
    }
    // Uneven erosion: the +x side lost more than the -x side.
    float xmin = 1e9f, xmax = -1e9f;
    for (size_t v = 0; v < sim.mesh().num_vertices(); ++v) {
        xmin = std::min(xmin, sim.mesh().vertices[3 * v]);
        xmax = std::max(xmax, sim.mesh().vertices[3 * v]);
    }
    EXPECT_LT(xmax, -xmin - 0.02f);
}

TEST(ShapeStep, PropertyIntegralsSurviveTransfer) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    Config c = sphere_config(5000, -0.01f, reinterpret_cast<const void*>(&k_erode_x));
    c.row_width = 6;
    c.surface_rows = {{0.1f, 0.2f, 0.3f, 0, 0}};
    c.surface_rows[0].push_back(0);
    Simulation sim(m, c);
    // A dye that varies over the surface: its integral is sum(value) x area / N.
    std::vector<float> rows = sim.rows();
    for (size_t i = 0; i < sim.num_surfels(); ++i) rows[6 * i + 5] = 2.0f + sim.surfels().position[3 * i + 1];
    sim.set_rows(rows.data());
    auto integral = [&](int col) {
        double s = 0;
        for (size_t i = 0; i < sim.num_surfels(); ++i) s += sim.rows()[6 * i + size_t(col)];
        return s * sim.mesh().area() / double(sim.num_surfels());
    };
    for (int it = 1; it <= 3; ++it) {
        sim.trace(it);
        sim.update(it);
        const double eroded_before = integral(3), dye_before = integral(5);
        ASSERT_TRUE(sim.shape(it).changed);
        EXPECT_NEAR(integral(3) / eroded_before, 1.0, 1e-5);
        EXPECT_NEAR(integral(5) / dye_before, 1.0, 1e-5);
        // Header columns are copied, not scaled.
        for (size_t i = 0; i < sim.num_surfels(); ++i) {
            EXPECT_EQ(sim.rows()[6 * i + 0], 0.1f);
            EXPECT_EQ(sim.rows()[6 * i + 2], 0.3f);
        }
    }
}

TEST(ShapeStep, DeterministicAcrossThreadsWithRetiling) {
    const Mesh m = gamma_test::icosphere(3, 1.0f);
    std::vector<float> verts[2], rows[2];
    for (int k = 0; k < 2; ++k) {
        Config c = sphere_config(3000, -0.02f, reinterpret_cast<const void*>(&k_erode_x));
        c.threads = k + 1;
        int t = c.add_ton_type(0.5f, 0.3f, 0.1f, {});
        c.add_source("sphere", t, 20000);
        Simulation sim(m, c);
        run_iterations(sim, 3);
        verts[k] = sim.mesh().vertices;
        rows[k] = sim.rows();
    }
    ASSERT_EQ(verts[0].size(), verts[1].size());
    EXPECT_EQ(0, std::memcmp(verts[0].data(), verts[1].data(), sizeof(float) * verts[0].size()));
    ASSERT_EQ(rows[0].size(), rows[1].size());
    EXPECT_EQ(0, std::memcmp(rows[0].data(), rows[1].data(), sizeof(float) * rows[0].size()));
}

TEST(ShapeStep, AnInvertingDisplacementIsClampedNotApplied) {
    const Mesh m = gamma_test::icosphere(3, 1.0f);
    // -5 m per unit: 5 m inward in one iteration would turn the sphere inside out.
    Simulation sim(m, sphere_config(3000, -5.0f, reinterpret_cast<const void*>(&k_erode_one)));
    sim.trace(1);
    sim.update(1);
    const ShapeStats s = sim.shape(1);
    EXPECT_GT(s.clamped_vertices, 0);
    EXPECT_TRUE(s.geometry.closed);
    EXPECT_GT(s.geometry.volume, 0.0);
    for (float x : sim.mesh().vertices) ASSERT_TRUE(std::isfinite(x));
}

TEST(ShapeStep, NothingIsRebuiltWhenNothingMoves) {
    const Mesh m = gamma_test::icosphere(3, 1.0f);
    Config c = sphere_config(2000, -0.01f, reinterpret_cast<const void*>(&k_erode_one));
    c.updates.clear();  // the property never changes
    Simulation sim(m, c);
    for (int it = 1; it <= 2; ++it) {
        sim.trace(it);
        sim.update(it);
        const ShapeStats s = sim.shape(it);
        EXPECT_FALSE(s.changed);
        EXPECT_EQ(s.moved_vertices, 0);
    }
    EXPECT_EQ(sim.shape_rebuilds(), 0);
    EXPECT_EQ(sim.scene_index().geometry_builds(), 1);
}

namespace {
// Pick-up: a grain takes 10 % of the surfel's `stone` on every hit and
// leaves everything it carries where it settles.
extern "C" int32_t k_pick(float* ton, const float* surf, float* delta, const GammaContext*) {
    const float take = 0.1f * surf[3];
    delta[3] -= take;
    ton[0] += take;
    return 0;
}
extern "C" int32_t k_drop(float* ton, const float*, float* delta, const GammaContext*) {
    delta[3] += ton[0];
    ton[0] = 0.0f;
    return 0;
}
extern "C" int32_t k_make(float* ton, const float*, float*, const GammaContext*) {
    ton[0] += 0.5f;  // creates material from nothing
    return 0;
}
}  // namespace

TEST(MassBooks, PickUpBalancesAndCreationIsReported) {
    gamma_test::Builder b;
    gamma_test::floor_quad(b, -1, 1, -1, 1);
    b.quad({-1, 0, -1}, {1, 0, -1}, {1, 1, -1}, {-1, 1, -1});  // a wall
    const Mesh m = b.mesh();
    Config c;
    c.surfels = 2000;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 1.0f}};
    c.threads = 2;
    const int t = c.add_ton_type(0.3f, 0.3f, 0.2f, {0.0f});
    c.add_source("hemisphere", t, 30000);
    c.set_transport(GAMMA_EVENT_HIT, t, 0, addr(reinterpret_cast<const void*>(&k_pick)), true);
    c.set_transport(GAMMA_EVENT_SETTLE, t, 0, addr(reinterpret_cast<const void*>(&k_drop)), true);
    c.add_mass_property({3}, {0});
    Simulation sim(m, c);
    double before = 0;
    for (size_t i = 0; i < sim.num_surfels(); ++i) before += sim.rows()[4 * i + 3];
    const TraceStats st = sim.trace(1);
    ASSERT_EQ(st.mass.size(), 1u);
    const MassBooks& k = st.mass[0];
    EXPECT_GT(k.removed, 100.0);
    EXPECT_GT(k.deposited, 10.0);
    EXPECT_GT(k.escaped, 0.0);
    EXPECT_EQ(k.emitted, 0.0);
    EXPECT_EQ(k.in_flight, 0.0);
    EXPECT_NEAR(k.created, 0.0, 1e-6 * k.removed);  // a conserving rule creates nothing
    EXPECT_NEAR(k.removed + k.emitted + k.created, k.deposited + k.escaped + k.dropped + k.in_flight,
                1e-9 * k.removed);
    // The surfaces lost exactly what was removed and gained what was deposited.
    double after = 0;
    for (size_t i = 0; i < sim.num_surfels(); ++i) after += sim.rows()[4 * i + 3];
    EXPECT_NEAR(after - before, k.deposited - k.removed, 1e-4 * k.removed);

    // A rule that makes material from nothing shows up as `created`.
    c.set_transport(GAMMA_EVENT_REFLECT, t, 0, addr(reinterpret_cast<const void*>(&k_make)), false);
    Simulation sim2(m, c);
    const MassBooks k2 = sim2.trace(1).mass[0];
    EXPECT_GT(k2.created, 1000.0);
    EXPECT_NEAR(k2.removed + k2.emitted + k2.created, k2.deposited + k2.escaped + k2.dropped, 1e-9 * k2.created);
    // The same books at 1 thread.
    c.threads = 1;
    Simulation sim3(m, c);
    const MassBooks k3 = sim3.trace(1).mass[0];
    EXPECT_EQ(k3.removed, k2.removed);
    EXPECT_EQ(k3.created, k2.created);
    EXPECT_EQ(k3.escaped, k2.escaped);
}

namespace {
// An icosphere whose x > 0.85 cap is pinched (every vertex there pulled 80 %
// of the way to a neighbour: short edges and slivers there, nothing
// elsewhere), the region a local re-tiling would take, and the target edge
// length (the sphere's mean edge).
struct PinchedSphere {
    Mesh mesh;
    double target = 0;
    std::vector<uint8_t> region;
};
PinchedSphere pinched_sphere() {
    PinchedSphere p;
    Mesh& m = p.mesh;
    m = gamma_test::icosphere(4, 1.0f);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const float* a = &m.vertices[3 * size_t(m.triangles[3 * t + size_t(k)])];
            const float* b = &m.vertices[3 * size_t(m.triangles[3 * t + size_t((k + 1) % 3)])];
            p.target += std::sqrt(double((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                                         (a[2] - b[2]) * (a[2] - b[2])));
        }
    p.target /= 3.0 * double(m.num_triangles());
    const std::vector<float> orig = m.vertices;
    for (size_t v = 0; v < m.num_vertices(); ++v) {
        if (orig[3 * v] <= 0.85f) continue;
        for (size_t t = 0; t < m.num_triangles(); ++t) {
            const int32_t* tri = &m.triangles[3 * t];
            if (tri[0] != int32_t(v)) continue;
            for (int d = 0; d < 3; ++d)
                m.vertices[3 * v + size_t(d)] = orig[3 * v + size_t(d)] +
                                                0.8f * (orig[3 * size_t(tri[1]) + size_t(d)] - orig[3 * v + size_t(d)]);
            break;
        }
    }
    p.region = retiling_region(m, std::vector<int32_t>(m.num_triangles(), 0), p.target, 15.0);
    return p;
}

// What a local re-tiling of `region` promises (SPEC §13.12 step 4): the
// mesh stays closed, it made triangles, no sliver is left, and every
// triangle that shares no vertex with the region comes out kept, with the
// same corners at bit-identical positions in the same orientation.
void expect_local_retiling(const Mesh& m, const std::vector<uint8_t>& region, const Retiled& rt) {
    const MeshMeasures g = measure(rt.mesh);
    EXPECT_TRUE(g.closed);
    EXPECT_EQ(rt.slivers_left, 0u);
    EXPECT_GE(g.min_angle_deg, kMinRetiledAngleDeg);
    std::vector<uint8_t> near(m.num_vertices(), 0);
    for (size_t t = 0; t < m.num_triangles(); ++t)
        if (region[t])
            for (int k = 0; k < 3; ++k) near[size_t(m.triangles[3 * t + size_t(k)])] = 1;
    std::vector<int> found(m.num_triangles(), 0);
    size_t made = 0;
    for (size_t t = 0; t < rt.kept.size(); ++t) {
        if (rt.kept[t] < 0) {
            ++made;
            continue;
        }
        const size_t o = size_t(rt.kept[t]);
        ++found[o];
        // same corners, same positions, same orientation (up to rotation)
        int match = 0;
        for (int r = 0; r < 3; ++r) {
            bool all = true;
            for (int k = 0; k < 3; ++k)
                all = all && std::memcmp(&rt.mesh.vertices[3 * size_t(rt.mesh.triangles[3 * t + size_t(k)])],
                                         &m.vertices[3 * size_t(m.triangles[3 * o + size_t((k + r) % 3)])],
                                         3 * sizeof(float)) == 0;
            match += all;
        }
        EXPECT_EQ(match, 1) << "kept triangle " << t;
    }
    EXPECT_GT(made, 0u);
    for (size_t t = 0; t < m.num_triangles(); ++t) {
        const bool touches = near[size_t(m.triangles[3 * t])] || near[size_t(m.triangles[3 * t + 1])] ||
                             near[size_t(m.triangles[3 * t + 2])];
        if (!touches) {
            EXPECT_EQ(found[t], 1) << "triangle " << t << " away from the region was not kept";
        }
        EXPECT_LE(found[t], 1);
    }
}
}  // namespace

// Local re-tiling (SPEC §13.12 step 4): only the flagged region and the
// triangles along its border may change; every other triangle comes out with
// the same corners at bit-identical positions, the mesh stays closed.
TEST(ShapeStep, LocalRetilingKeepsTrianglesOutsideTheRegion) {
    const PinchedSphere p = pinched_sphere();
    size_t flagged = 0;
    for (uint8_t f : p.region) flagged += f;
    ASSERT_GT(flagged, 0u);
    ASSERT_LT(flagged, p.mesh.num_triangles() / 2);
    const Retiled rt = retile(p.mesh, std::vector<int32_t>(p.mesh.num_triangles(), 0), p.target, 3, &p.region);
    EXPECT_EQ(rt.whole_mesh_fallbacks, 0);
    expect_local_retiling(p.mesh, p.region, rt);
}

// When CGAL cannot hold the sub-mesh cut around a region (a vertex of the
// cut with two fans of triangles), the pass runs in the whole mesh, same
// region (SPEC §13.12 step 4).  No natural input was found that makes CGAL
// refuse a cut, so the test hook refuses them: the first pass alone, then
// every pass; the result keeps every promise of a local re-tiling.
TEST(ShapeStep, ARefusedCutFallsBackToTheWholeMesh) {
    const PinchedSphere p = pinched_sphere();
    const std::vector<int32_t> ts(p.mesh.num_triangles(), 0);
    refuse_retile_cuts_for_testing(1);
    const Retiled first = retile(p.mesh, ts, p.target, 3, &p.region);
    refuse_retile_cuts_for_testing(1000);
    const Retiled every = retile(p.mesh, ts, p.target, 3, &p.region);
    refuse_retile_cuts_for_testing(0);
    EXPECT_EQ(first.whole_mesh_fallbacks, 1);
    EXPECT_GE(every.whole_mesh_fallbacks, 1);
    expect_local_retiling(p.mesh, p.region, first);
    expect_local_retiling(p.mesh, p.region, every);
    // In the whole mesh every vertex goes through CGAL: the output's vertex
    // order is CGAL's (the cut keeps the unconverted vertices first, in the
    // input's order), so the fallback really ran.
    const Retiled cut = retile(p.mesh, ts, p.target, 3, &p.region);
    EXPECT_EQ(cut.whole_mesh_fallbacks, 0);
    EXPECT_NE(first.mesh.vertices, cut.mesh.vertices);
}

namespace {
// A groove: strong erosion in a band narrower than a triangle, so the
// triangles across it shear into slivers and later shape steps re-tile there.
// The shape step averages vertex displacements over 2 rings (SPEC §13.12
// step 2), which spreads such a groove until no sliver forms in 8 steps;
// the tests of local re-tiling switch the averaging off to keep it sharp.
extern "C" int32_t k_erode_band(float* surf, const GammaContext* ctx) {
    surf[3] += std::fabs(ctx->position[2]) < 0.04f ? 1.0f : 0.0f;
    return 0;
}
Config groove_config(int64_t surfels) {
    Config c = sphere_config(surfels, -0.05f, reinterpret_cast<const void*>(&k_erode_band));
    c.displacement_rings = 0;
    return c;
}
}  // namespace

// Local re-tilings happen, keep every property's integral and the surfel
// count, and are bit-identical at 1 and 2 threads.
TEST(ShapeStep, LocalRetilingConservesAndIsDeterministic) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    std::vector<float> verts[2], rows[2];
    int local[2] = {0, 0};
    for (int k = 0; k < 2; ++k) {
        Config c = groove_config(5000);
        c.threads = k + 1;
        Simulation sim(m, c);
        std::vector<float> r = sim.rows();
        for (size_t i = 0; i < sim.num_surfels(); ++i) r[5 * i + 4] = 1.0f + sim.surfels().position[3 * i + 2];
        sim.set_rows(r.data());
        auto integral = [&](int col) {
            double s = 0;
            for (size_t i = 0; i < sim.num_surfels(); ++i) s += sim.rows()[5 * i + size_t(col)];
            return s * sim.mesh().area() / double(sim.num_surfels());
        };
        for (int it = 1; it <= 8; ++it) {
            sim.trace(it);
            sim.update(it);
            const double eroded = integral(3), dye = integral(4);
            const size_t n = sim.num_surfels();
            const ShapeStats s = sim.shape(it);
            ASSERT_TRUE(s.changed);
            EXPECT_TRUE(s.geometry.closed) << "iteration " << it;
            EXPECT_EQ(sim.num_surfels(), n);
            EXPECT_NEAR(integral(3) / eroded, 1.0, 1e-5) << "iteration " << it;
            EXPECT_NEAR(integral(4) / dye, 1.0, 1e-5) << "iteration " << it;
            if (it > 1 && s.retiled) {
                EXPECT_GT(s.retiled_triangles, 0);
                local[k] += size_t(s.retiled_triangles) < s.geometry.triangles / 2;
            }
        }
        verts[k] = sim.mesh().vertices;
        rows[k] = sim.rows();
    }
    EXPECT_GT(local[0], 0) << "no local re-tiling happened";
    EXPECT_EQ(local[0], local[1]);
    ASSERT_EQ(verts[0].size(), verts[1].size());
    EXPECT_EQ(0, std::memcmp(verts[0].data(), verts[1].data(), sizeof(float) * verts[0].size()));
    ASSERT_EQ(rows[0].size(), rows[1].size());
    EXPECT_EQ(0, std::memcmp(rows[0].data(), rows[1].data(), sizeof(float) * rows[0].size()));
}

namespace {
// Uneven wear: between 0 and 1 unit per iteration, varying over a few
// wavelengths of the bunny (about 0.15 units across).
extern "C" int32_t k_erode_waves(float* surf, const GammaContext* ctx) {
    const float* p = ctx->position;
    surf[3] += 0.5f + 0.5f * std::sin(60.0f * p[0]) * std::sin(50.0f * p[1] + 1.0f) * std::cos(40.0f * p[2]);
    return 0;
}

// The smallest angle of the mesh (degrees) at a corner that is not between
// two kept edges (an edge with other than two triangles: here there are no
// seams), computed apart from the runtime's own helpers; and whether every
// directed edge appears once (consistently oriented, at most two triangles
// per edge).
struct AngleCheck {
    double min_free_deg = 180;
    size_t boundary_edges = 0;
    bool oriented_manifold = true;
};
AngleCheck check_angles(const Mesh& m) {
    std::map<std::pair<int32_t, int32_t>, int> undirected;
    std::map<std::pair<int32_t, int32_t>, int> directed;
    for (size_t t = 0; t < m.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const int32_t a = m.triangles[3 * t + size_t(k)], b = m.triangles[3 * t + size_t((k + 1) % 3)];
            ++undirected[{std::min(a, b), std::max(a, b)}];
            ++directed[{a, b}];
        }
    AngleCheck r;
    for (const auto& e : directed) r.oriented_manifold = r.oriented_manifold && e.second == 1;
    for (const auto& e : undirected) r.boundary_edges += e.second == 1;
    auto kept = [&](int32_t a, int32_t b) { return undirected[{std::min(a, b), std::max(a, b)}] != 2; };
    for (size_t t = 0; t < m.num_triangles(); ++t) {
        const int32_t* tri = &m.triangles[3 * t];
        for (int k = 0; k < 3; ++k) {
            const int32_t a = tri[k], b = tri[(k + 1) % 3], c = tri[(k + 2) % 3];
            if (kept(a, b) && kept(c, a)) continue;
            double u[3], v[3];
            for (int d = 0; d < 3; ++d) {
                u[d] = double(m.vertices[3 * size_t(b) + size_t(d)]) - m.vertices[3 * size_t(a) + size_t(d)];
                v[d] = double(m.vertices[3 * size_t(c) + size_t(d)]) - m.vertices[3 * size_t(a) + size_t(d)];
            }
            const double cx = u[1] * v[2] - u[2] * v[1], cy = u[2] * v[0] - u[0] * v[2], cz = u[0] * v[1] - u[1] * v[0];
            // in single precision through the project's atan2, as the runtime
            // measures angles (SPEC §11: no C library math), so that the two agree
            // bit for bit and the bound is checked on the same number
            const double deg = double(gm::atan2(float(std::sqrt(cx * cx + cy * cy + cz * cz)),
                                                float(u[0] * v[0] + u[1] * v[1] + u[2] * v[2]))) *
                               180.0 / M_PI;
            r.min_free_deg = std::min(r.min_free_deg, deg);
        }
    }
    return r;
}

// One iteration (trace, update, shape step) and what every shape step
// promises (SPEC §13.12): the geometry moved, no sliver is left, no angle
// below kMinRetiledAngleDeg except at a corner between two boundary edges,
// an oriented manifold, closed (no boundary edge) or with its boundary, and
// finite.  Returns whether the step re-tiled locally (fewer than half the
// triangles made).
bool well_shaped_step(Simulation& sim, int it, bool closed) {
    sim.trace(it);
    sim.update(it);
    const ShapeStats s = sim.shape(it);
    EXPECT_TRUE(s.changed) << "iteration " << it;
    EXPECT_EQ(s.slivers_left, 0) << "iteration " << it;
    const AngleCheck a = check_angles(sim.mesh());
    EXPECT_GE(a.min_free_deg, kMinRetiledAngleDeg) << "iteration " << it;
    EXPECT_DOUBLE_EQ(s.geometry.min_free_angle_deg, a.min_free_deg) << "iteration " << it;
    EXPECT_TRUE(a.oriented_manifold) << "iteration " << it;
    EXPECT_EQ(s.geometry.closed, closed) << "iteration " << it;
    if (closed)
        EXPECT_EQ(a.boundary_edges, 0u) << "iteration " << it;
    else
        EXPECT_GT(a.boundary_edges, 0u) << "iteration " << it;
    for (float x : sim.mesh().vertices) EXPECT_TRUE(std::isfinite(x)) << "iteration " << it;
    return it > 1 && s.retiled && size_t(s.retiled_triangles) < s.geometry.triangles / 2;
}
}  // namespace

// The angle bound holds after every shape step, local re-tilings included
// (SPEC §13.12 step 4): on a sphere worn along a groove (slivers form there
// and are re-tiled locally) every angle stays >= kMinRetiledAngleDeg and the
// sphere closed.
TEST(ShapeStep, EveryLocalRetilingKeepsTheAngleBoundOnASphere) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    Simulation sim(m, groove_config(5000));
    int local = 0;
    for (int it = 1; it <= 8; ++it) {
        local += well_shaped_step(sim, it, /*closed=*/true);
        if (::testing::Test::HasFatalFailure()) return;
    }
    EXPECT_GE(local, 2) << "the groove should need local re-tilings";
}

namespace {
// The bunny (12,000 surfels, 2 threads) worn by k_erode_waves.
Config bunny_waves_config() {
    Config c;
    c.surfels = 12000;
    c.seed = 11;
    c.row_width = 5;
    c.surface_rows = {{0, 0, 0, 0, 0}};
    c.set_update(0, addr(reinterpret_cast<const void*>(&k_erode_waves)));
    c.add_shape_rate(0, 3, -0.001f);
    c.threads = 2;
    return c;
}
}  // namespace

// The same on the Stanford bunny, a scanned surface with open boundaries
// (holes in its base) and many creases over 60° that erosion makes and
// moves: every angle except at a corner between two boundary edges stays
// >= kMinRetiledAngleDeg after every step, the boundary stays a boundary
// and the mesh an oriented manifold.
TEST(ShapeStep, EveryLocalRetilingKeepsTheAngleBoundOnTheBunny) {
    const Mesh m = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    ASSERT_GT(check_angles(m).boundary_edges, 0u);
    ASSERT_LT(check_angles(m).min_free_deg, 1.0);   // the scan's own tiling has slivers
    Simulation sim(m, bunny_waves_config());
    int local = 0;
    for (int it = 1; it <= 6; ++it) {
        local += well_shaped_step(sim, it, /*closed=*/false);
        if (::testing::Test::HasFatalFailure()) return;
    }
    EXPECT_GE(local, 2) << "later steps should re-tile locally";
}

// After a local re-tiling the scene index takes the triangle lookup's
// entries built beside the re-tiling where they hold
// (SceneIndex::build_lookup_ahead): its lookup is the one a build from
// scratch over the new mesh and surfels makes, entry for entry, and most
// triangles' entries were taken.
TEST(ShapeStep, ALocalRetilingsLookupIsTheOneBuiltFromScratch) {
    const Mesh m = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    Simulation sim(m, bunny_waves_config());
    int local = 0;
    for (int it = 1; it <= 5; ++it) {
        sim.trace(it);
        sim.update(it);
        const ShapeStats s = sim.shape(it);
        const SceneIndex& index = sim.scene_index();
        if (it == 1 || !s.retiled || size_t(s.retiled_triangles) * 2 >= s.geometry.triangles) continue;
        ++local;
        SceneIndex scratch;
        scratch.build_geometry(sim.mesh(), index.tri_surface(), index.n_surfaces(), false);
        const SurfelState& st = sim.state();
        scratch.build_surfels(st.surf.position.data(), st.surface.data(), st.size(), index.sigma(), 2);
        EXPECT_TRUE(index.same_lookup(scratch)) << "iteration " << it;
        EXPECT_GT(index.lookup_reused_triangles(), s.geometry.triangles / 2) << "iteration " << it;
    }
    EXPECT_GE(local, 2) << "later steps should re-tile locally";
}

namespace {
// The signed volume of a mesh (divergence theorem).  Of two patches with
// the same boundary at the same positions, the difference is the volume
// between them.
double signed_volume(const Mesh& x) {
    double v = 0;
    for (size_t t = 0; t < x.num_triangles(); ++t) {
        const float* a = &x.vertices[3 * size_t(x.triangles[3 * t])];
        const float* b = &x.vertices[3 * size_t(x.triangles[3 * t + 1])];
        const float* c = &x.vertices[3 * size_t(x.triangles[3 * t + 2])];
        v += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
              double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
              double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) / 6.0;
    }
    return v;
}

struct FoldPatch {
    Mesh mesh;
    std::vector<uint8_t> region;   // group fold_region
    double region_area = 0;
};

// A patch cut from a step of bench/bench_erosion.py (runtime/tests/data):
// the displaced mesh around one component of that step's re-tiling region
// (group fold_region) and 3 vertex rings around it.
FoldPatch load_fold_patch(const std::string& file, size_t region_triangles) {
    FoldPatch p;
    p.mesh = Mesh::load(std::string(GAMMA_TEST_DATA_DIR) + "/" + file);
    const auto fold = std::find(p.mesh.part_names.begin(), p.mesh.part_names.end(), "fold_region");
    EXPECT_NE(fold, p.mesh.part_names.end());
    p.region.assign(p.mesh.num_triangles(), 0);
    size_t flagged = 0;
    for (size_t t = 0; t < p.mesh.num_triangles(); ++t) {
        p.region[t] = p.mesh.group_id[t] == int32_t(fold - p.mesh.part_names.begin());
        flagged += p.region[t];
        if (p.region[t]) {
            const std::vector<int32_t> one(&p.mesh.triangles[3 * t], &p.mesh.triangles[3 * t] + 3);
            p.region_area += Mesh::from_arrays(p.mesh.vertices.data(), p.mesh.num_vertices(), one.data(), 1).area();
        }
    }
    EXPECT_EQ(flagged, region_triangles);
    return p;
}

// A local re-tiling of the patch's region (`target`: the bench's target
// edge length in that step) leaves no angle below kMinRetiledAngleDeg, the
// patch an oriented manifold with a boundary, triangles made
// and most of the rings around kept, the same at a second call.  Returns
// the volume it added (the change of the signed volume).
double expect_no_sliver_after_retiling(const FoldPatch& p, double target) {
    const AngleCheck before = check_angles(p.mesh);
    EXPECT_TRUE(before.oriented_manifold);
    const std::vector<int32_t> ts(p.mesh.num_triangles(), 0);
    const Retiled rt = retile(p.mesh, ts, target, 3, &p.region);
    EXPECT_EQ(rt.slivers_left, 0u);
    const AngleCheck after = check_angles(rt.mesh);
    EXPECT_GE(after.min_free_deg, kMinRetiledAngleDeg);
    EXPECT_TRUE(after.oriented_manifold);
    EXPECT_GT(after.boundary_edges, 0u);   // open stays open (its edges may be split or collapsed)
    size_t made = 0;
    for (int32_t k : rt.kept) made += k < 0;
    EXPECT_GT(made, 0u);
    EXPECT_LT(made, rt.mesh.num_triangles() / 2);
    const Retiled again = retile(p.mesh, ts, target, 3, &p.region);
    EXPECT_EQ(again.mesh.vertices, rt.mesh.vertices);
    EXPECT_EQ(again.mesh.triangles, rt.mesh.triangles);
    return signed_volume(rt.mesh) - signed_volume(p.mesh);
}
}  // namespace

// A sharp erosion fold (runtime/tests/data/erosion_fold.obj: from the
// bench's 8th iteration at 100k surfels, the step that left 2 slivers at
// 9°): faces there meet at 130-170°, and re-tiling left a spike vertex of
// valence 3 whose two neighbours share a short edge.  The edge cannot be
// collapsed (it fails the link condition), so neither CGAL's remeshing nor
// its removal of almost-degenerate faces removed the two slivers on it.
// Now the spike is flattened, and the volume between the surfaces before
// and after, spread over the region, is under 1 % of an edge length thick.
TEST(ShapeStep, ASpikeAtASharpErosionFoldLeavesNoSliver) {
    const FoldPatch p = load_fold_patch("erosion_fold.obj", 256);
    const double target = 0.0014878297603735098;
    const double added = expect_no_sliver_after_retiling(p, target);
    EXPECT_LT(std::fabs(added), 0.01 * target * p.region_area);
}

// A pit erosion dug behind a mouth narrower than an edge
// (runtime/tests/data/erosion_pit.obj: from the bench's 8th iteration at
// 50k surfels, where 2 slivers at 5° were left; left alone such pits grew
// into caves of hundreds of triangles on a neck of three edges, with
// slivers at 0.2°).  The pit's mouth is a 3-cycle of edges that keeps the
// short edge there from being collapsed; the pit (41 triangles) is closed
// by one triangle: the solid gains its volume, a few cubic edge lengths.
TEST(ShapeStep, APitBehindAMouthNarrowerThanAnEdgeIsClosedWithoutSlivers) {
    const FoldPatch p = load_fold_patch("erosion_pit.obj", 137);
    const double target = 0.002094603219640914;
    const double added = expect_no_sliver_after_retiling(p, target);
    EXPECT_GT(added, 0.0);   // closed, not cut off
    EXPECT_LT(added, 5.0 * target * target * target);
}

// The geometry summary's two angles: min_angle_deg over every corner,
// min_free_angle_deg over the corners the 15° bound applies to (not between
// two kept edges: boundary or seam).
TEST(ShapeStep, MinFreeAngleLeavesOutCornersBetweenBoundaryAndSeamEdges) {
    const float tan10 = float(std::tan(10.0 * M_PI / 180.0));
    const float v[] = {0, 0, 0, 1, 0, 0, 1, tan10, 0, 0, 1, 0};
    const int32_t one[] = {0, 1, 2};
    const MeshMeasures lone = measure(Mesh::from_arrays(v, 4, one, 1, "lone"));
    EXPECT_NEAR(lone.min_angle_deg, 10.0, 1e-4);
    EXPECT_EQ(lone.min_free_angle_deg, 180.0);   // every corner between two boundary edges
    // A second triangle on edge (2, 0): the 10° corner now has an inner edge.
    const int32_t two[] = {0, 1, 2, 0, 2, 3};
    const Mesh pair = Mesh::from_arrays(v, 4, two, 2, "pair");
    EXPECT_NEAR(measure(pair).min_free_angle_deg, 10.0, 1e-4);
    // The same edge as a seam between two surfaces: exempt again.
    EXPECT_EQ(measure(pair, {0, 1}).min_free_angle_deg, 180.0);
    EXPECT_NEAR(measure(pair, {0, 1}).min_angle_deg, 10.0, 1e-4);
}

namespace {
// A closed box centred on the origin, wound outward (12 triangles).
Mesh closed_box(float sx, float sy, float sz) {
    std::vector<float> v;
    for (int i = 0; i < 8; ++i) {
        v.push_back((i & 1 ? 0.5f : -0.5f) * sx);
        v.push_back((i & 2 ? 0.5f : -0.5f) * sy);
        v.push_back((i & 4 ? 0.5f : -0.5f) * sz);
    }
    // each face's corners around it: -x, +x, -y, +y, -z, +z
    const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    std::vector<int32_t> t;
    for (const auto& q : quads) t.insert(t.end(), {q[0], q[1], q[2], q[0], q[2], q[3]});
    return Mesh::from_arrays(v.data(), 8, t.data(), 12, "box");
}
}  // namespace

// Uniform wear must not inflate what it wears through (SPEC §13.12 steps 2
// and 3).  The bunny at 12,000 surfels (edges ~4.4 mm) loses 2 mm all over
// in every step, 16 mm in 8: more than its ears and the rims of its open
// base are thick.  A solid worn uniformly only loses area; moved along the
// raw vertex normals and without the clearance limit, the two sides of an
// ear crossed and the part turned inside out there inflated under further
// wear (measured before: the area grew from step 4 on, to 1.9x the input's
// by step 8).  Every step's area stays at or below the one before, and the
// boundary holds.
TEST(ShapeStep, UniformWearOfTheBunnyNeverGrowsItsArea) {
    const Mesh m = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    Config c = bunny_waves_config();
    c.set_update(0, addr(reinterpret_cast<const void*>(&k_erode_one)));
    c.shape_rates.clear();
    c.add_shape_rate(0, 3, -0.002f);
    Simulation sim(m, c);
    double area = m.area();
    int64_t clearance_limited = 0;
    for (int it = 1; it <= 8; ++it) {
        const ShapeStats s = run_iteration(sim, it);
        clearance_limited += s.clearance_limited;
        EXPECT_LE(s.geometry.area, area) << "iteration " << it;
        // (the 15° bound is not guaranteed, SPEC §13.12: a step that misses it says so)
        EXPECT_EQ(s.slivers_left > 0, s.geometry.min_free_angle_deg < kMinRetiledAngleDeg) << "iteration " << it;
        EXPECT_FALSE(s.geometry.closed) << "iteration " << it;
        area = s.geometry.area;
    }
    EXPECT_GT(clearance_limited, 0) << "the ears should have reached the clearance limit";
    EXPECT_LT(area, 0.8 * m.area());
}

// The move directions (SPEC §13.12 step 2) on a sphere stay radial: the
// smoothing over rings tilts a field that is already smooth by less than a
// degree and a half; with no rings they are the area-weighted normals.
TEST(ShapeStep, MoveDirectionsOfASphereAreRadial) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    const std::vector<V3> raw = move_directions(m, 0), smooth = move_directions(m, kMoveDirectionRings);
    const std::vector<V3> normals = vertex_normals(m);
    double worst_raw = 1, worst_smooth = 1;
    for (size_t v = 0; v < m.num_vertices(); ++v) {
        const V3 p = normalize(V3{m.vertices[3 * v], m.vertices[3 * v + 1], m.vertices[3 * v + 2]});
        EXPECT_EQ(raw[v].x, normals[v].x);
        worst_raw = std::min(worst_raw, double(dot(raw[v], p)));
        worst_smooth = std::min(worst_smooth, double(dot(smooth[v], p)));
    }
    // measured: 0.34° (raw normals) and 0.88° (smoothed: the plain average
    // over the ring leans a little towards the side with more neighbours)
    EXPECT_GT(worst_raw, std::cos(0.5 * M_PI / 180.0));
    EXPECT_GT(worst_smooth, std::cos(1.5 * M_PI / 180.0));

    // A sphere rough at the edge's own scale (each vertex's radius off by up
    // to ±0.3 edge): raw normals scatter by tens of degrees, the smoothed
    // directions stay near radial -- what keeps moves from folding it.
    Mesh rough = m;
    const double edge = 1.1 / 16.0;  // icosphere(4) of radius 1
    for (size_t v = 0; v < rough.num_vertices(); ++v) {
        const uint32_t h = uint32_t(v) * 2654435761u;
        const double r = 1.0 + 0.3 * edge * (double(h >> 8) / double(1u << 24) * 2.0 - 1.0);
        for (int k = 0; k < 3; ++k) rough.vertices[3 * v + size_t(k)] *= float(r);
    }
    const std::vector<V3> rough_raw = move_directions(rough, 0),
                          rough_smooth = move_directions(rough, kMoveDirectionRings);
    double raw_sq = 0, smooth_sq = 0;
    for (size_t v = 0; v < rough.num_vertices(); ++v) {
        const V3 p = normalize(V3{rough.vertices[3 * v], rough.vertices[3 * v + 1], rough.vertices[3 * v + 2]});
        const double a_raw = std::acos(std::min(1.0, double(dot(rough_raw[v], p))));
        const double a_smooth = std::acos(std::min(1.0, double(dot(rough_smooth[v], p))));
        raw_sq += a_raw * a_raw;
        smooth_sq += a_smooth * a_smooth;
    }
    const double raw_rms = std::sqrt(raw_sq / double(rough.num_vertices()));
    const double smooth_rms = std::sqrt(smooth_sq / double(rough.num_vertices()));
    EXPECT_GT(raw_rms, 5.0 * M_PI / 180.0);
    EXPECT_LT(smooth_rms, 0.3 * raw_rms);
}

// The displacement averaging (SPEC §13.12 step 2) keeps a uniform field
// exactly uniform (a sphere worn evenly stays a sphere) and damps a field
// that varies from vertex to vertex (hit noise, pits finer than the mesh).
TEST(ShapeStep, AveragingOverRingsKeepsAUniformFieldAndDampsNoise) {
    const Mesh m = gamma_test::icosphere(4, 1.0f);
    std::vector<float> uniform(m.num_vertices(), -0.0123f);
    average_over_rings(m, uniform, 2);
    for (float x : uniform) ASSERT_EQ(x, -0.0123f);
    std::vector<float> noise(m.num_vertices());
    uint64_t state = 7;
    for (float& x : noise) {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        x = float(int64_t(state >> 33) % 2001 - 1000) * 1e-3f;   // uniform in [-1, 1]
    }
    auto rms = [](const std::vector<float>& v) {
        double s = 0;
        for (float x : v) s += double(x) * x;
        return std::sqrt(s / double(v.size()));
    };
    const double before = rms(noise);
    average_over_rings(m, noise, 2);
    // two means over ~7 vertices each: independent noise drops to about a quarter (measured 0.256)
    EXPECT_LT(rms(noise), 0.35 * before);
    std::vector<float> same = noise;
    average_over_rings(m, same, 0);
    EXPECT_EQ(same, noise);
}

// The clearance limit alone (SPEC §13.12 step 3): a slab 0.06 thick worn by
// 0.01 per step from both sides thins to about the target edge length and
// no further; its faces never cross (it stays at least half a target edge
// thick over its 1 m² faces) and it stays closed.
TEST(ShapeStep, ASlabWornFromBothSidesKeepsOneEdgeOfThickness) {
    const Mesh m = closed_box(1.0f, 1.0f, 0.06f);
    ASSERT_GT(measure(m).volume, 0.0);   // outward-wound
    Simulation sim(m, sphere_config(6000, -0.01f, reinterpret_cast<const void*>(&k_erode_one)));
    int64_t limited = 0;
    double target = 0;
    for (int it = 1; it <= 6; ++it) {
        const ShapeStats s = run_iteration(sim, it);
        limited += s.clearance_limited;
        target = 2.0 * std::sqrt(s.geometry.area / 6000.0);
        ASSERT_TRUE(s.geometry.closed) << "iteration " << it;
        EXPECT_GT(s.geometry.volume, 0.5 * target) << "iteration " << it;   // over the 1 m² faces
    }
    EXPECT_GT(limited, 0);
    // thinner than it was, by about the 0.06 - target the limit allows
    EXPECT_LT(measure(sim.mesh()).volume, 0.9 * measure(m).volume);
}

// The clearance limit (its rays and the neighbour rule) gives the same mesh
// and rows at 1 and 2 threads, on a slab whose two faces stop each other
// (the sphere tests' rays are far too short to hit anything).
TEST(ShapeStep, ClearanceLimitedWearIsTheSameAtOneAndTwoThreads) {
    const Mesh m = closed_box(1.0f, 1.0f, 0.06f);
    std::vector<float> verts[2], rows[2];
    int64_t limited[2] = {0, 0};
    for (int k = 0; k < 2; ++k) {
        Config c = sphere_config(6000, -0.01f, reinterpret_cast<const void*>(&k_erode_x));
        c.threads = k + 1;
        Simulation sim(m, c);
        for (int it = 1; it <= 4; ++it) limited[k] += run_iteration(sim, it).clearance_limited;
        verts[k] = sim.mesh().vertices;
        rows[k] = sim.rows();
    }
    EXPECT_GT(limited[0], 0);
    EXPECT_EQ(limited[0], limited[1]);
    ASSERT_EQ(verts[0].size(), verts[1].size());
    EXPECT_EQ(0, std::memcmp(verts[0].data(), verts[1].data(), sizeof(float) * verts[0].size()));
    ASSERT_EQ(rows[0].size(), rows[1].size());
    EXPECT_EQ(0, std::memcmp(rows[0].data(), rows[1].data(), sizeof(float) * rows[0].size()));
}
