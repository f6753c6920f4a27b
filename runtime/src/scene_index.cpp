// Embree BVH + per-surface surfel kd-trees (see gamma/scene_index.h).
#include "gamma/scene_index.h"

#include <nanoflann.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

struct Cloud {
    const float* p = nullptr;
    size_t n = 0;
    size_t kdtree_get_point_count() const { return n; }
    float kdtree_get_pt(size_t i, size_t d) const { return p[3 * i + d]; }
    template <class BBOX>
    bool kdtree_get_bbox(BBOX&) const { return false; }
};
using KDTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>,
                                                   Cloud, 3, uint32_t>;

// kd-tree over a point set; `index` maps to global surfel ids (empty = identity).
struct PointTree {
    std::vector<float> pos;
    std::vector<uint32_t> index;
    Cloud cloud;
    std::unique_ptr<KDTree> kd;

    void build() {
        cloud = {pos.data(), pos.size() / 3};
        kd = cloud.n ? std::make_unique<KDTree>(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10)) : nullptr;
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

// Candidates of a triangle tested against its nearest this many surfels
// when the lookup drops the ones that can never be the nearest.
constexpr size_t kPruningSurfels = 8;

V3 unit(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return {float(a[0] / l), float(a[1] / l), float(a[2] / l)};
}

}  // namespace

struct SceneIndex::Trees {
    PointTree all;                  // every surfel
    std::vector<PointTree> surface; // per surface id
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
    // Bounding sphere of each triangle (centroid, farthest vertex) for the
    // triangle lookup; the reach is padded so a hit point a rounding error
    // off the triangle still counts as on it.
    lookup_tri_.assign(m, TriangleLookup{0, 0, 0, 0, 0, 0});
    const float pad = 1e-6f * mesh.diagonal();
    for (size_t t = 0; t < m; ++t) {
        const float* v[3];
        for (int k = 0; k < 3; ++k) v[k] = &mesh.vertices[3 * size_t(mesh.triangles[3 * t + k])];
        double c[3];
        for (int d = 0; d < 3; ++d) c[d] = (double(v[0][d]) + v[1][d] + v[2][d]) / 3.0;
        double r2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double dx = v[k][0] - c[0], dy = v[k][1] - c[1], dz = v[k][2] - c[2];
            r2 = std::max(r2, dx * dx + dy * dy + dz * dz);
        }
        const double reach = std::sqrt(r2) * (1.0 + 1e-5) + pad;
        lookup_tri_[t] = TriangleLookup{float(c[0]), float(c[1]), float(c[2]), float(reach * reach), 0, 0};
    }
    lookup_cand_.clear();
    lookup_ids_.clear();
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE)
        throw std::runtime_error("internal error: embree scene build failed");
    ++geometry_builds_;
    // The candidates depend on both halves: refresh them if the surfels are
    // already indexed for these surfaces.
    if (refresh_lookup && n_surfels_ > 0 && trees_->surface.size() == size_t(n_surfaces_)) build_lookup(0);
}

void SceneIndex::build_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma,
                               int threads) {
    Trees& T = *trees_;
    n_surfels_ = n;
    sigma_ = sigma;
    T.all.pos.assign(positions, positions + 3 * n);
    T.all.index.clear();
    T.surface.clear();  // trees hold references into their own Cloud: never copied or moved once built
    T.surface.resize(size_t(n_surfaces_));
    for (size_t i = 0; i < n; ++i) {
        const int s = surfel_surface[i];
        if (s < 0 || s >= n_surfaces_) throw Error("scene index: surfel surface id out of range");
        PointTree& t = T.surface[size_t(s)];
        t.index.push_back(uint32_t(i));
        t.pos.insert(t.pos.end(), positions + 3 * i, positions + 3 * i + 3);
    }
    // The trees are independent (each build is serial and deterministic):
    // built side by side.
    run_with_threads(threads, [&] {
        tbb::parallel_for(size_t(0), T.surface.size() + 1,
                          [&](size_t k) { (k == 0 ? T.all : T.surface[k - 1]).build(); });
    });
    ++surfel_builds_;
    build_lookup(threads);
}

