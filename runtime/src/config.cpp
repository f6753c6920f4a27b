// Validation of the run-wide part of a Config (see gamma/config.h).
#include "gamma/config.h"

#include <algorithm>
#include <cmath>

#include "gamma/error.h"
#include "gamma/threads.h"
#include "gamma/vec.h"

namespace gammart {

namespace {

[[noreturn]] void fail(const std::string& m) { throw Error(m); }

void check_limits(const Config& c) {
    if (c.surfels < 1) fail("config: surfels must be at least 1 (got " + std::to_string(c.surfels) + ")");
    if (c.surfels > 400000000) fail("config: surfels too large (" + std::to_string(c.surfels) + ")");
    if (c.max_interactions < 1)
        fail("config: max_interactions must be at least 1 (got " + std::to_string(c.max_interactions) + ")");
    if (c.threads > kMaxThreads)
        fail("config: threads must be at most " + std::to_string(kMaxThreads) + " (got " +
             std::to_string(c.threads) + ")");
    if (c.row_width < GAMMA_ROW_HEADER)
        fail("config: row_width must be at least " + std::to_string(GAMMA_ROW_HEADER) + " (got " +
             std::to_string(c.row_width) + ")");
    if (!finite3(c.down)) fail("config: down has a non-finite component");
    if (!nonzero3(c.down)) fail("config: down is the zero vector");
}

void check_surface_rows(const Config& c) {
    if (c.surface_rows.empty()) fail("config: no surfaces (surface_rows is empty)");
    for (size_t s = 0; s < c.surface_rows.size(); ++s) {
        if (int(c.surface_rows[s].size()) != c.row_width)
            fail("config: surface_rows[" + std::to_string(s) + "] has " + std::to_string(c.surface_rows[s].size()) +
                 " floats, row_width is " + std::to_string(c.row_width));
        for (float x : c.surface_rows[s])
            if (!std::isfinite(x)) fail("config: surface_rows[" + std::to_string(s) + "] has a non-finite value");
    }
}

// Per-triangle surface ids (accepting the post- or pre-degenerate-removal length).
std::vector<int32_t> triangle_surfaces(const Config& c, const Mesh& mesh) {
    const size_t m = mesh.num_triangles();
    const int nsurf = int(c.surface_rows.size());
    std::vector<int32_t> tri_surface(m, 0);
    if (c.triangle_surface.empty()) return tri_surface;
    if (c.triangle_surface.size() == m) {
        tri_surface = c.triangle_surface;
    } else if (c.triangle_surface.size() == mesh.input_triangles) {
        for (size_t t = 0; t < m; ++t) tri_surface[t] = c.triangle_surface[size_t(mesh.original_triangle[t])];
    } else {
        fail("config: triangle_surface has " + std::to_string(c.triangle_surface.size()) + " entries, mesh has " +
             std::to_string(m) + " triangles");
    }
    for (size_t t = 0; t < m; ++t)
        if (tri_surface[t] < 0 || tri_surface[t] >= nsurf)
            fail("config: triangle " + std::to_string(t) + " has surface id " + std::to_string(tri_surface[t]) +
                 ", only " + std::to_string(nsurf) + " surfaces");
    return tri_surface;
}

void check_ton_type(const TonType& tt, size_t t) {
    const std::string at = "config: ton type " + std::to_string(t) + ": ";
    if (!(std::isfinite(tt.ks) && std::isfinite(tt.kp) && std::isfinite(tt.kf)) || tt.ks < 0 || tt.kp < 0 ||
        tt.kf < 0)
        fail(at + "motion probabilities must be finite and non-negative");
    for (float x : tt.initial_carry)
        if (!std::isfinite(x)) fail(at + "initial_carry has a non-finite value");
    if (!std::isfinite(tt.bounce_distance) || !(tt.bounce_distance > 0))
        fail(at + "bounce_distance must be positive and finite");
    if (!std::isfinite(tt.flow_step) || !(tt.flow_step > 0)) fail(at + "flow_step must be positive and finite");
    if (!(tt.drip_angle_deg >= 0 && tt.drip_angle_deg <= 90)) fail(at + "drip_angle_deg must be in [0, 90]");
}

void check_shape(const Config& c) {
    const int nsurf = int(c.surface_rows.size());
    for (size_t i = 0; i < c.shape_rates.size(); ++i) {
        const ShapeRate& r = c.shape_rates[i];
        const std::string at = "config: shape rate " + std::to_string(i) + ": ";
        if (r.surface < 0 || r.surface >= nsurf) fail(at + "surface index out of range");
        if (r.column < GAMMA_ROW_HEADER || r.column >= c.row_width) fail(at + "column must be a property column");
        if (!std::isfinite(r.metres_per_unit)) fail(at + "metres per unit must be finite");
    }
    if (c.shape_rates.empty()) return;
    if (!(c.retile_edge_factor > 0) || !std::isfinite(c.retile_edge_factor))
        fail("config: retile_edge_factor must be positive");
    if (c.retile_iterations < 1 || c.retile_iterations > 100) fail("config: retile_iterations must be in 1..100");
    if (!(c.max_step_factor > 0) || !std::isfinite(c.max_step_factor)) fail("config: max_step_factor must be positive");
    if (c.displacement_rings < 0 || c.displacement_rings > 16) fail("config: displacement_rings must be in 0..16");
}

void check_mass_property(const Config& c, const MassProperty& mp, size_t i) {
    const std::string at = "config: mass property " + std::to_string(i) + ": ";
    if (mp.column.size() != c.surface_rows.size()) fail(at + "needs one column per surface");
    for (int col : mp.column)
        if (col != -1 && (col < GAMMA_ROW_HEADER || col >= c.row_width))
            fail(at + "column must be a property column or -1");
    if (mp.carry.size() != c.ton_types.size()) fail(at + "needs one carry index per ton type");
    for (size_t t = 0; t < mp.carry.size(); ++t)
        if (mp.carry[t] < -1 || mp.carry[t] >= int(c.ton_types[t].initial_carry.size()))
            fail(at + "carry index out of range for ton type " + std::to_string(t));
}

}  // namespace

std::vector<int32_t> validate_config(const Config& c, const Mesh& mesh) {
    check_limits(c);
    check_surface_rows(c);
    std::vector<int32_t> tri_surface = triangle_surfaces(c, mesh);
    for (size_t t = 0; t < c.ton_types.size(); ++t) check_ton_type(c.ton_types[t], t);
    check_shape(c);
    for (size_t i = 0; i < c.mass_properties.size(); ++i) check_mass_property(c, c.mass_properties[i], i);
    return tri_surface;
}

size_t max_carry(const Config& c) {
    size_t n = 1;
    for (const TonType& tt : c.ton_types) n = std::max(n, tt.initial_carry.size());
    return n;
}

}  // namespace gammart
