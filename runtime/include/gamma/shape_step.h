// The shape step (SPEC §19, "Shape change"): after the update pass, surfaces
// whose shape follows a property move along their outward normal by
// metres-per-unit x the property's change in the iteration; the mesh is
// re-tiled (remesh.h), the surfels are re-sampled on the new surface with
// every property's area integral conserved, and the scene index is rebuilt.
// Nothing is rebuilt in an iteration where no vertex moved.
#pragma once
#include <cstdint>
#include <memory>
#include <vector>

#include "gamma/config.h"
#include "gamma/mesh.h"
#include "gamma/remesh.h"
#include "gamma/scene_index.h"
#include "gamma/surfel_state.h"

namespace gammart {

struct ShapeStats {
    bool changed = false;              // the geometry moved (and the scene index was rebuilt)
    bool retiled = false;              // ... re-tiled with new surfels (else the surfels rode on their triangles)
    int64_t retiled_triangles = 0;     // triangles the re-tiling made (the rest it kept as they were)
    int64_t slivers_left = 0;          // slivers the re-tiling could not remove (Retiled::slivers_left)
    int64_t moved_vertices = 0;
    int64_t clamped_vertices = 0;      // |displacement| cut to the per-iteration bound
    int64_t inversion_limited = 0;     // vertices whose move was shortened so that no triangle flips
    int64_t clearance_limited = 0;     // vertices whose move was shortened to keep a part from thinning through
    int64_t nonfinite_surfels = 0;     // surfels whose displacement was NaN/inf (taken as 0)
    double max_displacement = 0;       // largest |vertex move| applied (scene units)
    double displace_seconds = 0, retile_seconds = 0, resample_seconds = 0, rebuild_seconds = 0;
    MeshMeasures geometry;             // after the step
};

// Per-surfel displacement along the outward normal in this iteration:
// sum over the surfel's surface's shape rates of metres_per_unit x
// (row[column] - before[column]).  Non-finite results are 0 (counted).
std::vector<float> surfel_displacement(const Config& c, const SurfelState& state, const std::vector<float>& before,
                                       int64_t& nonfinite);

// Area-weighted unit vertex normals (outward for a consistently oriented
// closed mesh).
std::vector<V3> vertex_normals(const Mesh& mesh);

// The direction each vertex moves along (SPEC §13.12 step 2): the
// area-weighted vertex normal, then `rings` times replaced by the
// normalised sum of its own and its edge neighbours' directions (Jacobi
// passes: the same at any thread count).  Moves as long as half an edge
// along the raw normals converge where the surface is rough at the edge
// length's scale (neighbours' normals differ by tens of degrees), fold the
// surface there, and the folds inflate under further erosion; directions
// smooth over a few edge lengths carry that roughness along instead.
// Vertices of no triangle get the zero vector.  `threads` <= 0: all.
constexpr int kMoveDirectionRings = 4;
std::vector<V3> move_directions(const Mesh& mesh, int rings, int threads = 0);

// The vertex displacements averaged `rings` times (Config::displacement_rings,
// 2 unless a test asks for a field sharper than the mesh): every vertex's value
// replaced by the plain mean of its own and its edge neighbours' (Jacobi
// passes, in double: a uniform field stays exactly uniform; the same at
// any thread count).  The surfels are half an edge apart and the 8 nearest
// cover less than a vertex's ring, so the vertices would otherwise sample
// the field finer than the mesh can follow: hit noise and the pits the
// sand digs at that scale tilt the triangles every step (SPEC §13.12 step 2).
void average_over_rings(const Mesh& mesh, std::vector<float>& dv, int rings, int threads = 0);

// Limits moves so that no part of the solid thins through and no gap
// closes (SPEC §13.12 step 3): a vertex moving by dv[v] along dir[v] casts
// a ray from where it is, along -dir[v] when it moves inward (dv < 0) and
// along +dir[v] when outward; if the ray meets the surface at distance t,
// the vertex's room is max(0, (t - min_gap) / 2) (no hit: unlimited) -- the
// two sides of a part (or of a gap) moving towards each other keep min_gap
// between them -- and |dv[v]| is cut to the least room of the vertex and
// its edge neighbours that move the same way (inward or outward).
// The rays look only min_gap + 2|dv| ahead (nothing farther can cut the
// move), so a neighbour sets a limit only when its own move was cut.
// Returns how many moves were cut.  The rays are cast in parallel, each
// vertex's room from its own ray; the neighbour minimum is serial, so the
// result is the same at any thread count.
int64_t limit_to_clearance(const SceneIndex& index, const Mesh& mesh, const std::vector<V3>& dir,
                           double min_gap, std::vector<float>& dv, int threads);

// Transfers rows from `old_state` (on a surface of area old_area) to the
// surfels of `state` (area new_area): every old surfel scatters its amount
// value x (old_area / N_old) to the new surfels of its own surface with the
// smoothing weights of `index` (built over the new surfels; they sum to 1),
// and a new surfel's value is its amount / (new_area / N_new): the area
// integral of every property column is conserved per surface (to float
// rounding).  Header columns (gamma-reflectance) are taken from the nearest
// old surfel of the same surface (`old_index`).  Sequential in old-surfel
// order: the same result at any thread count.
void transfer_rows(const SurfelState& old_state, double old_area, const SceneIndex& old_index,
                   SurfelState& state, double new_area, const SceneIndex& index, int threads);

// What a triangle needs re-tiling for (SPEC §13.12), one byte per
// triangle: kSliverDefect when it is a sliver (is_sliver_triangle: an angle
// below min_deg not between two kept edges), kEdgeDefect when an edge is
// shorter than kRegionShortEdge or longer than kRegionLongEdge x target.
// One pass over the triangles (their corners read once).
constexpr double kRegionShortEdge = 0.4, kRegionLongEdge = 2.0;
constexpr uint8_t kSliverDefect = 1, kEdgeDefect = 2;
std::vector<uint8_t> triangle_defects(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target,
                                      double min_deg);

// The triangles a re-tiling after the first re-tiles: those with a defect
// (triangle_defects) and the triangles within kRegionRings vertex rings of
// one.  One flag per triangle.
constexpr int kRegionRings = 1;
// The triangle lookup built ahead beside a local re-tiling leaves out the
// region and this many vertex rings around it (triangles there are mostly
// re-tiled, or hold surfels the re-tiling replaces in their search balls:
// measured on the bunny, 2 rings leave out ~90 % of those and ~4 % of the
// triangles whose entries would have been taken).
constexpr int kAheadSkipRings = 2;
std::vector<uint8_t> retiling_region(const Mesh& mesh, const std::vector<uint8_t>& defects);
std::vector<uint8_t> retiling_region(const Mesh& mesh, const std::vector<int32_t>& tri_surface, double target,
                                     double min_deg);

class ShapeStep {
public:
    explicit ShapeStep(const Config& c) : cfg_(c) {}
    bool active() const { return !cfg_.shape_rates.empty(); }

