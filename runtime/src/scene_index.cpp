// Embree BVH + per-surface surfel kd-trees (see gamma/scene_index.h).
#include "gamma/scene_index.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

#include "gamma/error.h"
#include "gamma/float_points.h"
#include "gamma/gmath.h"
#include "gamma/lookup_pruning.h"
#include "gamma/point_columns.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

// kd-tree over a point set; `index` maps to global surfel ids (empty = identity).
struct PointTree {
    std::vector<float> pos;
    std::vector<uint32_t> index;
    FloatPoints cloud;
    std::unique_ptr<FloatPointsKdTree> kd;

    void build() {
        cloud = {pos.data(), pos.size() / 3};
        kd = cloud.n ? std::make_unique<FloatPointsKdTree>(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10))
                      : nullptr;
    }
    uint32_t query(const float p[3]) const {
        uint32_t idx = 0;
        float d2 = 0;
        nanoflann::KNNResultSet<float, uint32_t> rs(1);
        rs.init(&idx, &d2);
        kd->findNeighbors(rs, p, nanoflann::SearchParams());
        return index.empty() ? idx : index[idx];
    }
};

// Candidates of a sphere tested against its nearest this many surfels when
// the lookup drops the ones that can never be the nearest.
constexpr size_t kPruningSurfels = LookupPruning::kNearest;
// The lookup's column index: columns this many surfel spacings wide; the
// nearest surfel to a sphere's centre searched first within this many
// spacings, doubled up to kNearestAttempts times (then the kd-tree).
// (Columns 4 spacings wide rather than 2: a search meets fewer columns, and
// their points are scanned four at a time.)
constexpr double kColumnSpacings = 4.0, kNearestStartSpacings = 1.0;
constexpr int kNearestAttempts = 4;

}  // namespace

struct SceneIndex::Trees {
    PointTree all;                  // every surfel
    std::vector<PointTree> surface; // per surface id
    std::vector<int32_t> surface_of;  // per surfel: its surface id
    // The surface that holds every surfel, when `all` is built (-1 if none):
    // its own tree would be `all` again (the same points in the same order,
    // so the same tree and answers), so `all` serves it and its entry in
    // `surface` stays empty.
    int whole = -1;
    const PointTree& of(int s) const { return s == whole ? all : surface[size_t(s)]; }
    // The surfel index of point i of tree t.
    static uint32_t surfel(const PointTree& t, uint32_t i) { return t.index.empty() ? i : t.index[i]; }
};

SceneFrame SceneFrame::of(const Mesh& mesh, std::array<float, 3> down) {
    SceneFrame f;
    const float diag = mesh.diagonal();
    f.diag = diag;
    f.lo = mesh.lo;
    f.hi = mesh.hi;
    f.centre = {0.5f * (mesh.lo[0] + mesh.hi[0]), 0.5f * (mesh.lo[1] + mesh.hi[1]),
                0.5f * (mesh.lo[2] + mesh.hi[2])};
    f.radius = 1.05f * 0.5f * diag;
    f.eps = 1e-5f * diag;
    f.down = unit(down);
    f.up = f.down * -1.0f;
    double mu = INFINITY;
    for (size_t i = 0; i < mesh.triangles.size(); ++i) {
        const float* v = &mesh.vertices[3 * size_t(mesh.triangles[i])];
        mu = std::min(mu, double(v[0]) * f.up.x + double(v[1]) * f.up.y + double(v[2]) * f.up.z);
    }
    f.min_up = float(mu);
    return f;
}

SceneIndex::SceneIndex() : trees_(std::make_unique<Trees>()) {}

SceneIndex::~SceneIndex() {
    if (scene_) rtcReleaseScene(scene_);
    if (device_) rtcReleaseDevice(device_);
}

void SceneIndex::build_geometry(const Mesh& mesh, std::vector<int32_t> tri_surface, int n_surfaces,
                                bool refresh_lookup) {
    const size_t m = mesh.num_triangles();
    if (tri_surface.size() != m) throw Error("scene index: one surface id per triangle expected");
    tri_surface_ = std::move(tri_surface);
    n_surfaces_ = n_surfaces;
    if (!device_) {
        device_ = rtcNewDevice(nullptr);
        if (!device_) throw std::runtime_error("internal error: embree cannot create a device");
    }
    if (scene_) {
        rtcReleaseScene(scene_);
        scene_ = nullptr;
    }
    scene_ = rtcNewScene(device_);
    rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_HIGH);
    float* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                            3 * sizeof(float), mesh.num_vertices()));
    uint32_t* ib = static_cast<uint32_t*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), m));
    if (!vb || !ib) throw std::runtime_error("internal error: embree cannot allocate geometry buffers");
    std::memcpy(vb, mesh.vertices.data(), sizeof(float) * mesh.vertices.size());
    for (size_t i = 0; i < 3 * m; ++i) ib[i] = uint32_t(mesh.triangles[i]);
    lookup_tri_.assign(m, TriangleLookup{0, 0, 0, 0, 0, 0, kNoGrid});
    triangle_spheres(mesh, mesh.diagonal());
    lookup_grids_.clear();
    lookup_cells_.clear();
    lookup_packed_.clear();
    lookup_cell_at_.clear();
    lookup_head_.clear();   // no lookup until the surfels are searched: the kd-tree answers
    lookup_n_candidates_ = 0;
    rtcCommitGeometry(geom);
    geom_id_ = rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE)
        throw std::runtime_error("internal error: embree scene build failed");
    ++geometry_builds_;
    // The candidates depend on both halves: refresh them if the surfels are
    // already indexed for these surfaces.
    if (refresh_lookup && n_surfels_ > 0 && trees_->surface.size() == size_t(n_surfaces_)) build_lookup(0);
}

