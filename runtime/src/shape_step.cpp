// The shape step (see gamma/shape_step.h).
#include "gamma/shape_step.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "gamma/error.h"
#include "gamma/kernel_table.h"
#include "gamma/render.h"
#include "gamma/splat.h"
#include "gamma/surfels.h"
#include "gamma/threads.h"
#include "gamma/triangle_quality.h"

namespace gammart {

std::vector<float> surfel_displacement(const Config& c, const SurfelState& state, const std::vector<float>& before,
                                       int64_t& nonfinite) {
    const size_t n = state.size();
    const size_t W = size_t(state.width);
    std::vector<float> d(n, 0.0f);
    for (size_t i = 0; i < n; ++i) {
        double acc = 0;
        for (const ShapeRate& r : c.shape_rates) {
            if (r.surface != state.surface[i]) continue;
            const size_t k = i * W + size_t(r.column);
            acc += double(r.metres_per_unit) * (double(state.rows[k]) - double(before[k]));
        }
        if (!std::isfinite(acc)) {
            ++nonfinite;
            acc = 0;
        }
        d[i] = float(acc);
    }
    return d;
}

std::vector<V3> vertex_normals(const Mesh& mesh) {
    std::vector<V3> n(mesh.num_vertices(), V3{0, 0, 0});
    for (size_t t = 0; t < mesh.num_triangles(); ++t) {
        const int32_t* tri = &mesh.triangles[3 * t];
        const V3 a = {mesh.vertices[3 * size_t(tri[0])], mesh.vertices[3 * size_t(tri[0]) + 1],
                      mesh.vertices[3 * size_t(tri[0]) + 2]};
        const V3 b = {mesh.vertices[3 * size_t(tri[1])], mesh.vertices[3 * size_t(tri[1]) + 1],
                      mesh.vertices[3 * size_t(tri[1]) + 2]};
        const V3 c = {mesh.vertices[3 * size_t(tri[2])], mesh.vertices[3 * size_t(tri[2]) + 1],
                      mesh.vertices[3 * size_t(tri[2]) + 2]};
        const V3 fn = cross(b - a, c - a);  // length = 2 x area: area-weighted
        for (int k = 0; k < 3; ++k) n[size_t(tri[k])] = n[size_t(tri[k])] + fn;
    }
    for (V3& v : n) v = normalize(v);
    return n;
}

namespace {

// Each vertex's edge neighbours, sorted, as compressed rows: row v is
// nb[offset[v] .. end[v]).
struct EdgeNeighbours {
    std::vector<uint32_t> offset, end, nb;
};

EdgeNeighbours edge_neighbours(const Mesh& mesh) {
    const size_t nv = mesh.num_vertices();
    EdgeNeighbours e;
    e.offset.assign(nv + 1, 0);
    for (int32_t x : mesh.triangles) e.offset[size_t(x) + 1] += 2;   // each corner: two of its triangle's edges
    for (size_t v = 0; v < nv; ++v) e.offset[v + 1] += e.offset[v];
    std::vector<uint32_t> fill(e.offset.begin(), e.offset.end() - 1);
    e.nb.resize(e.offset[nv]);
    for (size_t t = 0; t < mesh.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const uint32_t a = uint32_t(mesh.triangles[3 * t + size_t(k)]);
            const uint32_t b = uint32_t(mesh.triangles[3 * t + size_t(k + 1) % 3]);
            e.nb[fill[a]++] = b;
            e.nb[fill[b]++] = a;
        }
    e.end.assign(nv, 0);
    for (size_t v = 0; v < nv; ++v) {
        auto first = e.nb.begin() + e.offset[v], last = e.nb.begin() + e.offset[v + 1];
        std::sort(first, last);
        e.end[v] = uint32_t(std::unique(first, last) - e.nb.begin());
    }
    return e;
}

// `passes` Jacobi passes over the vertices: every value replaced by
// combine(own value, its neighbours' values) computed from the previous pass.
template <class T, class Combine>
void ring_passes(const EdgeNeighbours& e, std::vector<T>& values, int passes, int threads, Combine combine) {
    const size_t nv = values.size();
    std::vector<T> next(nv);
    for (int pass = 0; pass < passes; ++pass) {
        run_with_threads(threads, [&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, 4096), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t v = r.begin(); v < r.end(); ++v)
                    next[v] = combine(values, v, e.nb.data() + e.offset[v], e.nb.data() + e.end[v]);
            });
        });
        values.swap(next);
    }
}

V3 summed_direction(const std::vector<V3>& dir, size_t v, const uint32_t* first, const uint32_t* last) {
    V3 acc = dir[v];
    for (const uint32_t* u = first; u != last; ++u) acc = acc + dir[*u];
    return normalize(acc);
}

