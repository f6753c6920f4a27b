// The scene index: what the passes query about the geometry and the surfels.
// - the Embree BVH over the mesh's triangles (rays, shadow/occlusion rays),
//   with the surface id of every triangle;
// - one nanoflann kd-tree over all surfels and one per surface id (the
//   surfel an interaction touches, the renders' property smoothing);
// - the triangle lookup: per triangle, the surfels of its surface that can be
//   nearest to a point on it (precomputed from the kd-trees), so the tracer's
//   nearest-surfel query is a scan of a few contiguous entries; a triangle
//   much larger than the surfel spacing is cut into a grid of sub-triangles
//   (cells), each with its own entries;
// - the scene frame: constants derived from the mesh's bounds and gravity.
// Both halves are rebuildable on their own: build_geometry after the mesh
// changed, build_surfels after the surfels changed.  When only positions
// changed (the shape step's surfels riding on their triangles, SPEC §13.12),
// move_vertices + move_surfels update the index in place: the BVH keeps its
// geometry object (its vertex buffer is updated), the kd-trees keep their
// point order, and the triangle lookup is searched again.
#pragma once
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <embree3/rtcore.h>

#include "gamma/float_points.h"
#include "gamma/huge_pages.h"
#include "gamma/mesh.h"
#include "gamma/render.h"
#include "gamma/vec.h"

namespace gammart {

// Constants of the scene used by the passes (computed from the mesh bounds).
struct SceneFrame {
    V3 centre, down, up;
    float radius = 1;   // environment source sphere radius (1.05 x half diagonal)
    float diag = 1;
    float eps = 1e-5f;  // ray offset (1e-5 x diagonal)
    float min_up = 0;   // min over used vertices of dot(v, up)
    std::array<float, 3> lo{}, hi{};  // bounding box

    // `down` must be finite and non-zero (it is normalised here).
    static SceneFrame of(const Mesh& mesh, std::array<float, 3> down);
};

class SceneIndex {
public:
    SceneIndex();
    ~SceneIndex();
    SceneIndex(const SceneIndex&) = delete;
    SceneIndex& operator=(const SceneIndex&) = delete;

    // (Re)builds the BVH over the mesh's triangles; tri_surface has one
    // surface id in [0, n_surfaces) per triangle.
    // The triangle lookup is refreshed too when surfels are indexed, unless
    // refresh_lookup is false (the caller rebuilds the surfels next).
    void build_geometry(const Mesh& mesh, std::vector<int32_t> tri_surface, int n_surfaces,
                        bool refresh_lookup = true);
    // (Re)builds the kd-trees over n surfels (positions n*3, surface ids n;
    // copied).  sigma = the smoothing width (mean surfel spacing).
    // Also rebuilds the triangle lookup (with `threads` threads, <= 0: all;
    // the result does not depend on the count).
    // With `ahead` (a lookup built ahead: build_lookup_ahead) and
    // ahead_triangle (per triangle of this index, one of ahead's or -1):
    // a triangle takes the entries ahead built for that triangle where
    // they are what a build here would make -- the same corners and
    // surface, and no surfel whose position or surface differs between the
    // two indices within the ball its candidates were searched in (nor the
    // nearest surfel then, since it lies in that ball) -- and is searched
    // otherwise.  The lookup is the one built without `ahead`, bit for bit.
    void build_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                       int threads = 0, const SceneIndex* ahead = nullptr,
                       const std::vector<int32_t>* ahead_triangle = nullptr);
    // Builds only what the triangle lookup needs (kd-trees, lookup; no BVH)
    // for `mesh` and n surfels, leaving out the triangles flagged in `skip`:
    // entries for build_surfels to reuse, made beside other work (the shape
    // step builds them while the re-tiling runs).  Runs in the calling
    // thread's TBB arena (no arena of its own), so a thread that waits for
    // it in that arena helps.  Such an index is only for build_surfels to
    // take from: it has no BVH and no tree over all surfels to query.
    void build_lookup_ahead(const Mesh& mesh, std::vector<int32_t> tri_surface, int n_surfaces,
                            const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                            const std::vector<uint8_t>& skip);
    // The mesh's vertices moved (same triangles, same vertex count): the BVH
    // is updated and the triangles' bounding spheres recomputed.  The triangle
    // lookup is stale until move_surfels is called next.
    void move_vertices(const Mesh& mesh);
    // The same surfels (same surfaces, same order) moved to `positions`: the
    // kd-trees and the triangle lookup are rebuilt.  sigma = the new
    // smoothing width.
    void move_surfels(const float* positions, float sigma, int threads = 0);

    // Closest hit along org + t*dir, t in [tnear, tfar]; rh.hit.geomID is
    // RTC_INVALID_GEOMETRY_ID on a miss.
    void cast(RTCRayHit& rh, V3 org, V3 dir, float tnear,
              float tfar = std::numeric_limits<float>::infinity()) const;
    // Shadow / AO ray: true if anything lies between tnear and tfar.
    bool occluded(V3 org, V3 dir, float tnear, float tfar) const;