// Bounding sphere of each triangle (centroid, farthest vertex) and its
// corners for the triangle lookup; the reach is padded so a hit point a
// rounding error off the triangle still counts as on it.  Keeps each
// triangle's candidates.
void SceneIndex::triangle_spheres(const Mesh& mesh, float diagonal) {
    const size_t m = mesh.num_triangles();
    lookup_tri_.resize(m, TriangleLookup{0, 0, 0, 0, 0, 0, kNoGrid});
    lookup_vertices_.resize(9 * m);
    // 1e-6 x the diagonal rounded up to a power of two: meshes whose bounds
    // differ a little (a displacement, a local re-tiling) get the same
    // spheres, so the entries of a lookup built ahead still fit.
    int e = 0;
    std::frexp(diagonal, &e);
    const float pad = 1e-6f * std::ldexp(1.0f, e);
    for (size_t t = 0; t < m; ++t) {
        const float* v[3];
        for (int k = 0; k < 3; ++k) v[k] = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + k])];
        for (int k = 0; k < 3; ++k) std::copy(v[k], v[k] + 3, lookup_vertices_.begin() + std::ptrdiff_t(9 * t + 3 * k));
        double c[3];
        for (int d = 0; d < 3; ++d) c[d] = (double(v[0][d]) + v[1][d] + v[2][d]) / 3.0;
        double r2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double dx = v[k][0] - c[0], dy = v[k][1] - c[1], dz = v[k][2] - c[2];
            r2 = std::max(r2, dx * dx + dy * dy + dz * dz);
        }
        const double reach = std::sqrt(r2) * (1.0 + 1e-5) + pad;
        TriangleLookup& L = lookup_tri_[t];
        L.cx = float(c[0]);
        L.cy = float(c[1]);
        L.cz = float(c[2]);
        L.reach2 = float(reach * reach);
    }
    // The heads follow (the candidates stay stale until the surfels are
    // searched again, as documented for move_vertices).
    if (lookup_head_.size() == m)
        for (size_t t = 0; t < m; ++t) {
            const TriangleLookup& L = lookup_tri_[t];
            TriangleHead& h = lookup_head_[t];
            h.cx = L.cx, h.cy = L.cy, h.cz = L.cz, h.reach2 = L.reach2;
        }
}

void SceneIndex::move_vertices(const Mesh& mesh) {
    if (!scene_ || mesh.num_triangles() != tri_surface_.size())
        throw Error("scene index: move_vertices needs the mesh the index was built on, with moved vertices");
    RTCGeometry geom = rtcGetGeometry(scene_, geom_id_);
    float* vb = static_cast<float*>(rtcGetGeometryBufferData(geom, RTC_BUFFER_TYPE_VERTEX, 0));
    if (!vb) throw std::runtime_error("internal error: embree vertex buffer missing");
    std::memcpy(vb, mesh.vertices.data(), sizeof(float) * mesh.vertices.size());
    rtcUpdateGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(geom);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE)
        throw std::runtime_error("internal error: embree scene update failed");
    triangle_spheres(mesh, mesh.diagonal());
    ++geometry_builds_;
}

void SceneIndex::index_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                               bool all_tree) {
    Trees& T = *trees_;
    n_surfels_ = n;
    sigma_ = sigma;
    T.all.pos.assign(positions, positions + 3 * n);
    T.all.index.clear();
    T.surface.clear();  // trees point into their own pos: never copied or moved once built
    T.surface.resize(size_t(n_surfaces_));
    T.surface_of.assign(surfel_surface, surfel_surface + n);
    const int first = n > 0 ? surfel_surface[0] : -1;
    T.whole = all_tree && first >= 0 && first < n_surfaces_ &&
                      std::all_of(surfel_surface, surfel_surface + n, [&](int32_t s) { return s == first; })
                  ? first
                  : -1;
    for (size_t i = 0; i < n && T.whole < 0; ++i) {
        const int s = surfel_surface[i];
        if (s < 0 || s >= n_surfaces_) throw Error("scene index: surfel surface id out of range");
        PointTree& t = T.surface[size_t(s)];
        t.index.push_back(uint32_t(i));
        t.pos.insert(t.pos.end(), positions + 3 * i, positions + 3 * i + 3);
    }
    // The trees are independent (each build is serial and deterministic):
    // built side by side.
    tbb::parallel_for(size_t(all_tree ? 0 : 1), T.surface.size() + 1,
                      [&](size_t k) { (k == 0 ? T.all : T.surface[k - 1]).build(); });
    ++surfel_builds_;
}

// What build_surfels takes from a lookup built ahead (see scene_index.h):
// the surfels that differ between the two indices, at both positions.
struct SceneIndex::Reuse {
    const SceneIndex& ahead;
    const std::vector<int32_t>& ahead_triangle;
    PointColumns changed;

    // Triangle t (sphere L) takes ahead's entries, appended to cand / ids
    // (L.begin, L.count set; ball2 = the ball's squared radius), when they
    // are what collect() would make here.
    bool take(const SceneIndex& here, size_t t, TriangleLookup& L, std::vector<Candidate>& cand,
              std::vector<uint32_t>& ids, float& ball2) const {
        const SceneIndex& A = ahead;
        if (t >= ahead_triangle.size() || ahead_triangle[t] < 0) return false;
        const size_t d = size_t(ahead_triangle[t]);
        if (d >= A.lookup_head_.size() || A.tri_surface_[d] != here.tri_surface_[t]) return false;
        if (std::memcmp(&A.lookup_vertices_[9 * d], &here.lookup_vertices_[9 * t], 9 * sizeof(float)) != 0)
            return false;
        const TriangleHead& h = A.lookup_head_[d];
        const float b2 = A.lookup_ball2_[d];
        const float sphere[4] = {L.cx, L.cy, L.cz, L.reach2}, ahead_sphere[4] = {h.cx, h.cy, h.cz, h.reach2};
        if (h.count == 0 || !(b2 > 0) || std::memcmp(sphere, ahead_sphere, sizeof sphere) != 0) return false;
        // A surfel that moved, came, left or changed surface inside the
        // ball could change the nearest distance, the ball or the set.
        bool touched = false;
        changed.within(sphere, b2, [&](uint32_t, float) { touched = true; });
        if (touched) return false;
        L.begin = uint32_t(cand.size());
        L.count = h.count;
        for (uint32_t k = 0; k < h.count; ++k) {
            const PackedEntry& e = k < kInlineCandidates ? h.first[k] : A.lookup_packed_[h.more + k - kInlineCandidates];
            cand.push_back(Candidate{e.x, e.y, e.z, e.w});
            ids.push_back(e.id);
        }
        ball2 = b2;
        return true;
    }
};

