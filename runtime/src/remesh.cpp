// CGAL isotropic remeshing and mesh measures (see gamma/remesh.h).
#include "gamma/remesh.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/boost/graph/Euler_operations.h>
#include <CGAL/Polygon_mesh_processing/detect_features.h>
#include <CGAL/Polygon_mesh_processing/remesh.h>
#include <CGAL/Polygon_mesh_processing/repair_degeneracies.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <utility>

#include "gamma/error.h"
#include "gamma/triangle_quality.h"

namespace gammart {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using SurfaceMesh = CGAL::Surface_mesh<Point>;
using VertexIndex = SurfaceMesh::Vertex_index;
using FaceIndex = SurfaceMesh::Face_index;
using EdgeIndex = SurfaceMesh::Edge_index;
namespace PMP = CGAL::Polygon_mesh_processing;

// Vertex rings around the region converted into CGAL's mesh with it.  In a
// remeshing pass one ring holds every triangle a split or collapse of a
// region-border edge can change, so the vertices of the cut (shared with
// triangles left outside) are never touched; a sliver pass's collapses can
// cascade into the triangles around the ones they change, so it gets more.
// Should a pass still move or remove a vertex of the cut, it is run again
// in the whole mesh.
constexpr int kRemeshMarginRings = 1, kSliverMarginRings = 3;

double angle_deg(const float* a, const float* b, const float* c) {  // angle at a
    double u[3], v[3];
    for (int k = 0; k < 3; ++k) {
        u[k] = double(b[k]) - a[k];
        v[k] = double(c[k]) - a[k];
    }
    const double uv = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    const double cx = u[1] * v[2] - u[2] * v[1], cy = u[2] * v[0] - u[0] * v[2], cz = u[0] * v[1] - u[1] * v[0];
    return double(gm::atan2(float(std::sqrt(cx * cx + cy * cy + cz * cz)), float(uv))) * 180.0 / M_PI;
}

// CGAL's isotropic remeshing of `faces` towards `target_edge_length`, as
// every pass of a re-tiling runs it: `rounds` rounds, each surface a patch,
// the `constrained` edges kept as polylines (split or collapsed, never
// flipped; their vertices not relaxed).
template <class FacePatch, class EdgeConstrained>
void remesh_faces(const std::vector<FaceIndex>& faces, double target_edge_length, unsigned rounds, SurfaceMesh& sm,
                  FacePatch patch, EdgeConstrained constrained) {
    PMP::isotropic_remeshing(faces, target_edge_length, sm,
                             CGAL::parameters::number_of_iterations(rounds)
                                 .face_patch_map(patch)
                                 .edge_is_constrained_map(constrained)
                                 .relax_constraints(false));
    sm.collect_garbage();
}

// Pockets at most this many triangles big are flattened (flatten_pockets):
// about 25 squared edge lengths of surface, a pit or spike a few edge
// lengths deep.  On the bunny benchmark at 50k surfels pits behind mouths
// narrower than an edge are born at about 40 triangles; left alone they
// grow into caves of hundreds, with slivers at their mouths.
constexpr size_t kMaxPocketFaces = 64;

// The triangles on the side of the 3-cycle of edges (a, b), (b, x), (x, a)
// that `h` (a halfedge of the cycle, not on the border) looks at, or none
// if that side has more than kMaxPocketFaces triangles.
std::vector<FaceIndex> pocket_side(const SurfaceMesh& sm, SurfaceMesh::Halfedge_index h, const EdgeIndex cycle[3]) {
    std::vector<FaceIndex> side{sm.face(h)};
    for (size_t i = 0; i < side.size(); ++i) {
        if (side.size() > kMaxPocketFaces) return {};
        for (SurfaceMesh::Halfedge_index g : sm.halfedges_around_face(sm.halfedge(side[i]))) {
            const EdgeIndex e = sm.edge(g);
            if (e == cycle[0] || e == cycle[1] || e == cycle[2] || sm.is_border(sm.opposite(g))) continue;
            const FaceIndex o = sm.face(sm.opposite(g));
            if (std::find(side.begin(), side.end(), o) == side.end()) side.push_back(o);
        }
    }
    return side;
}

// Flattens the pocket the 3-cycle of edges (a, b), (b, x), (x, a) cuts
// off, if one side of the cycle is small (at most kMaxPocketFaces
// triangles; the other side larger) with no kept edge and no vertex of the
// mesh's border or of the cut (`frozen`) inside: its triangles are replaced
// by the one triangle (a, b, x), oriented as they are -- unless that
// triangle is degenerate or the mirror of a triangle already beyond one of
// its edges.  (Any surface on the cycle has the same vector area, so the
// triangle faces the way the pocket does on the whole.)  Returns whether it
// did (the pocket's elements are left as garbage).
template <class EdgeConstrained, class VertexFrozen>
bool flatten_cycle(SurfaceMesh& sm, VertexIndex a, VertexIndex b, VertexIndex x, const EdgeConstrained& constrained,
                   const VertexFrozen& frozen) {
    using Halfedge = SurfaceMesh::Halfedge_index;
    const VertexIndex cyc[3] = {a, b, x};
    EdgeIndex cycle[3];
    Halfedge ch[3];
    for (int j = 0; j < 3; ++j) {
        const auto [h, found] = CGAL::halfedge(cyc[j], cyc[(j + 1) % 3], sm);
        if (!found) return false;
        ch[j] = h;
        cycle[j] = sm.edge(h);
    }
    // the two sides, seen from the cycle's halfedges a -> b and b -> a
    const Halfedge sides[2] = {ch[0], sm.opposite(ch[0])};
    if (sm.is_border(sides[0]) || sm.is_border(sides[1])) return false;
    std::vector<FaceIndex> side[2];
    for (int k = 0; k < 2; ++k) side[k] = pocket_side(sm, sides[k], cycle);
    const bool small0 = !side[0].empty(), small1 = !side[1].empty();
    if (small0 == small1) return false;   // both small (a tiny closed piece) or neither
    const std::vector<FaceIndex>& pocket = small0 ? side[0] : side[1];
    // the new triangle keeps the pocket's orientation along (a, b)
    const VertexIndex u = small0 ? a : b, v = small0 ? b : a;
    for (FaceIndex g : pocket)
        for (Halfedge h : sm.halfedges_around_face(sm.halfedge(g))) {
            const EdgeIndex e = sm.edge(h);
            if (e != cycle[0] && e != cycle[1] && e != cycle[2] && constrained[e]) return false;
            const VertexIndex w = sm.target(h);
            if (w != a && w != b && w != x && (frozen[w] || sm.is_border(w))) return false;
        }
    if (CGAL::collinear(sm.point(u), sm.point(v), sm.point(x))) return false;
    const VertexIndex t[3] = {u, v, x};
    for (int j = 0; j < 3; ++j) {
        const auto [h, found] = CGAL::halfedge(t[(j + 1) % 3], t[j], sm);
        if (found && !sm.is_border(h) && sm.target(sm.next(h)) == t[(j + 2) % 3]) return false;   // the mirror
    }
    for (FaceIndex g : pocket) CGAL::Euler::remove_face(sm.halfedge(g), sm);
    const auto [hole, found] = CGAL::halfedge(u, v, sm);
    if (!found || !sm.is_border(hole)) throw Error("retile: flattening a pocket left no hole (internal error)");
    CGAL::Euler::fill_hole(hole, sm);
    return true;
}

// The faces of sm that is_sliver flags, in face order.
template <class IsSliver>
std::vector<FaceIndex> sliver_faces(const SurfaceMesh& sm, IsSliver is_sliver) {
    std::vector<FaceIndex> slivers;
    for (FaceIndex f : sm.faces())
        if (is_sliver(f)) slivers.push_back(f);
    return slivers;
}

// Flattens the small pockets (flatten_cycle) at the slivers: the star of a
// spike (a corner of valence 3: the cycle of its three neighbours), and a
// pocket that keeps the sliver's shortest edge (a, b) from being collapsed
// -- a neighbour x of both a and b that is not the apex of a triangle on
// (a, b) fails the link condition (collapsing would make the mesh
// non-manifold), and the cycle (a, b, x) cuts the surface in two (a spike,
// a fin, or a bulb erosion made on a neck narrower than an edge).  The
// solid loses (or gains) what lay between the pocket and its new triangle.
// Returns how many pockets were flattened.
template <class EdgeConstrained, class VertexFrozen, class IsSliver>
int flatten_pockets(SurfaceMesh& sm, const EdgeConstrained& constrained, const VertexFrozen& frozen,
                    IsSliver is_sliver) {
    using Halfedge = SurfaceMesh::Halfedge_index;
    int flattened = 0;
    for (FaceIndex f : sliver_faces(sm, is_sliver)) {
        if (sm.is_removed(f)) continue;
        std::vector<VertexIndex> corners;
        for (VertexIndex w : sm.vertices_around_face(sm.halfedge(f))) corners.push_back(w);
        for (VertexIndex w : corners) {
            if (sm.is_removed(f)) break;
            if (sm.is_removed(w) || sm.is_border(w) || sm.degree(w) != 3) continue;
            std::vector<VertexIndex> link;
            for (VertexIndex n : sm.vertices_around_target(sm.halfedge(w))) link.push_back(n);
            flattened += flatten_cycle(sm, link[0], link[1], link[2], constrained, frozen);
        }
        if (sm.is_removed(f)) continue;
        Halfedge hs = sm.halfedge(f);   // the sliver's shortest edge
        double shortest = std::numeric_limits<double>::infinity();
        for (Halfedge h : sm.halfedges_around_face(sm.halfedge(f))) {
            const double l = CGAL::squared_distance(sm.point(sm.source(h)), sm.point(sm.target(h)));
            if (l < shortest) {
                shortest = l;
                hs = h;
            }
        }
        const VertexIndex a = sm.source(hs), b = sm.target(hs);
        const VertexIndex apex0 = sm.target(sm.next(hs));
        const VertexIndex apex1 =
            sm.is_border(sm.opposite(hs)) ? SurfaceMesh::null_vertex() : sm.target(sm.next(sm.opposite(hs)));
        std::vector<VertexIndex> around_a, common;
        for (VertexIndex v : sm.vertices_around_target(sm.halfedge(a))) around_a.push_back(v);
        std::sort(around_a.begin(), around_a.end());
        for (VertexIndex v : sm.vertices_around_target(sm.halfedge(b)))
            if (v != apex0 && v != apex1 && v != a && std::binary_search(around_a.begin(), around_a.end(), v))
                common.push_back(v);
        std::sort(common.begin(), common.end());
        for (VertexIndex x : common) {
            if (sm.is_removed(f) || sm.is_removed(a) || sm.is_removed(b) || sm.is_removed(x)) break;
            flattened += flatten_cycle(sm, a, b, x, constrained, frozen);
        }
    }
    return flattened;
}

// Test hook (remesh.h): cuts still to refuse.
std::atomic<int> g_refuse_cuts_for_testing{0};

// Takes one refusal if any is left (the counter never goes below 0).
bool take_refusal_for_testing() {
    int left = g_refuse_cuts_for_testing.load();
    while (left > 0 && !g_refuse_cuts_for_testing.compare_exchange_weak(left, left - 1)) {
    }
    return left > 0;
}

enum class Pass { Remesh, Slivers };

// One pass of a re-tiling on `region` (all triangles when null).
// Pass::Remesh: isotropic remeshing of the region, sharp edges kept.
// Pass::Slivers (region = slivers and the triangles around them): sharp
// edges not kept, CGAL's removal of almost-degenerate faces, then isotropic
// remeshing of the slivers still left and the triangles within
// kSliverPassRings vertex rings of them.
// `cut`: convert only the region and the margin rings around it,
// else the whole mesh.  slivers_left is not filled in.
using FacePatch = SurfaceMesh::Property_map<FaceIndex, int32_t>;
using FaceInput = SurfaceMesh::Property_map<FaceIndex, int32_t>;
using VertexInput = SurfaceMesh::Property_map<VertexIndex, int32_t>;
using VertexFlag = SurfaceMesh::Property_map<VertexIndex, bool>;
using EdgeFlag = SurfaceMesh::Property_map<EdgeIndex, bool>;

// An edge the re-tiling keeps in place: on a border, or between two surfaces.
bool kept_edge(const SurfaceMesh& sm, const FacePatch& patch, SurfaceMesh::Halfedge_index h) {
    const auto o = sm.opposite(h);
    return sm.is_border(h) || sm.is_border(o) || patch[sm.face(h)] != patch[sm.face(o)];
}

// Pass::Slivers on the sub-mesh (retile_pass): CGAL's removal of almost
// degenerate faces, then the slivers still left and the triangles around
// them remeshed, then what the remeshing left flattened and removed.
void remove_slivers(SurfaceMesh& sm, std::vector<FaceIndex>& faces, const FacePatch& patch, const EdgeFlag& constrained,
                    const VertexFlag& vertex_frozen, double target_edge_length, unsigned rounds) {
    // Isotropic remeshing flips edges for valence, not angles, and its
    // relaxation cannot pull a vertex off a fold of the surface it
    // projects onto: a cap (an angle above kCapDeg) is flipped and a
    // needle (longest / shortest edge above kNeedleRatio, about
    // 1 / sin 15°) collapsed first, edges kept by `constrained` untouched.
    constexpr double kCapDeg = 120.0, kNeedleRatio = 4.0;
    PMP::experimental::remove_almost_degenerate_faces(faces, sm, cos_of_deg(kCapDeg), kNeedleRatio,
                                                      target_edge_length,
                                                      CGAL::parameters::edge_is_constrained_map(constrained));
    sm.collect_garbage();
    // The slivers still left and the triangles within kSliverPassRings
    // vertex rings of them (none touching the cut), remeshed.
    const double cos_max = cos_of_deg(kMinRetiledAngleDeg);
    auto is_sliver = [&](FaceIndex f) {
        const auto h0 = sm.halfedge(f);
        const SurfaceMesh::Halfedge_index hs[3] = {h0, sm.next(h0), sm.next(sm.next(h0))};
        double p[3][3];
        uint8_t kept[3];
        for (int k = 0; k < 3; ++k) {   // p[k] = source of hs[k]: corner k lies between hs[k] and hs[k + 2]
            const Point& q = sm.point(sm.source(hs[k]));
            p[k][0] = q.x(); p[k][1] = q.y(); p[k][2] = q.z();
            kept[k] = kept_edge(sm, patch, hs[k]);
        }
        return is_sliver_triangle(p, kept, cos_max);
    };
    std::vector<uint8_t> in(sm.num_faces(), 0);
    for (FaceIndex f : sliver_faces(sm, is_sliver)) in[f.idx()] = 1;
    for (int ring = 0; ring < kSliverPassRings; ++ring) {
        std::vector<uint8_t> near(sm.num_vertices(), 0);
        for (FaceIndex f : sm.faces())
            if (in[f.idx()])
                for (VertexIndex x : sm.vertices_around_face(sm.halfedge(f))) near[x.idx()] = 1;
        for (FaceIndex f : sm.faces())
            for (VertexIndex x : sm.vertices_around_face(sm.halfedge(f))) in[f.idx()] |= near[x.idx()];
    }
    faces.clear();
    for (FaceIndex f : sm.faces()) {
        if (!in[f.idx()]) continue;
        bool touches_cut = false;
        for (VertexIndex x : sm.vertices_around_face(sm.halfedge(f))) touches_cut = touches_cut || vertex_frozen[x];
        if (!touches_cut) faces.push_back(f);
    }
    if (!faces.empty()) remesh_faces(faces, target_edge_length, rounds, sm, patch, constrained);
    // The slivers the remeshing itself left (at a sharp fold its flips
    // and collapses are refused and its relaxation cannot widen them):
    // the small pockets at them are flattened first (flatten_pockets: a
    // spike, or a pit or fin whose 3-edge neck keeps a short edge from
    // being collapsed), then CGAL's removal of almost-degenerate faces
    // runs on the slivers with a needle ratio that catches every one
    // (below kAllSliversNeedleRatio, a triangle with an angle under
    // kMinRetiledAngleDeg has an angle over kCapDeg), vertices of the
    // cut held, and once more for caps alone.  Nothing is remeshed
    // after it.
    constexpr double kAllSliversNeedleRatio = 3.3;   // < sin(kCapDeg) / sin(kMinRetiledAngleDeg) = 3.35
    std::vector<FaceIndex> left = sliver_faces(sm, is_sliver);
    if (!left.empty()) {
        if (flatten_pockets(sm, constrained, vertex_frozen, is_sliver) > 0) {
            sm.collect_garbage();
            left = sliver_faces(sm, is_sliver);
        }
        PMP::experimental::remove_almost_degenerate_faces(
            left, sm, cos_of_deg(kCapDeg), kAllSliversNeedleRatio, target_edge_length,
            CGAL::parameters::edge_is_constrained_map(constrained).vertex_is_constrained_map(vertex_frozen));
        sm.collect_garbage();
        // A sliver that is both a needle and a cap is only ever treated
        // as a needle; where its collapse would invert a triangle, its
        // cap is flipped instead (no needle threshold).
        left = sliver_faces(sm, is_sliver);
        if (!left.empty()) {
            PMP::experimental::remove_almost_degenerate_faces(
                left, sm, cos_of_deg(kCapDeg), 1e6,
                target_edge_length,
                CGAL::parameters::edge_is_constrained_map(constrained).vertex_is_constrained_map(vertex_frozen));
            sm.collect_garbage();
        }
    }
}

// retile_pass's result: the input's vertices that were not converted, then
// the sub-mesh's; the triangles left outside, then the sub-mesh's.
Retiled sub_mesh_result(const Mesh& mesh, const std::vector<int32_t>& tri_surface, const std::vector<uint8_t>& sub,
                        const std::vector<uint8_t>& used, const SurfaceMesh& sm, const FacePatch& patch,
                        const VertexInput& vertex_input, const FaceInput& face_input, const VertexFlag& vertex_frozen) {
    Retiled out;
    const size_t m = mesh.num_triangles(), n = mesh.num_vertices();
    // The output: the input's vertices that were not converted, then the
    // sub-mesh's (after collect_garbage its indices are 0 .. k-1 in order);
    // the triangles left outside, then the sub-mesh's.  For the whole mesh
    // this is the sub-mesh alone, in CGAL's order.
    std::vector<float> v;
    v.reserve(3 * (n + sm.number_of_vertices()));
    std::vector<int32_t> out_of_input(n, -1);
    for (size_t i = 0; i < n; ++i)
        if (!used[i]) {
            out_of_input[i] = int32_t(v.size() / 3);
            v.insert(v.end(), &mesh.vertices[3 * i], &mesh.vertices[3 * i] + 3);
        }
    const int32_t first_sub = int32_t(v.size() / 3);
    auto id = [&](VertexIndex x) { return first_sub + int32_t(x.idx()); };
    for (VertexIndex x : sm.vertices()) {
        const Point& p = sm.point(x);
        v.push_back(float(p.x()));
        v.push_back(float(p.y()));
        v.push_back(float(p.z()));
        if (vertex_frozen[x]) out_of_input[size_t(vertex_input[x])] = id(x);   // the cut's vertices never move
    }
    // A vertex is the input's if it is the same element at the same place.
    auto unchanged = [&](VertexIndex x) {
        const int32_t i = vertex_input[x];
        if (i < 0) return false;
        const Point& p = sm.point(x);
        const float* q = &mesh.vertices[3 * size_t(i)];
        return float(p.x()) == q[0] && float(p.y()) == q[1] && float(p.z()) == q[2];
    };
    std::vector<int32_t> t;
    std::vector<int32_t> surf, same;
    t.reserve(3 * (m + sm.number_of_faces()));
    for (size_t o = 0; o < m; ++o) {
        if (sub[o]) continue;
        for (int k = 0; k < 3; ++k) t.push_back(out_of_input[size_t(mesh.triangles[3 * o + size_t(k)])]);
        surf.push_back(tri_surface[o]);
        same.push_back(int32_t(o));
    }
    for (FaceIndex f : sm.faces()) {
        int32_t in[3];
        int k = 0;
        bool kept = face_input[f] >= 0;
        for (VertexIndex x : sm.vertices_around_face(sm.halfedge(f))) {
            t.push_back(id(x));
            kept = kept && unchanged(x);
            in[k++] = vertex_input[x];
        }
        if (kept) {  // the same corners as the input triangle, in the same cyclic order
            const int32_t* o = &mesh.triangles[3 * size_t(face_input[f])];
            kept = (in[0] == o[0] && in[1] == o[1] && in[2] == o[2]) ||
                   (in[0] == o[1] && in[1] == o[2] && in[2] == o[0]) ||
                   (in[0] == o[2] && in[1] == o[0] && in[2] == o[1]);
        }
        surf.push_back(patch[f]);
        same.push_back(kept ? face_input[f] : -1);
    }
    out.mesh = Mesh::from_arrays(v.data(), v.size() / 3, t.data(), t.size() / 3, mesh.name);
    out.tri_surface.resize(out.mesh.num_triangles());
    out.kept.resize(out.mesh.num_triangles());
    for (size_t k = 0; k < out.tri_surface.size(); ++k) {
        out.tri_surface[k] = surf[size_t(out.mesh.original_triangle[k])];
        out.kept[k] = same[size_t(out.mesh.original_triangle[k])];
    }
    return out;
}

Retiled retile_pass(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target_edge_length,
                    int iterations, const std::vector<uint8_t>* region, bool cut, Pass pass) {
    const size_t m = mesh.num_triangles(), n = mesh.num_vertices();
    // A pass on a region hands CGAL only the region and a few
    // vertex rings around it (CGAL's relaxation recomputes the normals of
    // every vertex of the mesh it is given, each round): `sub` flags the
    // triangles converted, `frozen` the vertices on the sub-mesh's cut (it
    // shares them with triangles left outside, so no face touching one is
    // ever re-tiled).
    std::vector<uint8_t> sub(m, 1), frozen(n, 0);
    if (region && cut) {
        sub = *region;
        grow_by_rings(mesh, sub, pass == Pass::Remesh ? kRemeshMarginRings : kSliverMarginRings);
        for (size_t t = 0; t < m; ++t)
            if (!sub[t])
                for (int k = 0; k < 3; ++k) frozen[size_t(mesh.triangles[3 * t + size_t(k)])] = 1;
    }
    SurfaceMesh sm;
    auto patch = sm.add_property_map<FaceIndex, int32_t>("f:surface", 0).first;
    // Which input vertex / triangle an element was (-1: made by the remeshing;
    // CGAL resets properties of recycled elements).
    auto vertex_input = sm.add_property_map<VertexIndex, int32_t>("v:input", -1).first;
    auto face_input = sm.add_property_map<FaceIndex, int32_t>("f:input", -1).first;
    auto vertex_frozen = sm.add_property_map<VertexIndex, bool>("v:frozen", false).first;
    std::vector<VertexIndex> vi(n, SurfaceMesh::null_vertex());
    std::vector<uint8_t> used(n, region && cut ? 0 : 1);   // the whole mesh: every vertex, isolated ones too
    for (size_t t = 0; t < m; ++t)
        if (sub[t])
            for (int k = 0; k < 3; ++k) used[size_t(mesh.triangles[3 * t + size_t(k)])] = 1;
    for (size_t i = 0; i < n; ++i) {
        if (!used[i]) continue;
        vi[i] = sm.add_vertex(Point(mesh.vertices[3 * i], mesh.vertices[3 * i + 1], mesh.vertices[3 * i + 2]));
        vertex_input[vi[i]] = int32_t(i);
        vertex_frozen[vi[i]] = frozen[i] != 0;
    }
    std::vector<FaceIndex> faces;
    const bool refuse = region && cut && take_refusal_for_testing();
    for (size_t t = 0; t < m; ++t) {
        if (!sub[t]) continue;
        const FaceIndex f = refuse ? SurfaceMesh::null_face()
                                   : sm.add_face(vi[size_t(mesh.triangles[3 * t])], vi[size_t(mesh.triangles[3 * t + 1])],
                                                 vi[size_t(mesh.triangles[3 * t + 2])]);
        if (f == SurfaceMesh::null_face()) {
            if (region && cut) {   // the cut made a vertex CGAL cannot hold (two fans): the pass in the whole mesh
                Retiled whole = retile_pass(mesh, tri_surface, target_edge_length, iterations, region, false, pass);
                whole.whole_mesh_fallbacks += 1;
                return whole;
            }
            throw Error("retile: " + mesh.name + " is not an oriented 2-manifold (triangle " + std::to_string(t) +
                        " cannot be added); re-tiling needs a manifold mesh");
        }
        patch[f] = tri_surface[t];
        face_input[f] = int32_t(t);
        if (!region || (*region)[t]) faces.push_back(f);
    }
    // Borders between surfaces and open boundaries stay where they are (as
    // polylines); so do sharp edges (faces meeting at more than
    // kSharpEdgeDeg) in a remeshing pass: otherwise flips and relaxation
    // would cut creases and shrink the solid.  A sliver pass releases them
    // (a crease there rounds off, as wear does).
    auto constrained = sm.add_property_map<EdgeIndex, bool>("e:constrained", false).first;
    if (pass == Pass::Remesh) PMP::detect_sharp_edges(sm, kSharpEdgeDeg, constrained);
    for (EdgeIndex e : sm.edges())
        if (kept_edge(sm, patch, sm.halfedge(e))) constrained[e] = true;
    const unsigned rounds = unsigned(std::max(iterations, 1));
    if (pass == Pass::Remesh) {
        remesh_faces(faces, target_edge_length, rounds, sm, patch, constrained);
    } else {
        remove_slivers(sm, faces, patch, constrained, vertex_frozen, target_edge_length, rounds);
    }
    if (region && cut) {   // every vertex of the cut still there, where it was
        size_t cut_vertices = 0, held = 0;
        for (size_t i = 0; i < n; ++i) cut_vertices += used[i] && frozen[i];
        for (VertexIndex x : sm.vertices()) {
            if (!vertex_frozen[x]) continue;
            const Point& p = sm.point(x);
            const float* q = &mesh.vertices[3 * size_t(vertex_input[x])];
            held += float(p.x()) == q[0] && float(p.y()) == q[1] && float(p.z()) == q[2];
        }
        if (held != cut_vertices) {
            Retiled whole = retile_pass(mesh, tri_surface, target_edge_length, iterations, region, false, pass);
            whole.whole_mesh_fallbacks += 1;
            return whole;
        }
    }
    return sub_mesh_result(mesh, tri_surface, sub, used, sm, patch, vertex_input, face_input, vertex_frozen);
}

// The slivers of `mesh` (is_sliver_triangle, one flag per triangle).  Which
// edges are kept is looked up only for the triangles with a narrow corner
// (a sort of their edges, not of the whole mesh's: this runs after every
// pass).
std::vector<uint8_t> sliver_flags(const Mesh& mesh, const std::vector<int32_t>& tri_surface) {
    const size_t m = mesh.num_triangles();
    const double cos_max = cos_of_deg(kMinRetiledAngleDeg);
    const uint8_t none_kept[3] = {0, 0, 0};
    std::vector<uint8_t> flags(m, 0);
    std::vector<uint32_t> narrow;
    for (size_t t = 0; t < m; ++t) {
        double p[3][3];
        triangle_corners(mesh, t, p);
        if (is_sliver_triangle(p, none_kept, cos_max)) narrow.push_back(uint32_t(t));
    }
    if (narrow.empty()) return flags;
    auto key = [&](size_t t, size_t k) {
        const uint32_t a = uint32_t(mesh.triangles[3 * t + k]), b = uint32_t(mesh.triangles[3 * t + (k + 1) % 3]);
        return uint64_t(std::min(a, b)) << 32 | std::max(a, b);
    };
    // kept_edge_slots' rule for the narrow triangles' edges: kept unless
    // exactly two triangles of one surface share it
    std::vector<uint64_t> keys;
    for (uint32_t t : narrow)
        for (size_t k = 0; k < 3; ++k) keys.push_back(key(t, k));
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    std::vector<uint32_t> count(keys.size(), 0);
    std::vector<int32_t> surface(keys.size(), INT32_MIN);
    std::vector<uint8_t> seam(keys.size(), 0);
    for (size_t t = 0; t < m; ++t)
        for (size_t k = 0; k < 3; ++k) {
            const auto it = std::lower_bound(keys.begin(), keys.end(), key(t, k));
            if (it == keys.end() || *it != key(t, k)) continue;
            const size_t e = size_t(it - keys.begin());
            ++count[e];
            const int32_t s = tri_surface.empty() ? 0 : tri_surface[t];
            if (surface[e] != INT32_MIN && surface[e] != s) seam[e] = 1;
            surface[e] = s;
        }
    for (uint32_t t : narrow) {
        double p[3][3];
        uint8_t kept[3];
        triangle_corners(mesh, t, p);
        for (size_t k = 0; k < 3; ++k) {
            const size_t e = size_t(std::lower_bound(keys.begin(), keys.end(), key(t, k)) - keys.begin());
            kept[k] = count[e] != 2 || seam[e];
        }
        flags[t] = is_sliver_triangle(p, kept, cos_max);
    }
    return flags;
}

}  // namespace

