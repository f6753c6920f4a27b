// A nanoflann kd-tree over points stored as a flat float array (x0 y0 z0 x1
// ...), the layout of the surfel positions: the one adaptor the runtime's
// radius and nearest searches share (and PointColumns reproduces exactly).
#pragma once
#include <cstddef>
#include <cstdint>

#include <nanoflann.hpp>

namespace gammart {

// Points p[3 i .. 3 i + 2], i < n, not copied: the array must outlive the tree.
struct FloatPoints {
    const float* p = nullptr;
    size_t n = 0;
    size_t kdtree_get_point_count() const { return n; }
    float kdtree_get_pt(size_t i, size_t d) const { return p[3 * i + d]; }
    template <class BBOX>
    bool kdtree_get_bbox(BBOX&) const { return false; }
};

using FloatPointsKdTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, FloatPoints>, FloatPoints, 3, uint32_t>;

}  // namespace gammart