// The plain mean in double: n equal floats give that float back exactly.
float mean_value(const std::vector<float>& d, size_t v, const uint32_t* first, const uint32_t* last) {
    double acc = d[v];
    for (const uint32_t* u = first; u != last; ++u) acc += d[*u];
    return float(acc / double(1 + (last - first)));
}

}  // namespace

std::vector<V3> move_directions(const Mesh& mesh, int rings, int threads) {
    std::vector<V3> dir = vertex_normals(mesh);
    if (rings <= 0) return dir;
    ring_passes(edge_neighbours(mesh), dir, rings, threads, summed_direction);
    return dir;
}

void average_over_rings(const Mesh& mesh, std::vector<float>& dv, int rings, int threads) {
    if (rings <= 0) return;
    ring_passes(edge_neighbours(mesh), dv, rings, threads, mean_value);
}

int64_t limit_to_clearance(const SceneIndex& index, const Mesh& mesh, const std::vector<V3>& dir,
                           double min_gap, std::vector<float>& dv, int threads) {
    const size_t nv = mesh.num_vertices();
    std::vector<double> room(nv, std::numeric_limits<double>::infinity());
    // The ray starts at the vertex itself: the triangles around it are met
    // at t = 0 only, which tnear leaves out.
    const float tnear = float(1e-3 * min_gap);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, 1024), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t v = r.begin(); v < r.end(); ++v) {
                if (dv[v] == 0.0f) continue;
                const V3 p = {mesh.vertices[3 * v], mesh.vertices[3 * v + 1], mesh.vertices[3 * v + 2]};
                // only a surface nearer than min_gap + 2|dv| can cut the move: the ray stops there
                RTCRayHit rh;
                index.cast(rh, p, dv[v] < 0 ? dir[v] * -1.0f : dir[v], tnear,
                           float(min_gap + 2.0 * std::fabs(double(dv[v]))));
                if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
                room[v] = std::max(0.0, 0.5 * (double(rh.ray.tfar) - min_gap));
            }
        });
    });
    // A vertex has no more room than its edge neighbours moving the same way:
    // at the rim of a part worn to one edge's thickness the rim's own ray runs
    // along the part, and the rim moving on between its stopped sides would
    // fold the surface there.
    std::vector<double> least = room;
    for (size_t t = 0; t < mesh.num_triangles(); ++t)
        for (int k = 0; k < 3; ++k) {
            const size_t a = size_t(mesh.triangles[3 * t + size_t(k)]);
            const size_t b = size_t(mesh.triangles[3 * t + size_t(k + 1) % 3]);
            if ((dv[a] < 0) != (dv[b] < 0)) continue;
            least[a] = std::min(least[a], room[b]);
            least[b] = std::min(least[b], room[a]);
        }
    int64_t n = 0;
    for (size_t v = 0; v < nv; ++v)
        if (std::fabs(double(dv[v])) > least[v]) {
            dv[v] = float(std::copysign(least[v], double(dv[v])));
            ++n;
        }
    return n;
}

void transfer_rows(const SurfelState& old_state, double old_area, const SceneIndex& old_index,
                   SurfelState& state, double new_area, const SceneIndex& index, int threads) {
    constexpr size_t K = kSmoothingNeighbours;
    const size_t n_old = old_state.size(), n_new = state.size();
    const size_t W = size_t(state.width);
    // Neighbours (parallel queries, stored), then a sequential scatter.
    std::vector<uint32_t> nb_idx(n_old * K);
    std::vector<double> nb_w(n_old * K);
    std::vector<uint8_t> nb_count(n_old);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n_old, 2048), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i < r.end(); ++i)
                nb_count[i] = uint8_t(index.smooth(old_state.surface[i], &old_state.surf.position[3 * i],
                                                   &nb_idx[i * K], &nb_w[i * K]));
        });
    });
    const double a_old = old_area / double(n_old), a_new = new_area / double(n_new);
    std::vector<double> amount(n_new * W, 0.0);
    for (size_t i = 0; i < n_old; ++i) {
        const float* row = old_state.row(i);
        for (size_t j = 0; j < nb_count[i]; ++j) {
            double* dst = &amount[size_t(nb_idx[i * K + j]) * W];
            const double w = nb_w[i * K + j] * a_old;
            for (size_t c = GAMMA_ROW_HEADER; c < W; ++c) dst[c] += w * double(row[c]);
        }
    }
    for (size_t j = 0; j < n_new; ++j) {
        float* row = state.row(j);
        const uint32_t src = old_index.nearest_of(state.surface[j], &state.surf.position[3 * j]);
        std::memcpy(row, old_state.row(src), sizeof(float) * GAMMA_ROW_HEADER);
        for (size_t c = GAMMA_ROW_HEADER; c < W; ++c) row[c] = float(amount[j * W + c] / a_new);
    }
}

