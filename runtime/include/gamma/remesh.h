// Re-tiling of a deformed surface (CGAL Polygon Mesh Processing isotropic
// remeshing) and the geometric measures reported per iteration.  CGAL is
// confined to remesh.cpp.
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"

namespace gammart {

// The smallest triangle angle re-tiling keeps (SPEC §13.12), except at a
// corner between two kept edges (open boundaries, seams between surfaces)
// that the input itself makes that narrow.
constexpr double kMinRetiledAngleDeg = 15.0;
// Re-tiling passes after the first over the slivers left (and the triangles
// within kSliverPassRings vertex rings of them), sharp edges there released.
constexpr int kSliverPasses = 4, kSliverPassRings = 2;

// Edges whose faces' normals differ by more than this are kept by re-tiling.
constexpr double kSharpEdgeDeg = 60.0;

struct Retiled {
    Mesh mesh;                       // validated (degenerate triangles dropped)
    std::vector<int32_t> tri_surface; // surface id of every kept triangle
    // Per triangle: the input triangle it is (same three vertices, at
    // bit-identical positions, same orientation), or -1 if re-tiling made it.
    std::vector<int32_t> kept;
    // Triangles still with an angle below kMinRetiledAngleDeg (not at a
    // corner between two kept edges) after the sliver passes: 0 unless they
    // could not remove them all.
    size_t slivers_left = 0;
    // Passes whose sub-mesh CGAL could not hold (a vertex of the cut with two
    // fans of triangles), run in the whole mesh instead (same region).
    int whole_mesh_fallbacks = 0;
};

// Isotropic remeshing towards `target_edge_length` (`iterations` rounds of
// split / collapse / flip / tangential relaxation with projection onto the
// deformed surface).  Each surface id is a patch: the borders between
// surfaces, the mesh's open boundaries and its sharp edges (kSharpEdgeDeg)
// are kept as polylines (their edges may be split or collapsed, never
// flipped, their vertices not relaxed), and every new triangle keeps the
// surface id of the triangle it came from.  Then up to kSliverPasses sliver
// passes re-tile the slivers left (an angle below kMinRetiledAngleDeg at a
// corner not between two border / seam edges) with the triangles within
// kSliverPassRings vertex rings, sharp edges there released: CGAL's removal
// of almost-degenerate faces (cap flips, needle collapses), then isotropic
// remeshing, then a clean-up of the slivers that remeshing left: small
// pockets at them flattened (a spike of valence 3, or a pit, fin or spike
// of at most 64 triangles behind a neck of three edges that keeps a
// sliver's short edge from being collapsed, replaced by one triangle), and
// the removal of almost-degenerate faces again with thresholds that make
// every sliver a needle or a cap, then for caps alone (SPEC §13.12).  Each sliver pass is cut from the mesh on its
// own (its region and a few vertex rings are converted, not the whole mesh
// nor the first pass's region again).  Deterministic (single-threaded).
// Texture coordinates and part labels do not survive (the result has none).
// Throws gammart::Error if the input is not a valid triangle mesh for CGAL.
//
// With `region` (one flag per triangle), only the flagged triangles are
// re-tiled (CGAL's face range; only they and one vertex ring around them
// are converted into CGAL's mesh): the border of the region is kept as a
// constraint like a seam, so apart from the region only triangles along its
// border can change (where a border edge is split or collapsed), and those
// the sliver passes re-tile around a sliver left along that border; every
// other triangle comes out as it was (Retiled::kept).  A pass whose cut
// CGAL cannot hold, or that would move a vertex of the cut, runs in the
// whole mesh instead (Retiled::whole_mesh_fallbacks).
Retiled retile(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target_edge_length,
               int iterations, const std::vector<uint8_t>* region = nullptr);

// `flags` (one per triangle) grown by `rings` vertex rings: per ring, every
// triangle sharing a vertex with a flagged one is flagged.
void grow_by_rings(const Mesh& mesh, std::vector<uint8_t>& flags, int rings);

// Test hook: the next `cuts` sub-meshes a pass on a region would hand CGAL
// are refused as if CGAL could not hold them, so the pass falls back to the
// whole mesh (Retiled::whole_mesh_fallbacks).  An atomic counter; tests only.
void refuse_retile_cuts_for_testing(int cuts);

struct MeshMeasures {
    double area = 0;
    double volume = 0;       // enclosed volume (divergence theorem); NaN when not closed
    bool closed = false;     // every edge has exactly two triangles, consistently oriented
    double min_angle_deg = 0;       // the smallest angle of any triangle corner
    // The smallest angle at a corner the kMinRetiledAngleDeg bound applies
    // to: not between two kept edges (open boundary, non-manifold, or a seam
    // between surfaces; kept_edge_slots).  180 when there is none.
    double min_free_angle_deg = 0;
    size_t triangles = 0;
};

// `tri_surface`: the surface of every triangle (for the seams), or empty
// (then only boundary and non-manifold edges are kept edges).
MeshMeasures measure(const Mesh& mesh, const std::vector<int32_t>& tri_surface = {});

}  // namespace gammart
