// Vector math of the runtime: GLM's vec3 (float) and its dot / cross /
// length.  GLM's operations are plain IEEE float in the same order as the
// runtime's former hand-written helpers (dot = (x*x' + y*y') + z*z',
// normalize = v * (1 / sqrt(dot(v, v)))), so results are bit-identical.
// GLM_FORCE_CTOR_INIT (set by the build) makes a default V3 zero.
#pragma once
#include <array>
#include <cmath>

#include <glm/geometric.hpp>
#include <glm/vec3.hpp>

namespace gammart {

using V3 = glm::vec3;
using glm::cross;
using glm::dot;
using glm::length;

// glm::normalize, except that the zero vector stays zero (GLM divides by zero).
inline V3 normalize(V3 a) { return dot(a, a) > 0 ? glm::normalize(a) : a; }

// The runtime's interface passes vectors as std::array<float, 3> (Config,
// sources, cameras): every component finite; a length (in double) finite and
// not zero; the vector divided by that length (in double), as a V3.
inline bool finite3(const std::array<float, 3>& a) {
    return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}
inline bool nonzero3(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return std::isfinite(l) && l > 0;
}
inline V3 unit(const std::array<float, 3>& a) {
    const double l = std::sqrt(double(a[0]) * a[0] + double(a[1]) * a[1] + double(a[2]) * a[2]);
    return {float(a[0] / l), float(a[1] / l), float(a[2] / l)};
}

// Orthonormal basis around unit n (Duff et al. 2017).
inline void onb(V3 n, V3& t, V3& b) {
    float sign = std::copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float bb = n.x * n.y * a;
    t = {1.0f + sign * n.x * n.x * a, sign * bb, -sign * n.x};
    b = {bb, sign + n.y * n.y * a, -n.y};
}
}  // namespace gammart