void SceneIndex::build_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                               int threads, const SceneIndex* ahead, const std::vector<int32_t>* ahead_triangle) {
    run_with_threads(threads, [&] {
        index_surfels(positions, surfel_surface, n, sigma);
        const Trees& T = *trees_;
        if (!ahead || !ahead_triangle || ahead->n_surfels_ != n || ahead->n_surfaces_ != n_surfaces_ ||
            ahead->lookup_ball2_.size() != ahead->lookup_head_.size()) {
            compute_lookup(nullptr, nullptr);
            return;
        }
        Reuse reuse{*ahead, *ahead_triangle, {}};
        const Trees& A = *ahead->trees_;
        std::vector<float> changed;
        for (size_t i = 0; i < n; ++i) {
            if (A.surface_of[i] == T.surface_of[i] &&
                std::memcmp(&A.all.pos[3 * i], &T.all.pos[3 * i], 3 * sizeof(float)) == 0)
                continue;
            changed.insert(changed.end(), &A.all.pos[3 * i], &A.all.pos[3 * i] + 3);
            changed.insert(changed.end(), &T.all.pos[3 * i], &T.all.pos[3 * i] + 3);
        }
        reuse.changed.build(changed.data(), changed.size() / 3, kColumnSpacings * double(sigma_));
        compute_lookup(&reuse, nullptr);
    });
}

void SceneIndex::build_lookup_ahead(const Mesh& mesh, std::vector<int32_t> tri_surface, int n_surfaces,
                                    const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                                    const std::vector<uint8_t>& skip) {
    if (tri_surface.size() != mesh.num_triangles() || skip.size() != mesh.num_triangles())
        throw Error("scene index: one surface id and one flag per triangle expected");
    tri_surface_ = std::move(tri_surface);
    n_surfaces_ = n_surfaces;
    // The spheres' pad as the re-tiled mesh's own diagonal gives it (the
    // same unless the re-tiling moved the bounds).
    triangle_spheres(mesh, float(mesh.used_diagonal()));
    index_surfels(positions, surfel_surface, n, sigma, /*all_tree=*/false);   // the lookup needs the surfaces' trees
    compute_lookup(nullptr, &skip);
}

void SceneIndex::move_surfels(const float* positions, float sigma, int threads) {
    Trees& T = *trees_;
    const size_t n = n_surfels_;
    sigma_ = sigma;
    T.all.pos.assign(positions, positions + 3 * n);
    T.all.build();
    for (PointTree& t : T.surface) {
        for (size_t k = 0; k < t.index.size(); ++k)
            std::memcpy(&t.pos[3 * k], positions + 3 * size_t(t.index[k]), 3 * sizeof(float));
        t.build();
    }
    ++surfel_builds_;
    build_lookup(threads);  // searched again: the pruned candidates hold only for the old positions
}

// For a sphere (c, reach) on surface s (a triangle's or a cell's bounding
// sphere) and q the surfel of s nearest to c (distance d0): a point p with
// |p - c| <= reach has its nearest surfel y* within |p - q| <= reach + d0 of
// p, so |c - y*| <= 2 reach + d0.  The candidates are the surfels of s in
// that ball (padded for rounding), so a scan finds the kd-tree's answer.  Of
// these, the ones farther than another candidate everywhere in the sphere
// are left out (they can never be the answer).
// A triangle with more than kMaxCandidates is cut into cells (a grid of
// sub-triangles, about kCellCandidates each); which cell a point is looked up
// in needs no exactness, since a point outside the cell's sphere goes to the
// kd-tree.
namespace {
struct LookupBlock {
    std::vector<SceneIndex::Candidate> cand;
    std::vector<uint32_t> ids;
    std::vector<SceneIndex::TriangleGrid> grids;
    std::vector<SceneIndex::TriangleLookup> cells;
    size_t reused = 0;
};
}  // namespace

namespace {

// The candidates of lookup spheres (compute_lookup's search): one per thread,
// its buffers reused from sphere to sphere.
class SphereCandidates {
public:
    explicit SphereCandidates(double spacing) : spacing_(spacing) {}