void ShapeStep::begin_iteration(const SurfelState& state) {
    if (active()) before_ = state.rows;
}

namespace {

// Refuses a surface that has triangles but no surfel (see Simulation).
void require_surfels(const SceneIndex& index, int iteration) {
    const std::vector<size_t> per = index.surfels_per_surface();
    std::vector<size_t> triangles(per.size(), 0);
    for (int32_t s : index.tri_surface()) ++triangles[size_t(s)];
    for (size_t s = 0; s < per.size(); ++s)
        if (triangles[s] > 0 && per[s] == 0)
            throw Error("shape: after re-tiling in iteration " + std::to_string(iteration) + ", surface " +
                        std::to_string(s) + " has " + std::to_string(triangles[s]) +
                        " triangle(s) but received no surfel; raise the surfel count");
}

V3 vertex(const Mesh& m, size_t i) { return {m.vertices[3 * i], m.vertices[3 * i + 1], m.vertices[3 * i + 2]}; }

// Surfels carried by their triangles from `before` to `after` (same
// connectivity): the same barycentric coordinates, the new face normal.
void carry_surfels(const Mesh& before, const Mesh& after, SurfelSet& surf, int threads) {
    const size_t n = surf.triangle.size();
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const int32_t* tri = &before.triangles[3 * size_t(surf.triangle[i])];
                double a[3], b[3], c[3], p[3];
                for (int k = 0; k < 3; ++k) {
                    a[k] = before.vertices[3 * size_t(tri[0]) + size_t(k)];
                    b[k] = before.vertices[3 * size_t(tri[1]) + size_t(k)];
                    c[k] = before.vertices[3 * size_t(tri[2]) + size_t(k)];
                    p[k] = surf.position[3 * i + size_t(k)];
                }
                // barycentric coordinates of p (in the triangle's plane) by the usual dot products
                double e1[3], e2[3], d[3];
                for (int k = 0; k < 3; ++k) { e1[k] = b[k] - a[k]; e2[k] = c[k] - a[k]; d[k] = p[k] - a[k]; }
                auto dotd = [](const double* x, const double* y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; };
                const double d11 = dotd(e1, e1), d12 = dotd(e1, e2), d22 = dotd(e2, e2);
                const double dp1 = dotd(d, e1), dp2 = dotd(d, e2), den = d11 * d22 - d12 * d12;
                const double v = den > 0 ? (d22 * dp1 - d12 * dp2) / den : 0.0;
                const double w = den > 0 ? (d11 * dp2 - d12 * dp1) / den : 0.0;
                const double u = 1.0 - v - w;
                double na[3], nb[3], nc[3];
                for (int k = 0; k < 3; ++k) {
                    na[k] = after.vertices[3 * size_t(tri[0]) + size_t(k)];
                    nb[k] = after.vertices[3 * size_t(tri[1]) + size_t(k)];
                    nc[k] = after.vertices[3 * size_t(tri[2]) + size_t(k)];
                    surf.position[3 * i + size_t(k)] = float(u * na[k] + v * nb[k] + w * nc[k]);
                }
                double f1[3], f2[3];
                for (int k = 0; k < 3; ++k) { f1[k] = nb[k] - na[k]; f2[k] = nc[k] - na[k]; }
                const double cr[3] = {f1[1] * f2[2] - f1[2] * f2[1], f1[2] * f2[0] - f1[0] * f2[2],
                                      f1[0] * f2[1] - f1[1] * f2[0]};
                const double len = std::sqrt(dotd(cr, cr));
                for (int k = 0; k < 3; ++k) surf.normal[3 * i + size_t(k)] = float(len > 0 ? cr[k] / len : 0.0);
            }
        });
    });
}

}  // namespace

std::vector<uint8_t> triangle_defects(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target,
                                      double min_deg) {
    const size_t m = mesh.num_triangles();
    const double lo2 = kRegionShortEdge * kRegionShortEdge * target * target;
    const double hi2 = kRegionLongEdge * kRegionLongEdge * target * target;
    const double cos_max = cos_of_deg(min_deg);
    const std::vector<uint8_t> kept = kept_edge_slots(mesh, tri_surface);
    std::vector<uint8_t> defects(m, 0);
    for (size_t t = 0; t < m; ++t) {
        double p[3][3];
        triangle_corners(mesh, t, p);
        if (is_sliver_triangle(p, &kept[3 * t], cos_max)) defects[t] |= kSliverDefect;
        for (int k = 0; k < 3; ++k) {
            const double* a = p[k];
            const double* b = p[(k + 1) % 3];
            const double uu = (b[0] - a[0]) * (b[0] - a[0]) + (b[1] - a[1]) * (b[1] - a[1]) + (b[2] - a[2]) * (b[2] - a[2]);
            if (uu < lo2 || uu > hi2) defects[t] |= kEdgeDefect;
        }
    }
    return defects;
}