    // Index of the surfel nearest to p (any surface).
    uint32_t nearest(const float p[3]) const;
    // The kd-tree over every surfel, at the positions last given to
    // build_surfels / move_surfels (null when there are none): other
    // builds over the same points search it instead of building their own.
    const FloatPointsKdTree* surfel_tree() const;
    // Index of the surfel of `surface` nearest to p.  Only for a surface that
    // has surfels (has_surfels); otherwise the nearest surfel of any surface
    // (callers that run rules must not rely on this: see Simulation).
    uint32_t nearest_of(int surface, const float p[3]) const;
    bool has_surfels(int surface) const;
    // The surfel nearest_of(tri_surface()[prim], p) finds, for p on or near
    // triangle prim (anywhere else it falls back to the kd-tree): a scan of
    // the triangle's candidates.  Equidistant surfels go to the lower index.
    uint32_t nearest_on_triangle(uint32_t prim, const float p[3]) const;
    // Starts fetching what nearest_on_triangle(prim, .) reads first (the
    // triangle's head), so a caller with other work can overlap the miss.
    // Always inlined: GCC finds a function whose only effect is a prefetch
    // "pure" and deletes calls to it, so out of line it did nothing.
    [[gnu::always_inline]] void prefetch_lookup(uint32_t prim) const {
        if (prim < lookup_head_.size()) {
            const char* h = reinterpret_cast<const char*>(lookup_head_.data() + prim);
            __builtin_prefetch(h);
            __builtin_prefetch(h + 64);
        }
    }
    // Once prefetch_lookup(prim)'s head has arrived: starts fetching the
    // triangle's candidates past the head's, where a scan that does not stop
    // within the head reads next (one more miss otherwise).
    [[gnu::always_inline]] void prefetch_lookup_rest(uint32_t prim) const {
        if (prim < lookup_head_.size()) {
            const TriangleHead& h = lookup_head_[prim];
            if (h.count > kInlineCandidates) __builtin_prefetch(lookup_packed_.data() + h.more);
        }
    }
    // The scan's answer alone: UINT32_MAX where nearest_on_triangle asks the
    // kd-tree instead (tests measure how often the lookup answers).
    uint32_t lookup_scan(uint32_t prim, const float p[3]) const;
    // Size of the triangle lookup: candidate entries in all, triangles cut
    // into cells, and triangles that use the kd-tree instead (no surfels, or
    // too many candidates even in cells).
    size_t lookup_candidates() const { return lookup_n_candidates_; }
    size_t lookup_grid_triangles() const { return lookup_grids_.size(); }
    size_t lookup_fallback_triangles() const;
    // Triangles whose entries the last build took from a lookup built ahead.
    size_t lookup_reused_triangles() const { return lookup_reused_; }
    // True when both lookups are the same, entry for entry (tests).
    bool same_lookup(const SceneIndex& other) const;
    // Bytes held by the triangle lookup.
    size_t lookup_bytes() const;
    // Number of surfels of each surface.
    std::vector<size_t> surfels_per_surface() const;

    // The property smoothing shared by both renders: the k = 8 nearest
    // surfels of `surface` to p (all surfels if the surface has none or is
    // out of range), Gaussian weights exp(-d^2 / (2 sigma^2)), normalised to
    // sum 1; if every weight underflows, the nearest surfel alone (weight 1).
    // Returns the number of neighbours written to idx / w (nearest first).
    // smooth() of n points close to one another (a run of texels): per
    // point its neighbours and weights (idx, w: n * kSmoothingNeighbours,
    // nearest first) and their count.  The neighbours are picked among the
    // surfels within d_k(c) + 2 r of the points' centre c (r: their largest
    // distance from it; d_k: the distance of c's k-th nearest surfel), which
    // holds each point's k nearest: one radius search instead of n k-nearest
    // searches, with smooth()'s distances and weights.  Surfels at exactly
    // the same distance from a point may come in another order than smooth()'s.
    void smooth_block(int surface, const float* points, size_t n, uint32_t* idx, double* w,
                      uint8_t* counts) const;
    size_t smooth(int surface, const float p[3], uint32_t idx[kSmoothingNeighbours],
                  double w[kSmoothingNeighbours]) const;

    const std::vector<int32_t>& tri_surface() const { return tri_surface_; }
    int n_surfaces() const { return n_surfaces_; }
    size_t n_surfels() const { return n_surfels_; }
    float sigma() const { return sigma_; }
    // How many times each half was built (for tests of "rebuilt only when
    // needed").
    int geometry_builds() const { return geometry_builds_; }
    int surfel_builds() const { return surfel_builds_; }