// `region` flags grown by `rings` vertex rings (every triangle sharing a
// vertex with a flagged one joins, per ring).
void grow_by_rings(const Mesh& mesh, std::vector<uint8_t>& flags, int rings) {
    const size_t m = mesh.num_triangles();
    for (int ring = 0; ring < rings; ++ring) {
        std::vector<uint8_t> near(mesh.num_vertices(), 0);
        for (size_t t = 0; t < m; ++t)
            if (flags[t])
                for (int k = 0; k < 3; ++k) near[size_t(mesh.triangles[3 * t + size_t(k)])] = 1;
        for (size_t t = 0; t < m; ++t)
            for (int k = 0; k < 3; ++k) flags[t] |= near[size_t(mesh.triangles[3 * t + size_t(k)])];
    }
}

Retiled retile(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target_edge_length,
               int iterations, const std::vector<uint8_t>* region) {
    if (!(target_edge_length > 0) || !std::isfinite(target_edge_length))
        throw Error("retile: target edge length must be positive");
    if (region && region->size() != mesh.num_triangles()) throw Error("retile: one region flag per triangle expected");
    Retiled out = retile_pass(mesh, tri_surface, target_edge_length, iterations, region, true, Pass::Remesh);
    // Sliver passes (SPEC §13.12): isotropic remeshing does not promise an
    // angle bound, and slivers survive where its region or a sharp-edge
    // polyline held it back (a local region's border; the creases noise and
    // erosion make on a scanned surface).  Each pass re-tiles the slivers
    // left and the triangles within kSliverPassRings vertex rings of them,
    // cut from the rest of the mesh on their own (a few hundred triangles,
    // not the whole region again).
    std::vector<uint8_t> slivers = sliver_flags(out.mesh, out.tri_surface);
    for (int pass = 0; pass < kSliverPasses; ++pass) {
        if (std::find(slivers.begin(), slivers.end(), uint8_t(1)) == slivers.end()) break;
        std::vector<uint8_t> around = slivers;
        grow_by_rings(out.mesh, around, kSliverPassRings);
        Retiled next = retile_pass(out.mesh, out.tri_surface, target_edge_length, iterations, &around, true,
                                   Pass::Slivers);
        for (int32_t& k : next.kept)   // kept from the input: kept by every pass
            if (k >= 0) k = out.kept[size_t(k)];
        next.whole_mesh_fallbacks += out.whole_mesh_fallbacks;
        out = std::move(next);
        slivers = sliver_flags(out.mesh, out.tri_surface);
    }
    out.slivers_left = size_t(std::count(slivers.begin(), slivers.end(), uint8_t(1)));
    return out;
}

