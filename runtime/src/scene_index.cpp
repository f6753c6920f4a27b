// Embree BVH + per-surface surfel kd-trees (see gamma/scene_index.h).
#include "gamma/scene_index.h"

#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "gamma/error.h"

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

void SceneIndex::build_geometry(const Mesh& mesh, std::vector<int32_t> tri_surface, int n_surfaces) {
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
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene_);
    if (rtcGetDeviceError(device_) != RTC_ERROR_NONE)
        throw std::runtime_error("internal error: embree scene build failed");
    ++geometry_builds_;
}

void SceneIndex::build_surfels(const float* positions, const int32_t* surfel_surface, size_t n, float sigma) {
    Trees& T = *trees_;
    n_surfels_ = n;
    sigma_ = sigma;
    T.all.pos.assign(positions, positions + 3 * n);
    T.all.index.clear();
    T.all.build();
    T.surface.clear();  // trees hold references into their own Cloud: never copied or moved once built
    T.surface.resize(size_t(n_surfaces_));
    for (size_t i = 0; i < n; ++i) {
        const int s = surfel_surface[i];
        if (s < 0 || s >= n_surfaces_) throw Error("scene index: surfel surface id out of range");
        PointTree& t = T.surface[size_t(s)];
        t.index.push_back(uint32_t(i));
        t.pos.insert(t.pos.end(), positions + 3 * i, positions + 3 * i + 3);
    }
    for (PointTree& t : T.surface) t.build();
    ++surfel_builds_;
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