    struct Trees;
    // One lookup entry while the lookup is built: a candidate surfel's
    // position and its distance from the triangle's centre (entries sorted
    // by it, so a scan stops early); its global index is kept beside it.
    struct Candidate {
        float x, y, z, from_centre;
    };
    // Per triangle (or cell): bounding sphere (centre, squared reach) and
    // its candidates, [begin, begin + count) of all candidates in triangle
    // and cell order (held packed: lookup_head_ / lookup_packed_); count 0 =
    // the triangle's grid if it has one (grid != kNoGrid), else the kd-tree.
    static constexpr uint32_t kNoGrid = UINT32_MAX;
    struct TriangleLookup {
        float cx, cy, cz, reach2;
        uint32_t begin, count;
        uint32_t grid;
    };
    // A triangle cut into s x s parallelogram slots of its (a, b) parameter
    // plane, p = o + a e1 + b e2; each slot holds a lower and an upper
    // sub-triangle, cells lookup_cells_[first + 2 (i s + j) + upper].  du and
    // dv give a = (p - o).du and b = (p - o).dv; slots past the triangle's
    // hypotenuse are empty cells (reach2 < 0).
    struct TriangleGrid {
        float ox, oy, oz, dux, duy, duz, dvx, dvy, dvz;
        uint32_t s, first;
    };
    // What the scan reads, laid out so that a lookup on a random hit costs
    // about one cache miss (a triangle, its candidates and their ids were
    // three arrays, a miss each).  A triangle's head is 128 bytes (two cache
    // lines, fetched together): its sphere, its candidate count and its
    // first kInlineCandidates candidates, where the scan usually stops; the
    // rest follow in lookup_packed_[more...].  A cell's block in
    // lookup_packed_ is a header entry (x, y, z = centre, w = squared
    // reach, id = candidate count) followed by its candidates.  A candidate
    // entry: x, y, z = position, w = distance from the centre (entries
    // sorted as above), id = the global surfel index.
    struct PackedEntry {
        float x, y, z, w;
        uint32_t id;
    };
    static constexpr uint32_t kInlineCandidates = 5;
    // count 0: `more` is kGridBit | grid index for a triangle cut into
    // cells, kNoBlock for the kd-tree.
    static constexpr uint32_t kNoBlock = UINT32_MAX, kGridBit = 0x80000000u;
    struct alignas(64) TriangleHead {
        float cx = 0, cy = 0, cz = 0, reach2 = 0;
        uint32_t count = 0, more = kNoBlock;
        PackedEntry first[kInlineCandidates] = {};
    };
    // More candidates than this (a triangle much larger than the surfel
    // spacing) and the triangle is cut into cells; a cell with more still
    // uses the kd-tree.
    static constexpr uint32_t kMaxCandidates = 48;
    // Cells aim at about this many candidates each; a grid has at most
    // kMaxGridSide slots a side.
    static constexpr uint32_t kCellCandidates = 12, kMaxGridSide = 128;

private:
    friend class SetupSnapshot;   // saves and restores the surfel half (setup_snapshot.h)
    struct Reuse;
    void build_lookup(int threads);
    // build_lookup's work in the calling thread's arena.
    void compute_lookup(const Reuse* reuse, const std::vector<uint8_t>* skip);
    // build_surfels' trees in the calling thread's arena (all_tree false:
    // not the tree over every surfel, which nearest() and smooth() need).
    void index_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                       bool all_tree = true);
    // The spheres are padded by 1e-6 x diagonal (rounded up to a power of two).
    void triangle_spheres(const Mesh& mesh, float diagonal);

    RTCDevice device_ = nullptr;
    RTCScene scene_ = nullptr;
    std::vector<int32_t> tri_surface_;
    int n_surfaces_ = 0;
    size_t n_surfels_ = 0;
    float sigma_ = 1;
    std::unique_ptr<Trees> trees_;
    std::vector<TriangleLookup> lookup_tri_;
    std::vector<float> lookup_vertices_;        // 9 per triangle: its corners
    std::vector<TriangleGrid> lookup_grids_;
    std::vector<TriangleLookup> lookup_cells_;
    // The packed form the scan reads (compute_lookup writes it straight
    // from its blocks).
    std::vector<PackedEntry, HugePageAllocator<PackedEntry>> lookup_packed_;
    std::vector<TriangleHead, HugePageAllocator<TriangleHead>> lookup_head_;  // per triangle
    std::vector<uint32_t> lookup_cell_at_;   // per cell: its block or kNoBlock
    // Per triangle: the squared radius (as searched) of the ball its
    // candidates came from; 0 where it has none of its own (cells, kd-tree).
    std::vector<float> lookup_ball2_;
    size_t lookup_n_candidates_ = 0, lookup_reused_ = 0;
    unsigned geom_id_ = 0;
    int geometry_builds_ = 0, surfel_builds_ = 0;
};

}  // namespace gammart