    // The candidates of sphere L (surface tree): appended to the block,
    // L.begin block-relative; their number (L left empty) if more than
    // `limit`.  ball2: the squared radius searched (where L got entries).
    size_t collect(const PointTree& tree, const PointColumns& cols, SceneIndex::TriangleLookup& L, size_t limit,
                   float* ball2, LookupBlock& out) {
        L.begin = 0;
        L.count = 0;
        const float c[3] = {L.cx, L.cy, L.cz};
        // The distance to the nearest surfel: the least of the
        // surfels closer than rho, if there are any (every
        // other one is farther); rho grows until some are, then
        // the kd-tree answers.
        float q2 = INFINITY;
        double rho = kNearestStartSpacings * spacing_;
        for (int attempt = 0; attempt < kNearestAttempts && q2 == INFINITY; ++attempt, rho *= 2.0)
            cols.within(c, float(rho * rho), [&](uint32_t, float d2) { q2 = std::min(q2, d2); });
        if (q2 == INFINITY) {
            uint32_t q = 0;
            nanoflann::KNNResultSet<float, uint32_t> rs(1);
            rs.init(&q, &q2);
            tree.kd->findNeighbors(rs, c, nanoflann::SearchParams());
        }
        const double R = (2.0 * std::sqrt(double(L.reach2)) + std::sqrt(double(q2))) * (1.0 + 1e-5);
        const float R2 = float(R * R);
        found_.clear();
        cols.append_within(c, R2, found_, [](uint32_t i, float d2) { return distance_key(d2, i); });
        // Drop the surfels that are never the nearest in the
        // sphere B(c, r): y loses to x everywhere in B when
        // |c-y|^2 - |c-x|^2 > 2 r |y-x| (the largest of
        // |p-x|^2 - |p-y|^2 over B), here with a margin far above
        // float rounding, so the scan's answer (ties included)
        // is unchanged.  x: the few surfels nearest to c.
        // Only which surfels are the kPruningSurfels nearest
        // matters, not their order (a surfel is dropped when any
        // x beats it; the kept ones are sorted below), and the
        // keys are distinct: selected, not sorted (sorting every
        // sphere's surfels is work nobody reads; bench/RESULTS.md).
        // The nx least, kept sorted while the rest pass by (few
        // enter once the first are in), are put first, the rest
        // after them in their order: cheaper than nth_element's
        // partitions (their order does not matter, as above).
        const size_t nx = std::min(found_.size(), kPruningSurfels);
        if (found_.size() > nx) {
            uint64_t least[kPruningSurfels];
            for (size_t k = 0; k < nx; ++k) {
                size_t j = k;
                for (; j > 0 && least[j - 1] > found_[k]; --j) least[j] = least[j - 1];
                least[j] = found_[k];
            }
            for (size_t p = nx; p < found_.size(); ++p) {
                const uint64_t f = found_[p];
                if (!(f < least[nx - 1])) continue;
                size_t j = nx - 1;
                for (; j > 0 && least[j - 1] > f; --j) least[j] = least[j - 1];
                least[j] = f;
            }
            const uint64_t cut = least[nx - 1];
            kept_.resize(found_.size() + 1);   // (+1: the write after the last one past the cut)
            std::copy(least, least + nx, kept_.begin());
            size_t m = nx;
            for (const uint64_t f : found_) {
                kept_[m] = f;
                m += f > cut;
            }
            kept_.resize(m);
            found_.swap(kept_);
        }
        const double r = std::sqrt(double(L.reach2));
        LookupPruning::Nearest X;
        for (size_t k = 0; k < nx; ++k)
            X.set(k, &tree.pos[3 * size_t(key_index(found_[k]))], key_distance(found_[k]));
        X.close(nx);
        kept_.resize(found_.size());
        kept_.resize(LookupPruning::keep(X, found_.data(), found_.size(), tree.pos.data(), r, kept_.data()));
        found_.swap(kept_);
        if (found_.size() > limit || found_.empty()) return found_.size();
        if (ball2) *ball2 = R2;
        L.count = uint32_t(found_.size());
        L.begin = uint32_t(out.cand.size());
        // entries sorted by (distance from the centre, surfel
        // index): distinct keys (the indices are), so the order
        // is fixed.  They are few (at most `limit`): an insertion
        // sort of (key, point) in place beats std::sort over
        // pairs and the staging copies it needed.
        order_.resize(found_.size());
        for (size_t k = 0; k < found_.size(); ++k) {
            const uint32_t i = key_index(found_[k]);
            const float* pp = &tree.pos[3 * size_t(i)];
            const float dx = pp[0] - c[0], dy = pp[1] - c[1], dz = pp[2] - c[2];
            const Ordered e{distance_key(std::sqrt(dx * dx + dy * dy + dz * dz), SceneIndex::Trees::surfel(tree, i)), i};
            size_t j = k;
            for (; j > 0 && order_[j - 1].key > e.key; --j) order_[j] = order_[j - 1];
            order_[j] = e;
        }
        // appended, not resized and then overwritten (a resize
        // writes every new entry twice)
        for (size_t k = 0; k < order_.size(); ++k) {
            const float* pp = &tree.pos[3 * size_t(order_[k].point)];
            out.cand.push_back(SceneIndex::Candidate{pp[0], pp[1], pp[2], key_distance(order_[k].key)});
            out.ids.push_back(key_index(order_[k].key));
        }
        return found_.size();
    }

private:
    struct Ordered {
        uint64_t key;    // distance_key(distance from the centre, surfel index)
        uint32_t point;  // of the tree
    };
    double spacing_;
    // distance_key(d2 from the centre, point of the tree)
    std::vector<uint64_t, HugePageAllocator<uint64_t>> found_, kept_;
    std::vector<Ordered> order_;
};

// A triangle (corners v, 9 floats) with too many candidates (n_found) cut
// into cells of about kCellCandidates each: its grid appended to the block
// and L.grid set (block-relative), or nothing for a degenerate triangle (the
// kd-tree answers there).
void cut_into_cells(SphereCandidates& sphere, const PointTree& tree, const PointColumns& cols, const float* v,
                    SceneIndex::TriangleLookup& L, size_t n_found, LookupBlock& out) {
    double o[3], e1[3], e2[3];
    for (int d = 0; d < 3; ++d) {
        o[d] = v[d];
        e1[d] = double(v[3 + d]) - v[d];
        e2[d] = double(v[6 + d]) - v[d];
    }
    const double g11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
    const double g12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2];
    const double g22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2];
    const double det = g11 * g22 - g12 * g12;
    if (!(det > 1e-30 * g11 * g22) || !std::isfinite(det)) return;  // degenerate: kd-tree
    // Side from the count (~kCellCandidates per cell if the
    // ball were all surface), doubled while a cell overflows.
    const double cells = std::ceil(std::sqrt(double(n_found) / SceneIndex::kCellCandidates));
    uint32_t side = uint32_t(std::min<double>(SceneIndex::kMaxGridSide, std::max(2.0, cells)));
    SceneIndex::TriangleGrid G;
    G.ox = v[0], G.oy = v[1], G.oz = v[2];
    G.dux = float((g22 * e1[0] - g12 * e2[0]) / det);
    G.duy = float((g22 * e1[1] - g12 * e2[1]) / det);
    G.duz = float((g22 * e1[2] - g12 * e2[2]) / det);
    G.dvx = float((g11 * e2[0] - g12 * e1[0]) / det);
    G.dvy = float((g11 * e2[1] - g12 * e1[1]) / det);
    G.dvz = float((g11 * e2[2] - g12 * e1[2]) / det);
    G.first = uint32_t(out.cells.size());  // block-relative until the offsets are known
    const size_t cand_mark = out.cand.size();
    const double pad = std::sqrt(double(L.reach2)) * 1e-5;
    for (;;) {
        auto at = [&](double a, double bb, double* p) {
            for (int d = 0; d < 3; ++d) p[d] = o[d] + (a * e1[d] + bb * e2[d]) / side;
        };
        size_t overflow = 0;
        for (uint32_t i = 0; i < side; ++i)
            for (uint32_t j = 0; j < side; ++j)
                for (int upper = 0; upper < 2; ++upper) {
                    SceneIndex::TriangleLookup C{0, 0, 0, -1.0f, 0, 0, SceneIndex::kNoGrid};
                    if (i + j + uint32_t(upper) <= side - 1) {
                        double p[3][3];
                        if (!upper) at(i, j, p[0]), at(i + 1, j, p[1]), at(i, j + 1, p[2]);
                        else at(i + 1, j, p[0]), at(i + 1, j + 1, p[1]), at(i, j + 1, p[2]);
                        double c[3], r2 = 0;
                        for (int d = 0; d < 3; ++d) c[d] = (p[0][d] + p[1][d] + p[2][d]) / 3.0;
                        for (int k = 0; k < 3; ++k) {
                            const double dx = p[k][0] - c[0], dy = p[k][1] - c[1],
                                         dz = p[k][2] - c[2];
                            r2 = std::max(r2, dx * dx + dy * dy + dz * dz);
                        }
                        const double reach = std::sqrt(r2) * (1.0 + 1e-5) + pad;
                        C = SceneIndex::TriangleLookup{float(c[0]), float(c[1]), float(c[2]), float(reach * reach),
                                                       0, 0, SceneIndex::kNoGrid};
                        const size_t found = sphere.collect(tree, cols, C, SceneIndex::kMaxCandidates, nullptr, out);
                        overflow += found > SceneIndex::kMaxCandidates;
                    }
                    out.cells.push_back(C);
                }
        if (overflow == 0 || side >= SceneIndex::kMaxGridSide) break;
        out.cand.resize(cand_mark);
        out.ids.resize(cand_mark);
        out.cells.resize(G.first);
        side = std::min(2 * side, SceneIndex::kMaxGridSide);
    }
    G.s = side;
    L.grid = uint32_t(out.grids.size());  // block-relative until the offsets are known
    out.grids.push_back(G);
}

}  // namespace