// For triangle t of surface s with bounding sphere (c, reach) and q the
// surfel of s nearest to c (distance d0): a point p with |p - c| <= reach has
// its nearest surfel y* within |p - q| <= reach + d0 of p, so
// |c - y*| <= 2 reach + d0.  The candidates are the surfels of s in that ball
// (padded for rounding), so the scan finds the kd-tree's answer.  Of these,
// the ones that are farther than another candidate everywhere in the ball
// are left out (they can never be the answer).
void SceneIndex::build_lookup(int threads) {
    const Trees& T = *trees_;
    const size_t m = lookup_tri_.size();
    constexpr size_t kBlock = 2048;  // triangles per work item (fixed: the result is thread-count free)
    const size_t nblocks = (m + kBlock - 1) / kBlock;
    std::vector<std::vector<Candidate>> block_cand(nblocks);
    std::vector<std::vector<uint32_t>> block_ids(nblocks);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, nblocks, 1), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<std::pair<uint32_t, float>> found, kept;
            for (size_t b = r.begin(); b < r.end(); ++b) {
                std::vector<Candidate>& out = block_cand[b];
                std::vector<uint32_t>& out_ids = block_ids[b];
                for (size_t t = b * kBlock; t < std::min(m, (b + 1) * kBlock); ++t) {
                    TriangleLookup& L = lookup_tri_[t];
                    L.begin = 0;
                    L.count = 0;
                    const int s = tri_surface_[t];
                    if (!has_surfels(s)) continue;
                    const PointTree& tree = T.surface[size_t(s)];
                    const float c[3] = {L.cx, L.cy, L.cz};
                    uint32_t q = 0;
                    float q2 = 0;
                    nanoflann::KNNResultSet<float, uint32_t> rs(1);
                    rs.init(&q, &q2);
                    tree.kd->findNeighbors(rs, c, nanoflann::SearchParams());
                    const double R = (2.0 * std::sqrt(double(L.reach2)) + std::sqrt(double(q2))) * (1.0 + 1e-5);
                    found.clear();
                    tree.kd->radiusSearch(c, float(R * R), found, nanoflann::SearchParams(32, 0.0f, false));
                    if (found.empty()) continue;
                    // Drop the surfels that are never the nearest in the
                    // triangle's ball B(c, r): y loses to x everywhere in B
                    // when |c-y|^2 - |c-x|^2 > 2 r |y-x| (the largest of
                    // |p-x|^2 - |p-y|^2 over B), here with a margin far above
                    // float rounding, so the scan's answer (ties included)
                    // is unchanged.  x: the few surfels nearest to c.
                    std::sort(found.begin(), found.end(), [](const auto& a, const auto& b2) {
                        return a.second < b2.second || (a.second == b2.second && a.first < b2.first);
                    });
                    const double r = std::sqrt(double(L.reach2));
                    const size_t nx = std::min(found.size(), kPruningSurfels);
                    kept.clear();
                    for (const auto& f : found) {
                        const float* y = &tree.pos[3 * size_t(f.first)];
                        const double cy2 = double(f.second);
                        bool never = false;
                        for (size_t k = 0; k < nx && !never; ++k) {
                            if (found[k].first == f.first) continue;
                            const float* x = &tree.pos[3 * size_t(found[k].first)];
                            const double ex = double(y[0]) - x[0], ey = double(y[1]) - x[1], ez = double(y[2]) - x[2];
                            const double yx = std::sqrt(ex * ex + ey * ey + ez * ez);
                            const double scale = r + std::sqrt(cy2) + yx;
                            never = cy2 - double(found[k].second) > 2.0 * r * yx + 1e-3 * scale * scale;
                        }
                        if (!never) kept.push_back(f);
                    }
                    if (kept.size() > kMaxCandidates) continue;
                    L.count = uint32_t(kept.size());
                    L.begin = uint32_t(out.size());  // block-relative until the offsets are known
                    const size_t first = out.size();
                    for (const auto& f : kept) {
                        const float* pp = &tree.pos[3 * size_t(f.first)];
                        const float dx = pp[0] - c[0], dy = pp[1] - c[1], dz = pp[2] - c[2];
                        out.push_back(Candidate{pp[0], pp[1], pp[2], std::sqrt(dx * dx + dy * dy + dz * dz)});
                        out_ids.push_back(tree.index[f.first]);
                    }
                    // Sort this triangle's entries by (distance from the centre, index).
                    std::vector<uint32_t> order(kept.size());
                    for (uint32_t k = 0; k < order.size(); ++k) order[k] = k;
                    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b2) {
                        const float ra = out[first + a].from_centre, rb = out[first + b2].from_centre;
                        return ra < rb || (ra == rb && out_ids[first + a] < out_ids[first + b2]);
                    });
                    std::vector<Candidate> sc(order.size());
                    std::vector<uint32_t> si(order.size());
                    for (size_t k = 0; k < order.size(); ++k) {
                        sc[k] = out[first + order[k]];
                        si[k] = out_ids[first + order[k]];
                    }
                    std::copy(sc.begin(), sc.end(), out.begin() + std::ptrdiff_t(first));
                    std::copy(si.begin(), si.end(), out_ids.begin() + std::ptrdiff_t(first));
                }
            }
        });
    });
    size_t total = 0;
    std::vector<size_t> offset(nblocks);
    for (size_t b = 0; b < nblocks; ++b) {
        offset[b] = total;
        total += block_cand[b].size();
    }
    if (total > size_t(UINT32_MAX)) throw Error("scene index: too many surfel candidates for the triangle lookup");
    lookup_cand_.resize(total);
    lookup_ids_.resize(total);
    for (size_t b = 0; b < nblocks; ++b) {
        std::copy(block_cand[b].begin(), block_cand[b].end(), lookup_cand_.begin() + std::ptrdiff_t(offset[b]));
        std::copy(block_ids[b].begin(), block_ids[b].end(), lookup_ids_.begin() + std::ptrdiff_t(offset[b]));
        for (size_t t = b * kBlock; t < std::min(m, (b + 1) * kBlock); ++t)
            if (lookup_tri_[t].count) lookup_tri_[t].begin += uint32_t(offset[b]);
    }
}