std::vector<uint8_t> retiling_region(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target,
                                     double min_deg) {
    return retiling_region(mesh, triangle_defects(mesh, tri_surface, target, min_deg));
}

std::vector<uint8_t> retiling_region(const Mesh& mesh, const std::vector<uint8_t>& defects) {
    const size_t m = mesh.num_triangles();
    // the defective triangles and those within kRegionRings vertex rings of one (room to fix them)
    std::vector<uint8_t> region(m, 0);
    for (size_t t = 0; t < m; ++t) region[t] = defects[t] != 0;
    grow_by_rings(mesh, region, kRegionRings);
    return region;
}

namespace {

// No triangle may flip: the moves of the vertices of a triangle whose normal
// would turn by more than 90 degrees are shortened (halving, up to 8 times,
// then 0).  Marks the vertices limited.
void limit_flips(const Mesh& mesh, const std::vector<V3>& direction, std::vector<float>& dv,
                 std::vector<uint8_t>& limited) {
    const size_t m = mesh.num_triangles();
    std::vector<V3> face_normal(m);
    for (size_t t = 0; t < m; ++t) {
        const int32_t* tri = &mesh.triangles[3 * t];
        face_normal[t] = cross(vertex(mesh, size_t(tri[1])) - vertex(mesh, size_t(tri[0])),
                               vertex(mesh, size_t(tri[2])) - vertex(mesh, size_t(tri[0])));
    }
    auto moved = [&](size_t v) { return vertex(mesh, v) + direction[v] * dv[v]; };
    for (int round = 0; round <= 8; ++round) {
        bool flipped = false;
        for (size_t t = 0; t < m; ++t) {
            const int32_t* tri = &mesh.triangles[3 * t];
            const V3 a = moved(size_t(tri[0])), b = moved(size_t(tri[1])), cc = moved(size_t(tri[2]));
            if (dot(cross(b - a, cc - a), face_normal[t]) > 0) continue;
            flipped = true;
            for (int k = 0; k < 3; ++k) {
                const size_t v = size_t(tri[k]);
                dv[v] = round < 8 ? 0.5f * dv[v] : 0.0f;
                limited[v] = 1;
            }
        }
        if (!flipped) break;
    }
}

// How far each vertex moves along `direction` (SPEC §13.12 steps 1-3): the
// surfels' displacements smoothed to the vertices, averaged over rings,
// clamped to max_step, limited by the clearance and so that no triangle
// flips; the counters in st.
std::vector<float> vertex_displacements(const Config& c, const Mesh& mesh, const SceneIndex& index,
                                        const std::vector<float>& d_surfel, const std::vector<V3>& direction,
                                        double target, double max_step, ShapeStats& st) {
    // Surfel -> vertex: the smoothing of the renders over all surfels
    // (Gaussian, k = 8), along the vertex normal smoothed over a few rings.
    const size_t nv = mesh.num_vertices();
    std::vector<float> dv(nv, 0.0f);
    run_with_threads(c.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, 1024), [&](const tbb::blocked_range<size_t>& r) {
            uint32_t idx[kSmoothingNeighbours];
            double w[kSmoothingNeighbours];
            for (size_t v = r.begin(); v < r.end(); ++v) {
                const size_t k = index.smooth(-1, &mesh.vertices[3 * v], idx, w);
                double acc = 0;
                for (size_t j = 0; j < k; ++j) acc += w[j] * double(d_surfel[idx[j]]);
                dv[v] = float(acc);
            }
        });
    });
    // The mesh cannot follow a displacement finer than its edges (SPEC §13.12 step 2).
    average_over_rings(mesh, dv, c.displacement_rings, c.threads);
    // Vertices used by no triangle do not move.
    std::vector<uint8_t> used(nv, 0);
    for (int32_t x : mesh.triangles) used[size_t(x)] = 1;
    for (size_t v = 0; v < nv; ++v) {
        if (!used[v] || !(dot(direction[v], direction[v]) > 0)) dv[v] = 0.0f;
        if (std::fabs(double(dv[v])) > max_step) {
            dv[v] = float(std::copysign(max_step, double(dv[v])));
            ++st.clamped_vertices;
        }
    }
    // No part may thin through, no gap close (their two sides would cross,
    // and a surface turned inside out there inflates under erosion).
    st.clearance_limited = limit_to_clearance(index, mesh, direction, target, dv, c.threads);
    std::vector<uint8_t> limited(nv, 0);
    limit_flips(mesh, direction, dv, limited);
    for (size_t v = 0; v < nv; ++v) {
        st.inversion_limited += limited[v];
        if (dv[v] != 0.0f) {
            ++st.moved_vertices;
            st.max_displacement = std::max(st.max_displacement, std::fabs(double(dv[v])));
        }
    }
    return dv;
}