void SceneIndex::build_lookup(int threads) {
    run_with_threads(threads, [&] { compute_lookup(nullptr, nullptr); });
}

void SceneIndex::compute_lookup(const Reuse* reuse, const std::vector<uint8_t>* skip) {
    const Trees& T = *trees_;
    const size_t m = lookup_tri_.size();
    constexpr size_t kBlock = 512;  // triangles per work item (the layout depends on neither it nor the thread count)
    // Entries per triangle the blocks make room for: the bunny's lookup keeps
    // ~14 (a block that needs more grows as a vector does).
    constexpr size_t kReservedPerTriangle = 16;
    const size_t nblocks = (m + kBlock - 1) / kBlock;
    std::vector<LookupBlock> blocks(nblocks);
    lookup_ball2_.assign(m, 0.0f);
    // The candidates' searches go to a column index per surface (the same
    // sets as the surface's kd-tree gives, found with less pointer chasing),
    // built here and dropped after.
    std::vector<PointColumns> columns(T.surface.size());
    const double spacing = double(sigma_);
    tbb::parallel_for(size_t(0), T.surface.size(), [&](size_t s) {
        const PointTree& tree = T.of(int(s));
        columns[s].build(tree.pos.data(), tree.pos.size() / 3, kColumnSpacings * spacing);
    });
    {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
            SphereCandidates sphere(spacing);
            for (size_t b = r.begin(); b < r.end(); ++b) {
                LookupBlock& out = blocks[b];
                // Room for the block's entries up front: grown from empty, its
                // vectors were copied ~13 times each into fresh memory (~2,500
                // page faults of a 100,000-surfel bunny's lookup).
                const size_t block_triangles = std::min(m, (b + 1) * kBlock) - b * kBlock;
                out.cand.reserve(block_triangles * kReservedPerTriangle);
                out.ids.reserve(block_triangles * kReservedPerTriangle);
                // The candidates of sphere L (surface tree): appended to the
                // block, L.begin block-relative; false if more than `limit`.
                // ball2: the squared radius searched (where L got entries).
                for (size_t t = b * kBlock; t < std::min(m, (b + 1) * kBlock); ++t) {
                    TriangleLookup& L = lookup_tri_[t];
                    L.grid = kNoGrid;
                    const int s = tri_surface_[t];
                    if (!has_surfels(s) || (skip && (*skip)[t])) {
                        L.begin = L.count = 0;
                        continue;
                    }
                    if (reuse && reuse->take(*this, t, L, out.cand, out.ids, lookup_ball2_[t])) {
                        ++out.reused;
                        continue;
                    }
                    const PointTree& tree = T.of(s);
                    const PointColumns& cols = columns[size_t(s)];
                    const size_t n_found = sphere.collect(tree, cols, L, kMaxCandidates, &lookup_ball2_[t], out);
                    if (L.count || n_found == 0) continue;
                    cut_into_cells(sphere, tree, cols, &lookup_vertices_[9 * t], L, n_found, out);
                }
            }
        });
    }
    // The blocks laid out as the scan reads them (see TriangleHead): per
    // triangle its head, the candidates past the head's in triangle order,
    // then each cell's block in cell order -- the blocks' offsets counted
    // first, then every block written in parallel.
    constexpr uint32_t K = kInlineCandidates;
    struct BlockAt {
        size_t cand = 0, grids = 0, cells = 0, tail = 0, cell_entries = 0;
    };
    std::vector<BlockAt> at(nblocks + 1);
    tbb::parallel_for(size_t(0), nblocks, [&](size_t b) {
        const LookupBlock& B = blocks[b];
        BlockAt& n = at[b + 1];
        n.cand = B.cand.size(), n.grids = B.grids.size(), n.cells = B.cells.size();
        for (size_t t = b * kBlock; t < std::min(m, (b + 1) * kBlock); ++t)
            n.tail += lookup_tri_[t].count > K ? lookup_tri_[t].count - K : 0;
        for (const TriangleLookup& C : B.cells) n.cell_entries += C.count > 0 ? 1 + C.count : 0;
    });
    for (size_t b = 0; b < nblocks; ++b) {
        at[b + 1].cand += at[b].cand, at[b + 1].grids += at[b].grids, at[b + 1].cells += at[b].cells;
        at[b + 1].tail += at[b].tail, at[b + 1].cell_entries += at[b].cell_entries;
    }
    const size_t n_cand = at[nblocks].cand, tails = at[nblocks].tail;
    const size_t entries = tails + at[nblocks].cell_entries;
    if (n_cand > size_t(UINT32_MAX) || at[nblocks].cells > size_t(UINT32_MAX) || entries >= size_t(kGridBit) ||
        at[nblocks].grids >= size_t(kGridBit))
        throw Error("scene index: too many surfel candidates for the triangle lookup");
    lookup_reused_ = 0;
    for (const LookupBlock& B : blocks) lookup_reused_ += B.reused;
    lookup_grids_.resize(at[nblocks].grids);
    lookup_cells_.resize(at[nblocks].cells);
    lookup_cell_at_.assign(at[nblocks].cells, kNoBlock);
    // (the loop below writes every head and entry, in parallel)
    decltype(lookup_packed_) packed(entries);
    if (lookup_head_.size() != m) lookup_head_.resize(m);
    tbb::parallel_for(size_t(0), nblocks, [&](size_t b) {
        const LookupBlock& B = blocks[b];
        const BlockAt& a = at[b];
        auto entry = [&](uint32_t k) {   // k: block-relative
            const Candidate& c = B.cand[k];
            return PackedEntry{c.x, c.y, c.z, c.from_centre, B.ids[k]};
        };
        size_t tail = a.tail;
        for (size_t t = b * kBlock; t < std::min(m, (b + 1) * kBlock); ++t) {
            TriangleLookup& L = lookup_tri_[t];
            TriangleHead& h = lookup_head_[t];
            h = TriangleHead{};
            h.cx = L.cx, h.cy = L.cy, h.cz = L.cz, h.reach2 = L.reach2;
            h.count = L.count;
            if (L.grid != kNoGrid) L.grid += uint32_t(a.grids);
            if (L.count) {
                for (uint32_t k = 0; k < std::min(L.count, K); ++k) h.first[k] = entry(L.begin + k);
                h.more = L.count > K ? uint32_t(tail) : 0;
                for (uint32_t k = K; k < L.count; ++k) packed[tail++] = entry(L.begin + k);
                L.begin += uint32_t(a.cand);
            } else {
                h.more = L.grid != kNoGrid ? kGridBit | L.grid : kNoBlock;
            }
        }
        size_t block = tails + a.cell_entries;
        for (size_t c = 0; c < B.cells.size(); ++c) {
            TriangleLookup C = B.cells[c];
            if (C.count) {
                lookup_cell_at_[a.cells + c] = uint32_t(block);
                packed[block++] = PackedEntry{C.cx, C.cy, C.cz, C.reach2, C.count};
                for (uint32_t k = C.begin; k < C.begin + C.count; ++k) packed[block++] = entry(k);
                C.begin += uint32_t(a.cand);
            }
            lookup_cells_[a.cells + c] = C;
        }
        for (size_t g = 0; g < B.grids.size(); ++g) {
            TriangleGrid G = B.grids[g];
            G.first += uint32_t(a.cells);
            lookup_grids_[a.grids + g] = G;
        }
    });
    lookup_packed_.swap(packed);
    lookup_n_candidates_ = n_cand;
}