uint32_t SceneIndex::nearest_on_triangle(uint32_t prim, const float p[3]) const {
    if (prim < lookup_tri_.size()) {
        const TriangleLookup& L = lookup_tri_[prim];
        const float dx = p[0] - L.cx, dy = p[1] - L.cy, dz = p[2] - L.cz;
        const float to_centre2 = dx * dx + dy * dy + dz * dz;
        if (L.count && to_centre2 <= L.reach2) {
            const Candidate* c = lookup_cand_.data() + L.begin;
            const uint32_t* ids = lookup_ids_.data() + L.begin;
            const float to_centre = std::sqrt(to_centre2);
            float best = std::numeric_limits<float>::infinity(), cut = best;
            uint32_t id = UINT32_MAX;
            for (uint32_t k = 0; k < L.count; ++k) {
                // |p - y| >= |c - y| - |p - c|: once that exceeds the best
                // distance (padded for rounding), no later entry can win or tie.
                if (c[k].from_centre > cut) break;
                // The kd-tree's metric, term by term: the same float distances.
                float a = p[0] - c[k].x;
                float d2 = 0.0f;
                d2 += a * a;
                a = p[1] - c[k].y;
                d2 += a * a;
                a = p[2] - c[k].z;
                d2 += a * a;
                if (d2 < best || (d2 == best && ids[k] < id)) {
                    best = d2;
                    id = ids[k];
                    cut = (to_centre + std::sqrt(best)) * 1.0001f + 1e-30f;
                }
            }
            return id;
        }
    }
    return nearest_of(prim < tri_surface_.size() ? tri_surface_[prim] : -1, p);
}

size_t SceneIndex::lookup_fallback_triangles() const {
    size_t n = 0;
    for (const TriangleLookup& L : lookup_tri_) n += L.count == 0;
    return n;
}

size_t SceneIndex::lookup_bytes() const {
    return lookup_tri_.capacity() * sizeof(TriangleLookup) + lookup_cand_.capacity() * sizeof(Candidate) +
           lookup_ids_.capacity() * sizeof(uint32_t);
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

bool SceneIndex::has_surfels(int surface) const {
    return surface >= 0 && surface < n_surfaces_ && trees_->surface[size_t(surface)].kd != nullptr;
}

uint32_t SceneIndex::nearest_of(int surface, const float p[3]) const {
    if (!has_surfels(surface)) return nearest(p);
    return trees_->surface[size_t(surface)].query(p);
}

std::vector<size_t> SceneIndex::surfels_per_surface() const {
    std::vector<size_t> n;
    for (const PointTree& t : trees_->surface) n.push_back(t.index.size());
    return n;
}

size_t SceneIndex::smooth(int surface, const float p[3], uint32_t* idx, double* w) const {
    constexpr size_t K = kSmoothingNeighbours;
    const PointTree* tree = &trees_->all;
    if (has_surfels(surface)) tree = &trees_->surface[size_t(surface)];
    const size_t count = tree->cloud.n;
    float d2[K];
    nanoflann::KNNResultSet<float, uint32_t> rs(std::min(K, count));
    rs.init(idx, d2);
    tree->kd->findNeighbors(rs, p, nanoflann::SearchParams());
    size_t got = rs.size();
    const double inv2s2 = 1.0 / (2.0 * double(sigma_) * double(sigma_));
    double sw = 0;
    for (size_t j = 0; j < got; ++j) {
        w[j] = std::exp(-double(d2[j]) * inv2s2);
        sw += w[j];
    }
    if (sw > 0) {
        for (size_t j = 0; j < got; ++j) w[j] /= sw;
    } else {  // every weight underflowed: the nearest surfel alone
        got = 1;
        w[0] = 1.0;
    }
    if (!tree->index.empty())
        for (size_t j = 0; j < got; ++j) idx[j] = tree->index[idx[j]];
    return got;
}

}  // namespace gammart