// The surfels ride on their triangles to the displaced mesh (no re-tiling):
// the amounts stay where they are, and the index is updated in place.
void ride(const Config& c, Mesh& mesh, Mesh&& displaced, double displaced_area, SurfelState& state,
          SceneIndex& index, ShapeStats& st) {
    auto t0 = std::chrono::steady_clock::now();
    const double old_area = mesh.area(), new_area = displaced_area;
    carry_surfels(mesh, displaced, state.surf, c.threads);
    // the integral of each property (value x area / N) is kept by scaling
    // with the change of area
    const double scale = new_area > 0 ? old_area / new_area : 1.0;
    const size_t W = size_t(state.width);
    for (size_t i = 0; i < state.size(); ++i)
        for (size_t col = GAMMA_ROW_HEADER; col < W; ++col)
            state.rows[i * W + col] = float(double(state.rows[i * W + col]) * scale);
    st.resample_seconds = seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    mesh = std::move(displaced);
    // Same triangles, same surfels: the index is updated in place (SPEC §13.12 step 6).
    index.move_vertices(mesh);
    index.move_surfels(state.surf.position.data(), float(std::sqrt(new_area / double(state.size()))), c.threads);
    st.rebuild_seconds = seconds_since(t0);  // splat, frame and measures are added below
}

// A local re-tiling of `region` with the triangle lookup of the triangles
// outside it built beside (in `ahead`, on another core), for the rebuild to
// take where it still holds (SceneIndex::build_surfels); the same lookup
// either way.  st.retile_seconds: the re-tiling's wall time from t0 less
// carry_seconds.
Retiled retile_with_lookup_ahead(const Config& c, const Mesh& displaced, double displaced_area,
                                 const std::vector<uint8_t>& region, const SurfelState& state,
                                 const SceneIndex& index, double target, int threads,
                                 std::unique_ptr<SceneIndex>& ahead, std::chrono::steady_clock::time_point t0,
                                 double carry_seconds, ShapeStats& st) {
    ahead = std::make_unique<SceneIndex>();
    const float ahead_sigma = float(std::sqrt(displaced_area / double(state.size())));
    tbb::global_control cap(tbb::global_control::max_allowed_parallelism, size_t(threads));
    tbb::task_arena arena(threads);
    tbb::task_group beside;
    // Waits for the lookup ahead on every way out (it reads this function's locals).
    struct Join {
        tbb::task_arena& arena;
        tbb::task_group& group;
        ~Join() {
            try {
                arena.execute([&] { group.wait(); });
            } catch (...) {   // only on the way out with the re-tiling's error, which goes on
            }
        }
    } join{arena, beside};
    // enqueued: a worker takes it while this thread re-tiles outside the arena
    arena.enqueue(beside.defer([&] {
        // Near the region the re-tiling and its new surfels change the entries: not built ahead.
        std::vector<uint8_t> skip = region;
        grow_by_rings(displaced, skip, kAheadSkipRings);
        ahead->build_lookup_ahead(displaced, index.tri_surface(), index.n_surfaces(), state.surf.position.data(),
                                  state.surface.data(), state.size(), ahead_sigma, skip);
    }));
    Retiled rt = retile(displaced, index.tri_surface(), target, c.retile_iterations, &region);
    st.retile_seconds = seconds_since(t0) - carry_seconds;
    const auto t1 = std::chrono::steady_clock::now();
    arena.execute([&] { beside.wait(); });
    st.rebuild_seconds += seconds_since(t1);   // what the lookup ahead took past the re-tiling
    return rt;
}

}  // namespace