static_assert(sizeof(SceneIndex::PackedEntry) == 20, "packed lookup entries are 20 bytes");
static_assert(sizeof(SceneIndex::TriangleHead) == 128, "a triangle head is two cache lines");

namespace {
// The scan of one sphere's candidates for p: `first` (n_first entries), then
// `rest` (count - n_first); UINT32_MAX if p is outside the sphere.
inline uint32_t scan_sphere(const float p[3], float cx, float cy, float cz, float reach2, uint32_t count,
                            const SceneIndex::PackedEntry* first, uint32_t n_first,
                            const SceneIndex::PackedEntry* rest) {
    const float dx = p[0] - cx, dy = p[1] - cy, dz = p[2] - cz;
    const float to_centre2 = dx * dx + dy * dy + dz * dz;
    if (!(to_centre2 <= reach2)) return UINT32_MAX;
    const float to_centre = std::sqrt(to_centre2);
    float best = std::numeric_limits<float>::infinity(), cut = best;
    uint32_t id = UINT32_MAX;
    // false once no later entry can win or tie
    auto visit = [&](const SceneIndex::PackedEntry& e) {
        // |p - y| >= |c - y| - |p - c|: once that exceeds the best
        // distance (padded for rounding), no later entry can win or tie.
        if (e.w > cut) return false;
        // The kd-tree's metric, term by term: the same float distances.
        float a = p[0] - e.x;
        float d2 = 0.0f;
        d2 += a * a;
        a = p[1] - e.y;
        d2 += a * a;
        a = p[2] - e.z;
        d2 += a * a;
        if (d2 < best || (d2 == best && e.id < id)) {
            best = d2;
            id = e.id;
            cut = (to_centre + std::sqrt(best)) * 1.0001f + 1e-30f;
        }
        return true;
    };
    for (uint32_t k = 0; k < n_first; ++k)
        if (!visit(first[k])) return id;
    for (uint32_t k = 0; k < count - n_first; ++k)
        if (!visit(rest[k])) return id;
    return id;
}
}  // namespace

uint32_t SceneIndex::nearest_on_triangle(uint32_t prim, const float p[3]) const {
    const uint32_t id = lookup_scan(prim, p);
    if (id != UINT32_MAX) return id;
    return nearest_of(prim < tri_surface_.size() ? tri_surface_[prim] : -1, p);
}

uint32_t SceneIndex::lookup_scan(uint32_t prim, const float p[3]) const {
    if (prim >= lookup_head_.size()) return UINT32_MAX;
    const TriangleHead& h = lookup_head_[prim];
    // both lines of the head in flight at once
    __builtin_prefetch(reinterpret_cast<const char*>(&h) + 64);
    if (h.count) {
        constexpr uint32_t K = kInlineCandidates;
        const bool more = h.count > K;
        const PackedEntry* rest = more ? lookup_packed_.data() + h.more : nullptr;
        if (more) __builtin_prefetch(rest);
        return scan_sphere(p, h.cx, h.cy, h.cz, h.reach2, h.count, h.first, more ? K : h.count, rest);
    }
    if (h.more == kNoBlock) return UINT32_MAX;
    const TriangleGrid& G = lookup_grids_[h.more & ~kGridBit];
    const float qx = p[0] - G.ox, qy = p[1] - G.oy, qz = p[2] - G.oz;
    const float a = (qx * G.dux + qy * G.duy + qz * G.duz) * float(G.s);
    const float b = (qx * G.dvx + qy * G.dvy + qz * G.dvz) * float(G.s);
    const int smax = int(G.s) - 1;
    int i = std::isfinite(a) ? std::clamp(int(std::floor(std::clamp(a, -1.0f, float(G.s)))), 0, smax) : 0;
    int j = std::isfinite(b) ? std::clamp(int(std::floor(std::clamp(b, -1.0f, float(G.s)))), 0, smax) : 0;
    while (i + j > smax) (i > j ? i : j) -= 1;
    const bool upper = i + j < smax && (a - float(i)) + (b - float(j)) > 1.0f;
    const uint32_t cell = lookup_cell_at_[G.first + 2 * (uint32_t(i) * G.s + uint32_t(j)) + (upper ? 1 : 0)];
    if (cell == kNoBlock) return UINT32_MAX;
    const PackedEntry* c = lookup_packed_.data() + cell;
    __builtin_prefetch(reinterpret_cast<const char*>(c) + 64);
    return scan_sphere(p, c->x, c->y, c->z, c->w, c->id, c + 1, c->id, nullptr);
}

