// Per-surfel accessibility, curvature and texture coordinates (see
// gamma/surfel_measures.h).
#include "gamma/surfel_measures.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <utility>

#include "gamma/float_points.h"
#include "gamma/philox.h"
#include "gamma/sampling.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

V3 at(const float* a, size_t i) { return {a[3 * i], a[3 * i + 1], a[3 * i + 2]}; }

float accessibility_of(const SceneIndex& index, V3 p, V3 n, float length, float eps, uint64_t seed, size_t i) {
    PhiloxStream rng(seed, kAccessibilityIteration, uint64_t(i));
    const V3 o = p + n * eps;
    int open = 0;
    for (int a = 0; a < kAccessibilityStrata; ++a)
        for (int b = 0; b < kAccessibilityStrata; ++b) {
            const float u = (float(a) + rng.next()) / float(kAccessibilityStrata);
            const float v = (float(b) + rng.next()) / float(kAccessibilityStrata);
            if (!index.occluded(o, cosine_hemisphere(n, u, v), eps, length)) ++open;
        }
    return float(open) / float(kAccessibilityRays);
}

// Solves the symmetric 6x6 system A x = b by Gaussian elimination with
// partial pivoting; false if it is singular.
bool solve6(std::array<std::array<double, 7>, 6>& m, std::array<double, 6>& x) {
    for (int c = 0; c < 6; ++c) {
        int best = c;
        for (int r = c + 1; r < 6; ++r)
            if (std::fabs(m[size_t(r)][size_t(c)]) > std::fabs(m[size_t(best)][size_t(c)])) best = r;
        if (std::fabs(m[size_t(best)][size_t(c)]) < 1e-300) return false;
        std::swap(m[size_t(c)], m[size_t(best)]);
        for (int r = c + 1; r < 6; ++r) {
            const double f = m[size_t(r)][size_t(c)] / m[size_t(c)][size_t(c)];
            for (int k = c; k < 7; ++k) m[size_t(r)][size_t(k)] -= f * m[size_t(c)][size_t(k)];
        }
    }
    for (int r = 5; r >= 0; --r) {
        double s = m[size_t(r)][6];
        for (int k = r + 1; k < 6; ++k) s -= m[size_t(r)][size_t(k)] * x[size_t(k)];
        x[size_t(r)] = s / m[size_t(r)][size_t(r)];
    }
    return true;
}

// Mean curvature at surfel i: h(u, v) = a u^2 + b uv + c v^2 + d u + e v + f
// fitted by least squares to the neighbours' heights above the surfel's
// tangent plane (u, v along it, h along the normal), then the mean curvature
// of that graph at the origin, its sign turned so that a surface bending away
// from the normal (convex) is positive.
float curvature_of(const FloatPointsKdTree& tree, const float* pos, const float* nrm, size_t i, float radius,
                   std::vector<std::pair<uint32_t, float>>& found) {
    const V3 p = at(pos, i), n = at(nrm, i);
    V3 t, s;
    onb(n, t, s);
    found.clear();
    nanoflann::SearchParams params;
    params.sorted = false;
    const float q[3] = {p.x, p.y, p.z};
    tree.radiusSearch(q, radius * radius, found, params);
    // in index order, so the sums do not depend on the tree's traversal
    std::sort(found.begin(), found.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    std::array<std::array<double, 7>, 6> m{};
    int used = 0;
    for (const auto& [j, d2] : found) {
        if (size_t(j) == i) continue;
        if (dot(n, at(nrm, j)) < kCurvatureMinNormalDot) continue;
        const V3 d = at(pos, j) - p;
        const double u = dot(d, t), v = dot(d, s), h = dot(d, n);
        const double row[6] = {u * u, u * v, v * v, u, v, 1.0};
        for (int r = 0; r < 6; ++r) {
            for (int c = 0; c < 6; ++c) m[size_t(r)][size_t(c)] += row[r] * row[c];
            m[size_t(r)][6] += row[r] * h;
        }
        ++used;
    }
    std::array<double, 6> x{};
    if (used < 6 || !solve6(m, x)) return 0.0f;
    const double fuu = 2 * x[0], fuv = x[1], fvv = 2 * x[2], fu = x[3], fv = x[4];
    const double g = 1 + fu * fu + fv * fv;
    const double h = ((1 + fv * fv) * fuu - 2 * fu * fv * fuv + (1 + fu * fu) * fvv) / (2 * g * std::sqrt(g));
    return float(-h);
}

}  // namespace

SurfelMeasures measure_surfels(const MeasureRequest& want, const Mesh& mesh, const SceneIndex& index,
                               const SurfelSet& surf, float ao_length, uint64_t seed, int threads) {
    SurfelMeasures out;
    const size_t n = surf.triangle.size();
    const float* pos = surf.position.data();
    const float* nrm = surf.normal.data();
    if (want.accessibility) out.accessibility.assign(n, 0.0f);
    if (want.accessibility) out.accessibility_back.assign(n, 0.0f);
    if (want.curvature) out.curvature.assign(n, 0.0f);
    if (want.uv) out.uv.assign(2 * n, 0.0f);
    if (n == 0) return out;
    const float spacing = float(std::sqrt(mesh.area() / double(n)));
    const float eps = 1e-5f * (2.0f * ao_length);   // the tracer's ray offset (1e-5 x diagonal)
    FloatPoints pts{pos, n};
    std::unique_ptr<FloatPointsKdTree> tree;
    if (want.curvature) {
        tree = std::make_unique<FloatPointsKdTree>(3, pts, nanoflann::KDTreeSingleIndexAdaptorParams(10));
        tree->buildIndex();
    }
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 256), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<std::pair<uint32_t, float>> found;
            for (size_t i = r.begin(); i < r.end(); ++i) {
                if (want.accessibility) {
                    out.accessibility[i] = accessibility_of(index, at(pos, i), at(nrm, i), ao_length, eps, seed, 2 * i);
                    out.accessibility_back[i] =
                        accessibility_of(index, at(pos, i), at(nrm, i) * -1.0f, ao_length, eps, seed, 2 * i + 1);
                }
                if (want.curvature)
                    out.curvature[i] = curvature_of(*tree, pos, nrm, i, kCurvatureRadiusInSpacings * spacing, found);
                if (want.uv && mesh.has_uvs()) {
                    // barycentric coordinates of the surfel in its triangle
                    const size_t tri = size_t(surf.triangle[i]);
                    const V3 a = at(mesh.vertices.data(), size_t(mesh.triangles[3 * tri]));
                    const V3 b = at(mesh.vertices.data(), size_t(mesh.triangles[3 * tri + 1]));
                    const V3 c = at(mesh.vertices.data(), size_t(mesh.triangles[3 * tri + 2]));
                    const V3 e0 = b - a, e1 = c - a, d = at(pos, i) - a;
                    const double d00 = dot(e0, e0), d01 = dot(e0, e1), d11 = dot(e1, e1);
                    const double d20 = dot(d, e0), d21 = dot(d, e1);
                    const double den = d00 * d11 - d01 * d01;
                    const double wb = den != 0 ? (d11 * d20 - d01 * d21) / den : 0.0;
                    const double wc = den != 0 ? (d00 * d21 - d01 * d20) / den : 0.0;
                    const double wa = 1.0 - wb - wc;
                    const float* uv = mesh.uvs.data() + 6 * tri;
                    for (int k = 0; k < 2; ++k)
                        out.uv[2 * i + size_t(k)] = float(wa * uv[k] + wb * uv[2 + k] + wc * uv[4 + k]);
                }
            }
        });
    });
    return out;
}

}  // namespace gammart