ShapeStats ShapeStep::apply(int iteration, Mesh& mesh, SurfelState& state, std::unique_ptr<SceneIndex>& index,
                            SceneFrame& frame) {
    ShapeStats st;
    if (!active()) return st;
    auto t0 = std::chrono::steady_clock::now();
    const Config& c = cfg_;
    if (before_.size() != state.rows.size()) before_ = state.rows;  // no begin_iteration: no change
    const std::vector<float> d_surfel = surfel_displacement(c, state, before_, st.nonfinite_surfels);
    const double spacing = std::sqrt(mesh.area() / double(state.size()));
    const double target = double(c.retile_edge_factor) * spacing;
    const double max_step = double(c.max_step_factor) * target;

    const std::vector<V3> direction = move_directions(mesh, kMoveDirectionRings, c.threads);
    const std::vector<float> dv = vertex_displacements(c, mesh, *index, d_surfel, direction, target, max_step, st);
    auto moved = [&](size_t v) { return vertex(mesh, v) + direction[v] * dv[v]; };
    const size_t nv = mesh.num_vertices();
    st.displace_seconds = seconds_since(t0);
    if (st.moved_vertices == 0) {
        st.geometry = measure(mesh, index->tri_surface());
        return st;
    }
    st.changed = true;
    ++rebuilds_;

    // Displace and re-tile.
    t0 = std::chrono::steady_clock::now();
    Mesh displaced = mesh;
    for (size_t v = 0; v < nv; ++v) {
        const V3 p = moved(v);
        displaced.vertices[3 * v] = p.x;
        displaced.vertices[3 * v + 1] = p.y;
        displaced.vertices[3 * v + 2] = p.z;
    }
    // Re-tile only when the triangles need it (SPEC §13.12): the first time
    // (the input's own tiling), when a sliver (an angle under kSliverDeg not
    // forced by two kept edges) appeared, when the area drifted by more than
    // 10 % from the last re-tiling, or after kMaxIterationsWithoutRetiling.
    // Otherwise the vertices move and the surfels ride on their triangles.
    // Every re-tiling leaves no sliver (remesh.h), so the bound holds after
    // every shape step.
    const double displaced_area = displaced.area();
    const std::vector<uint8_t> defects = triangle_defects(displaced, index->tri_surface(), target, kSliverDeg);
    const bool has_sliver = std::any_of(defects.begin(), defects.end(), [](uint8_t d) { return d & kSliverDefect; });
    const bool first = retiled_area_ == 0;
    const bool drifted = std::fabs(displaced_area - retiled_area_) > 0.1 * retiled_area_;
    bool keep_tiling = !first && !drifted && kept_iterations_ < kMaxIterationsWithoutRetiling && !has_sliver;
    // After the first re-tiling, only the triangles that need it are re-tiled
    // (unless the area drifted: then the whole mesh); if none does, the
    // surfels ride.
    std::vector<uint8_t> region;
    std::vector<uint32_t> replaced;   // after a local re-tiling: the surfels it replaced
    if (!keep_tiling && !first && !drifted) {
        region = retiling_region(displaced, defects);
        if (std::find(region.begin(), region.end(), uint8_t(1)) == region.end()) {
            keep_tiling = true;
            kept_iterations_ = -1;  // checked now: counts again from here
            region.clear();
        }
    }
    if (keep_tiling) {
        ++kept_iterations_;
        st.retiled = false;
        st.retile_seconds = seconds_since(t0);
        ride(c, mesh, std::move(displaced), displaced_area, state, *index, st);
    } else {
        kept_iterations_ = 0;
        st.retiled = true;
        Retiled rt;
        std::unique_ptr<SceneIndex> ahead;
        if (region.empty()) {
            rt = retile(displaced, index->tri_surface(), target, c.retile_iterations, nullptr);
            st.retile_seconds = seconds_since(t0);
        } else {
            // A local re-tiling keeps most triangles and the surfels on
            // them: the surfels ride onto the displaced mesh first, and the
            // triangle lookup of the triangles outside the region is built
            // beside the re-tiling (serial CGAL work, one core), for the
            // rebuild to take where it still holds (SceneIndex::build_surfels);
            // the same lookup either way.
            auto t1 = std::chrono::steady_clock::now();
            carry_surfels(mesh, displaced, state.surf, c.threads);
            const double carry_seconds = seconds_since(t1);
            st.resample_seconds += carry_seconds;
            const int threads = resolve_threads(c.threads);
            if (threads < 2) {   // no core to spare: nothing is built ahead
                rt = retile(displaced, index->tri_surface(), target, c.retile_iterations, &region);
                st.retile_seconds = seconds_since(t0) - carry_seconds;
            } else {
                rt = retile_with_lookup_ahead(c, displaced, displaced_area, region, state, *index, target, threads,
                                              ahead, t0, carry_seconds, st);
            }
        }
        for (int32_t k : rt.kept) st.retiled_triangles += k < 0;
        if (region.empty())
            resample(iteration, rt, mesh, state, index, st);
        else
            replaced = resample_region(iteration, rt, mesh, displaced, state, index, ahead, st);
        st.slivers_left = int64_t(rt.slivers_left);
        retiled_area_ = mesh.area();
    }

    // New surfels need their own splat neighbourhoods (SPEC §13.2); the old
    // kernel's offsets no longer match and would silently switch spreading off.
    // Riding surfels keep their neighbourhoods, with weights for the new
    // distances; after a local re-tiling, so do the surfels it kept away
    // from the ones it replaced.
    t0 = std::chrono::steady_clock::now();
    run_with_threads(c.threads, [&] {
        // The mesh's measures (serial) beside the kernel: neither reads what the other writes.
        tbb::task_group beside;
        beside.run([&] { st.geometry = measure(mesh, index->tri_surface()); });
        if (keep_tiling)
            reweight_splat_kernel(state.splat, state.surf.position.data(), state.size(), index->sigma());
        else if (!region.empty())
            state.splat = update_splat_kernel(state.splat, state.surf.position.data(), state.surf.normal.data(),
                                              state.surface.data(), state.size(), index->sigma(), replaced,
                                              index->surfel_tree());
        else
            state.splat = build_splat_kernel(state.surf.position.data(), state.surf.normal.data(),
                                             state.surface.data(), state.size(), index->sigma());
        beside.wait();
    });
    frame = SceneFrame::of(mesh, c.down);
    // the moved or new surfels' accessibility, curvature and uv, as at setup (SPEC §12)
    state.measures = measure_surfels({c.measure_accessibility, c.measure_curvature, c.measure_uv}, mesh, *index,
                                     state.surf, kAoLengthFraction * frame.diag, c.seed, c.threads);
    before_ = state.rows;
    st.rebuild_seconds += seconds_since(t0);
    return st;
}