    // Remembers the rows at the start of the iteration (before tracing).
    void begin_iteration(const SurfelState& state);

    // Displaces, re-tiles, re-samples, transfers and rebuilds.  mesh, state,
    // index (a new one) and frame are replaced when the geometry changed.
    // Throws gammart::Error if a surface loses all its surfels.
    ShapeStats apply(int iteration, Mesh& mesh, SurfelState& state, std::unique_ptr<SceneIndex>& index,
                     SceneFrame& frame);
    // How many times apply() rebuilt the geometry.
    int rebuilds() const { return rebuilds_; }

    // Re-tilings are skipped while the triangles stay good: at most this
    // many iterations in a row (SPEC §13.12).
    static constexpr int kMaxIterationsWithoutRetiling = 8;
    static constexpr double kSliverDeg = kMinRetiledAngleDeg;   // a triangle with a smaller angle is a sliver

private:
    // New surfels on the re-tiled mesh, rows transferred, scene index rebuilt.
    void resample(int iteration, Retiled& rt, Mesh& mesh, SurfelState& state, std::unique_ptr<SceneIndex>& index,
                  ShapeStats& st) const;
    // After a local re-tiling (state's surfels already carried onto
    // `displaced`): surfels on kept triangles stay, those on replaced ones
    // are replaced by as many new surfels sampled on the new triangles,
    // whose amounts spread over the new surfels around them.  `ahead`: the
    // triangle lookup built over `displaced` and the carried surfels
    // (SceneIndex::build_lookup_ahead), whose entries the new index takes
    // where they still hold (released once taken).  Returns the indices of
    // the replaced surfels (ascending).
    std::vector<uint32_t> resample_region(int iteration, Retiled& rt, Mesh& mesh, const Mesh& displaced,
                                          SurfelState& state, std::unique_ptr<SceneIndex>& index,
                                          std::unique_ptr<SceneIndex>& ahead, ShapeStats& st) const;

    const Config& cfg_;
    std::vector<float> before_;
    int rebuilds_ = 0;
    int kept_iterations_ = 0;           // shape steps since the last re-tiling
    double retiled_area_ = 0;           // area right after the last re-tiling
};

}  // namespace gammart