size_t SceneIndex::lookup_fallback_triangles() const {
    size_t n = 0;
    for (const TriangleLookup& L : lookup_tri_) n += L.count == 0 && L.grid == kNoGrid;
    return n;
}

bool SceneIndex::same_lookup(const SceneIndex& o) const {
    auto same_entry = [](const PackedEntry& a, const PackedEntry& b) {
        return std::memcmp(&a, &b, sizeof(PackedEntry)) == 0;   // 5 words, no padding
    };
    auto same_sphere = [](const TriangleLookup& a, const TriangleLookup& b) {
        return a.cx == b.cx && a.cy == b.cy && a.cz == b.cz && a.reach2 == b.reach2 && a.begin == b.begin &&
               a.count == b.count && a.grid == b.grid;
    };
    if (lookup_head_.size() != o.lookup_head_.size() || lookup_packed_.size() != o.lookup_packed_.size() ||
        lookup_grids_.size() != o.lookup_grids_.size() || lookup_cells_.size() != o.lookup_cells_.size() ||
        lookup_cell_at_ != o.lookup_cell_at_ || lookup_n_candidates_ != o.lookup_n_candidates_ ||
        lookup_ball2_ != o.lookup_ball2_)
        return false;
    for (size_t t = 0; t < lookup_head_.size(); ++t) {
        const TriangleHead &a = lookup_head_[t], &b = o.lookup_head_[t];
        if (a.cx != b.cx || a.cy != b.cy || a.cz != b.cz || a.reach2 != b.reach2 || a.count != b.count ||
            a.more != b.more)
            return false;
        for (uint32_t k = 0; k < std::min(a.count, kInlineCandidates); ++k)
            if (!same_entry(a.first[k], b.first[k])) return false;
        if (!same_sphere(lookup_tri_[t], o.lookup_tri_[t])) return false;
    }
    for (size_t k = 0; k < lookup_packed_.size(); ++k)
        if (!same_entry(lookup_packed_[k], o.lookup_packed_[k])) return false;
    for (size_t g = 0; g < lookup_grids_.size(); ++g)
        if (std::memcmp(&lookup_grids_[g], &o.lookup_grids_[g], sizeof(TriangleGrid)) != 0) return false;
    for (size_t c = 0; c < lookup_cells_.size(); ++c)
        if (!same_sphere(lookup_cells_[c], o.lookup_cells_[c])) return false;
    return true;
}

size_t SceneIndex::lookup_bytes() const {
    return lookup_tri_.capacity() * sizeof(TriangleLookup) + lookup_vertices_.capacity() * sizeof(float) +
           lookup_grids_.capacity() * sizeof(TriangleGrid) + lookup_cells_.capacity() * sizeof(TriangleLookup) +
           lookup_packed_.capacity() * sizeof(PackedEntry) + lookup_head_.capacity() * sizeof(TriangleHead) +
           lookup_cell_at_.capacity() * sizeof(uint32_t) + lookup_ball2_.capacity() * sizeof(float);
}

void SceneIndex::cast(RTCRayHit& rh, V3 org, V3 dir, float tnear, float tfar) const {
    rh.ray.org_x = org.x; rh.ray.org_y = org.y; rh.ray.org_z = org.z;
    rh.ray.dir_x = dir.x; rh.ray.dir_y = dir.y; rh.ray.dir_z = dir.z;
    rh.ray.tnear = tnear;
    rh.ray.tfar = tfar;
    rh.ray.time = 0;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    rtcIntersect1(scene_, &ictx, &rh);
}

bool SceneIndex::occluded(V3 org, V3 dir, float tnear, float tfar) const {
    RTCRay ray;
    ray.org_x = org.x; ray.org_y = org.y; ray.org_z = org.z;
    ray.dir_x = dir.x; ray.dir_y = dir.y; ray.dir_z = dir.z;
    ray.tnear = tnear;
    ray.tfar = tfar;
    ray.time = 0;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    rtcOccluded1(scene_, &ictx, &ray);
    return ray.tfar < 0;  // Embree sets tfar = -inf on a hit
}

uint32_t SceneIndex::nearest(const float p[3]) const { return trees_->all.query(p); }

const FloatPointsKdTree* SceneIndex::surfel_tree() const { return trees_->all.kd.get(); }

bool SceneIndex::has_surfels(int surface) const {
    return surface >= 0 && surface < n_surfaces_ && trees_->of(surface).kd != nullptr;
}

uint32_t SceneIndex::nearest_of(int surface, const float p[3]) const {
    if (!has_surfels(surface)) return nearest(p);
    return trees_->of(surface).query(p);
}

std::vector<size_t> SceneIndex::surfels_per_surface() const {
    std::vector<size_t> n;
    for (size_t s = 0; s < trees_->surface.size(); ++s)
        n.push_back(int(s) == trees_->whole ? n_surfels_ : trees_->surface[s].index.size());
    return n;
}

namespace {

// smooth()'s weights of the neighbours found (their squared distances d2),
// and its underflow rule; returns the count.
size_t smoothing_weights_of(const float* d2, size_t got, double inv2s2, double* w) {
    double sw = 0;
    for (size_t j = 0; j < got; ++j) {
        w[j] = double(gm::exp(float(-double(d2[j]) * inv2s2)));
        sw += w[j];
    }
    if (sw > 0) {
        for (size_t j = 0; j < got; ++j) w[j] /= sw;
        return got;
    }
    w[0] = 1.0;  // every weight underflowed: the nearest surfel alone
    return 1;
}

}  // namespace