void ShapeStep::resample(int iteration, Retiled& rt, Mesh& mesh, SurfelState& state,
                         std::unique_ptr<SceneIndex>& index, ShapeStats& st) const {
    const Config& c = cfg_;
    // Re-sample surfels (a new seed per iteration) and transfer the rows.
    auto t0 = std::chrono::steady_clock::now();
    const double old_area = mesh.area(), new_area = rt.mesh.area();
    std::vector<std::vector<float>> zero_rows(size_t(index->n_surfaces()), std::vector<float>(size_t(state.width), 0));
    SurfelState fresh = SurfelState::sample(rt.mesh, rt.tri_surface, state.size(),
                                            mix64(c.seed ^ (uint64_t(uint32_t(iteration)) << 32)), zero_rows);
    st.resample_seconds = seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    auto rebuilt = std::make_unique<SceneIndex>();
    rebuilt->build_geometry(rt.mesh, rt.tri_surface, index->n_surfaces());
    rebuilt->build_surfels(fresh.surf.position.data(), fresh.surface.data(), fresh.size(),
                           float(std::sqrt(new_area / double(fresh.size()))));
    require_surfels(*rebuilt, iteration);
    st.rebuild_seconds = seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    transfer_rows(state, old_area, *index, fresh, new_area, *rebuilt, c.threads);
    st.resample_seconds += seconds_since(t0);

    mesh = std::move(rt.mesh);
    state = std::move(fresh);
    index = std::move(rebuilt);
}