void refuse_retile_cuts_for_testing(int cuts) { g_refuse_cuts_for_testing.store(cuts); }

MeshMeasures measure(const Mesh& mesh, const std::vector<int32_t>& tri_surface) {
    if (!tri_surface.empty() && tri_surface.size() != mesh.num_triangles())
        throw Error("measure: one surface id per triangle expected");
    MeshMeasures m;
    m.triangles = mesh.num_triangles();
    m.area = mesh.area();
    m.min_angle_deg = m.triangles ? 180.0 : 0.0;
    m.min_free_angle_deg = m.min_angle_deg;
    const std::vector<uint8_t> kept = kept_edge_slots(mesh, tri_surface);
    // Closed: every directed edge (a, b) appears once and its reverse once.
    std::vector<uint64_t> directed;
    directed.reserve(3 * m.triangles);
    double vol = 0;
    for (size_t t = 0; t < m.triangles; ++t) {
        const int32_t* tri = &mesh.triangles[3 * t];
        const float* a = &mesh.vertices[3 * size_t(tri[0])];
        const float* b = &mesh.vertices[3 * size_t(tri[1])];
        const float* c = &mesh.vertices[3 * size_t(tri[2])];
        const double corner[3] = {angle_deg(a, b, c), angle_deg(b, c, a), angle_deg(c, a, b)};
        for (size_t k = 0; k < 3; ++k) {   // corner k lies between edge slots k and k + 2
            m.min_angle_deg = std::min(m.min_angle_deg, corner[k]);
            if (!(kept[3 * t + k] && kept[3 * t + (k + 2) % 3])) m.min_free_angle_deg = std::min(m.min_free_angle_deg, corner[k]);
        }
        vol += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
                double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
                double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) / 6.0;
        for (int k = 0; k < 3; ++k)
            directed.push_back(uint64_t(uint32_t(tri[k])) << 32 | uint32_t(tri[(k + 1) % 3]));
    }
    std::sort(directed.begin(), directed.end());
    m.closed = m.triangles > 0;
    for (size_t i = 0; i < directed.size() && m.closed; ++i) {
        const uint64_t e = directed[i], rev = (e << 32) | (e >> 32);
        const bool once = (i == 0 || directed[i - 1] != e) && (i + 1 == directed.size() || directed[i + 1] != e);
        if (!once || !std::binary_search(directed.begin(), directed.end(), rev)) m.closed = false;
    }
    m.volume = m.closed ? vol : std::numeric_limits<double>::quiet_NaN();
    return m;
}

}  // namespace gammart
