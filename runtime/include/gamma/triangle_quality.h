// Triangle shape tests shared by the shape step (which triangles need
// re-tiling) and the re-tiling itself (which slivers it must still remove):
// one angle test, in double precision, and the "kept" edges whose corners no
// re-tiling can widen (SPEC §13.12).  Header-only so that remesh.cpp (CGAL)
// and shape_step.cpp use the same arithmetic.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"
#include "gamma/gmath.h"

namespace gammart {

// cos(min_deg): a corner whose cosine is above it has an angle below min_deg.
inline double cos_of_deg(double min_deg) { return gm::cos(float(min_deg * 3.14159265358979323846 / 180.0)); }

// True when the angle at corner a of triangle (a, b, c) is below the angle
// whose cosine is cos_max, or the corner is degenerate (a zero-length edge).
inline bool corner_below(const double* a, const double* b, const double* c, double cos_max) {
    const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double uu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2], vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    const double uv = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    return !(uu > 0 && vv > 0) || uv > cos_max * std::sqrt(uu * vv);
}

// The corners of triangle t in double: p[k] is the position of corner k.
inline void triangle_corners(const Mesh& mesh, size_t t, double p[3][3]) {
    for (int k = 0; k < 3; ++k)
        for (int d = 0; d < 3; ++d)
            p[k][d] = double(mesh.vertices[3 * size_t(mesh.triangles[3 * t + size_t(k)]) + size_t(d)]);
}

// Per triangle edge slot 3t + k (the edge from corner k to corner k + 1):
// 1 when re-tiling keeps the edge as a polyline that cannot be flipped away:
// an open boundary (one triangle), a non-manifold edge (more than two), or a
// seam between two surfaces (tri_surface differs).
inline std::vector<uint8_t> kept_edge_slots(const Mesh& mesh, const std::vector<int32_t>& tri_surface) {
    const size_t m = mesh.num_triangles();
    struct Slot {
        uint64_t key;
        uint32_t slot;
    };
    std::vector<Slot> s(3 * m);
    for (size_t t = 0; t < m; ++t)
        for (size_t k = 0; k < 3; ++k) {
            const uint32_t a = uint32_t(mesh.triangles[3 * t + k]), b = uint32_t(mesh.triangles[3 * t + (k + 1) % 3]);
            s[3 * t + k] = {uint64_t(std::min(a, b)) << 32 | std::max(a, b), uint32_t(3 * t + k)};
        }
    std::sort(s.begin(), s.end(), [](const Slot& x, const Slot& y) { return x.key != y.key ? x.key < y.key : x.slot < y.slot; });
    std::vector<uint8_t> kept(3 * m, 0);
    for (size_t i = 0; i < s.size();) {
        size_t j = i + 1;
        while (j < s.size() && s[j].key == s[i].key) ++j;
        bool keep = j - i != 2;
        if (!keep && !tri_surface.empty()) keep = tri_surface[s[i].slot / 3] != tri_surface[s[i + 1].slot / 3];
        for (size_t q = i; q < j; ++q) kept[s[q].slot] = keep;
        i = j;
    }
    return kept;
}

// True when the triangle with corners p has an angle below the one whose
// cosine is cos_max at a corner that is not between two kept edges (`kept`:
// the triangle's three kept_edge_slots).  A corner between two kept edges
// is the input's own (a boundary or seam turning sharply): no re-tiling can
// widen it, so it does not count.
inline bool is_sliver_triangle(const double p[3][3], const uint8_t kept[3], double cos_max) {
    for (size_t k = 0; k < 3; ++k)
        if (corner_below(p[k], p[(k + 1) % 3], p[(k + 2) % 3], cos_max) && !(kept[k] && kept[(k + 2) % 3]))
            return true;
    return false;
}

}  // namespace gammart