std::vector<uint32_t> ShapeStep::resample_region(int iteration, Retiled& rt, Mesh& mesh, const Mesh& displaced,
                                                 SurfelState& state, std::unique_ptr<SceneIndex>& index,
                                                 std::unique_ptr<SceneIndex>& ahead, ShapeStats& st) const {
    const Config& c = cfg_;
    auto t0 = std::chrono::steady_clock::now();
    const size_t n = state.size();
    const size_t W = size_t(state.width);
    const double old_area = mesh.area(), new_area = rt.mesh.area();
    // Surfels on triangles re-tiling kept stay (on the same triangle, renumbered);
    // the others are replaced by as many new surfels on the new triangles.
    std::vector<int32_t> new_of_old(displaced.num_triangles(), -1);
    std::vector<int32_t> new_faces;
    for (size_t t = 0; t < rt.kept.size(); ++t) {
        if (rt.kept[t] >= 0)
            new_of_old[size_t(rt.kept[t])] = int32_t(t);
        else
            new_faces.push_back(int32_t(t));
    }
    std::vector<uint32_t> removed;
    for (size_t i = 0; i < n; ++i)
        if (new_of_old[size_t(state.surf.triangle[i])] < 0) removed.push_back(uint32_t(i));
    SurfelState fresh;
    fresh.width = state.width;
    fresh.surf = state.surf;
    fresh.surface = state.surface;
    fresh.rows = state.rows;
    fresh.splat = state.splat;   // the kept surfels' neighbourhoods (update_splat_kernel)
    for (size_t i = 0; i < n; ++i) {
        const int32_t t = new_of_old[size_t(state.surf.triangle[i])];
        if (t >= 0) fresh.surf.triangle[i] = t;
    }
    if (!removed.empty()) {
        if (new_faces.empty())
            throw Error("shape: re-tiling in iteration " + std::to_string(iteration) +
                        " removed triangles but made none (internal error)");
        // New surfels on the new triangles only (a sub-mesh of them), seed mixed with the iteration.
        std::vector<int32_t> sub_tris;
        std::vector<int32_t> sub_surface;
        for (int32_t t : new_faces) {
            sub_tris.insert(sub_tris.end(), &rt.mesh.triangles[3 * size_t(t)], &rt.mesh.triangles[3 * size_t(t)] + 3);
            sub_surface.push_back(rt.tri_surface[size_t(t)]);
        }
        const Mesh sub = Mesh::from_arrays(rt.mesh.vertices.data(), rt.mesh.num_vertices(), sub_tris.data(),
                                           new_faces.size(), rt.mesh.name);
        std::vector<int32_t> sub_kept_surface(sub.num_triangles());
        for (size_t k = 0; k < sub.num_triangles(); ++k)
            sub_kept_surface[k] = sub_surface[size_t(sub.original_triangle[k])];
        std::vector<std::vector<float>> zero_rows(size_t(index->n_surfaces()), std::vector<float>(W, 0));
        const SurfelState added = SurfelState::sample(
            sub, sub_kept_surface, removed.size(), mix64(c.seed ^ (uint64_t(uint32_t(iteration)) << 32)), zero_rows);
        if (added.size() != removed.size())
            throw Error("shape: re-sampling in iteration " + std::to_string(iteration) + " made " +
                        std::to_string(added.size()) + " surfels for " + std::to_string(removed.size()) +
                        " (internal error)");
        for (size_t j = 0; j < removed.size(); ++j) {
            const size_t i = removed[j];
            for (int d = 0; d < 3; ++d) {
                fresh.surf.position[3 * i + size_t(d)] = added.surf.position[3 * j + size_t(d)];
                fresh.surf.normal[3 * i + size_t(d)] = added.surf.normal[3 * j + size_t(d)];
            }
            fresh.surf.triangle[i] = new_faces[size_t(sub.original_triangle[size_t(added.surf.triangle[j])])];
            fresh.surface[i] = added.surface[j];
            // gamma-reflectance from the nearest old surfel of the same surface, properties from the transfer
            const uint32_t src = index->nearest_of(fresh.surface[i], &fresh.surf.position[3 * i]);
            std::memcpy(fresh.row(i), state.row(src), sizeof(float) * GAMMA_ROW_HEADER);
            std::fill(fresh.row(i) + GAMMA_ROW_HEADER, fresh.row(i) + W, 0.0f);
        }
    }
    st.resample_seconds += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    auto rebuilt = std::make_unique<SceneIndex>();
    rebuilt->build_geometry(rt.mesh, rt.tri_surface, index->n_surfaces(), /*refresh_lookup=*/false);
    rebuilt->build_surfels(fresh.surf.position.data(), fresh.surface.data(), fresh.size(),
                           float(std::sqrt(new_area / double(fresh.size()))), c.threads, ahead.get(), &rt.kept);
    ahead.reset();   // taken: its memory back before the transfer
    require_surfels(*rebuilt, iteration);
    st.rebuild_seconds += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    // Amounts (value x A/N): kept surfels keep theirs; each replaced surfel
    // spreads its amount over the (up to) 8 nearest surfels of its surface
    // on the new mesh with the smoothing weights, in surfel order.
    constexpr size_t K = kSmoothingNeighbours;
    std::vector<uint32_t> nb_idx(removed.size() * K);
    std::vector<double> nb_w(removed.size() * K);
    std::vector<uint8_t> nb_count(removed.size());
    run_with_threads(c.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, removed.size(), 512), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t j = r.begin(); j < r.end(); ++j) {
                const size_t i = removed[j];
                nb_count[j] = uint8_t(rebuilt->smooth(state.surface[i], &state.surf.position[3 * i], &nb_idx[j * K],
                                                      &nb_w[j * K]));
            }
        });
    });
    const double a_old = old_area / double(n), a_new = new_area / double(n);
    std::vector<double> amount(n * W, 0.0);
    for (size_t i = 0; i < n; ++i)
        for (size_t col = GAMMA_ROW_HEADER; col < W; ++col) amount[i * W + col] = double(fresh.rows[i * W + col]) * a_old;
    for (size_t j = 0; j < removed.size(); ++j) {
        const float* row = state.row(removed[j]);
        for (size_t k = 0; k < nb_count[j]; ++k) {
            double* dst = &amount[size_t(nb_idx[j * K + k]) * W];
            const double w = nb_w[j * K + k] * a_old;
            for (size_t col = GAMMA_ROW_HEADER; col < W; ++col) dst[col] += w * double(row[col]);
        }
    }
    for (size_t i = 0; i < n; ++i)
        for (size_t col = GAMMA_ROW_HEADER; col < W; ++col) fresh.rows[i * W + col] = float(amount[i * W + col] / a_new);
    st.resample_seconds += seconds_since(t0);

    mesh = std::move(rt.mesh);
    state = std::move(fresh);
    index = std::move(rebuilt);
    return removed;
}

}  // namespace gammart