size_t SceneIndex::smooth(int surface, const float p[3], uint32_t* idx, double* w) const {
    constexpr size_t K = kSmoothingNeighbours;
    const PointTree* tree = &trees_->all;
    if (has_surfels(surface)) tree = &trees_->of(surface);
    const size_t count = tree->cloud.n;
    float d2[K];
    nanoflann::KNNResultSet<float, uint32_t> rs(std::min(K, count));
    rs.init(idx, d2);
    tree->kd->findNeighbors(rs, p, nanoflann::SearchParams());
    const size_t got = smoothing_weights_of(d2, rs.size(), 1.0 / (2.0 * double(sigma_) * double(sigma_)), w);
    if (!tree->index.empty())
        for (size_t j = 0; j < got; ++j) idx[j] = tree->index[idx[j]];
    return got;
}


void SceneIndex::smooth_block(int surface, const float* points, size_t n, uint32_t* idx, double* w,
                              uint8_t* counts) const {
    constexpr size_t K = kSmoothingNeighbours;
    if (n == 0) return;
    const PointTree* tree = &trees_->all;
    if (has_surfels(surface)) tree = &trees_->of(surface);
    const size_t count = tree->cloud.n;
    const size_t k = std::min(K, count);
    // The block's centre and radius, in double so the bound is not cut short.
    double c[3] = {0, 0, 0};
    for (size_t i = 0; i < n; ++i)
        for (int d = 0; d < 3; ++d) c[d] += double(points[3 * i + d]);
    for (double& x : c) x /= double(n);
    double r2 = 0;
    for (size_t i = 0; i < n; ++i) {
        double e = 0;
        for (int d = 0; d < 3; ++d) e += (double(points[3 * i + d]) - c[d]) * (double(points[3 * i + d]) - c[d]);
        r2 = std::max(r2, e);
    }
    const float cf[3] = {float(c[0]), float(c[1]), float(c[2])};
    uint32_t near[K];
    float near_d2[K];
    nanoflann::KNNResultSet<float, uint32_t> first(k);
    first.init(near, near_d2);
    tree->kd->findNeighbors(first, cf, nanoflann::SearchParams());
    // Every point's k nearest lie within d_k(c) + 2 r of c (triangle
    // inequality), padded for float rounding of the distances.
    const double reach = (std::sqrt(double(near_d2[first.size() - 1])) + 2.0 * std::sqrt(r2)) * (1.0 + 1e-4) +
                         1e-6 * double(sigma_);
    std::vector<std::pair<uint32_t, float>> found;
    tree->kd->radiusSearch(cf, float(reach * reach), found, nanoflann::SearchParams(32, 0.0f, false));
    // Each point keeps the k candidates smallest in (squared distance, index):
    // what nanoflann's KNNResultSet keeps when they come in index order (it
    // takes a candidate only if strictly nearer than its worst, and places it
    // after those as near), but in any order.  They come nearest to the
    // block's centre first, so few are taken and then dropped, and a point
    // stops at the first candidate that cannot be among its k (triangle
    // inequality, with a margin far above the float distances' rounding).
    const double inv2s2 = 1.0 / (2.0 * double(sigma_) * double(sigma_));
    const float* cloud = tree->cloud.p;
    const size_t m = found.size();
    thread_local std::vector<std::pair<double, uint32_t>> order;
    thread_local std::vector<float> xs, ys, zs;
    thread_local std::vector<double> centre_distance;
    thread_local std::vector<uint32_t> ids;
    order.resize(m);
    for (size_t a = 0; a < m; ++a) {
        const float* q = cloud + 3 * size_t(found[a].first);
        double e = 0;
        for (int d = 0; d < 3; ++d) e += (double(q[d]) - c[d]) * (double(q[d]) - c[d]);
        order[a] = {std::sqrt(e), found[a].first};
    }
    std::sort(order.begin(), order.end());
    xs.resize(m);
    ys.resize(m);
    zs.resize(m);
    centre_distance.resize(m);
    ids.resize(m);
    for (size_t a = 0; a < m; ++a) {
        const float* q = cloud + 3 * size_t(order[a].second);
        xs[a] = q[0];
        ys[a] = q[1];
        zs[a] = q[2];
        centre_distance[a] = order[a].first;
        ids[a] = order[a].second;
    }
    for (size_t i = 0; i < n; ++i) {
        const float* p = points + 3 * i;
        uint32_t* out = idx + K * i;
        float d2[K];
        double rp = 0;
        for (int d = 0; d < 3; ++d) rp += (double(p[d]) - c[d]) * (double(p[d]) - c[d]);
        rp = std::sqrt(rp);
        const float px = p[0], py = p[1], pz = p[2];
        size_t got_k = 0;
        for (size_t q = 0; q < m; ++q) {
            if (got_k == k) {
                if (k == 0) break;
                const double bound = centre_distance[q] - rp;   // |p - candidate| >= bound
                if (bound > 0 && bound * bound > double(d2[k - 1]) * (1.0 + 1e-5) + 1e-30) break;
            }
            // nanoflann's L2_Simple_Adaptor, operation for operation: ((0 + dx²) + dy²) + dz²
            const float dx = px - xs[q], dy = py - ys[q], dz = pz - zs[q];
            const float dist = dx * dx + dy * dy + dz * dz;
            const uint32_t j = ids[q];
            if (got_k == k) {
                if (!(dist < d2[k - 1] || (dist == d2[k - 1] && j < out[k - 1]))) continue;
            } else if (!(dist < std::numeric_limits<float>::max())) {
                continue;                                        // KNNResultSet's empty worst
            }
            size_t at = got_k < k ? got_k : k - 1;
            while (at > 0 && (d2[at - 1] > dist || (d2[at - 1] == dist && out[at - 1] > j))) {
                d2[at] = d2[at - 1];
                out[at] = out[at - 1];
                --at;
            }
            d2[at] = dist;
            out[at] = j;
            if (got_k < k) ++got_k;
        }
        const size_t got = smoothing_weights_of(d2, got_k, inv2s2, w + K * i);
        counts[i] = uint8_t(got);
        if (!tree->index.empty())
            for (size_t j = 0; j < got; ++j) out[j] = tree->index[out[j]];
    }
}

}  // namespace gammart
