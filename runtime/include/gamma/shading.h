// Shading normals for the renders (SPEC §16.3, "Shading"): per triangle
// corner, the area-weighted mean of the normals of the triangles that share
// the corner's position and meet this triangle at less than the crease
// angle, so curved surfaces render smooth and sharp edges stay sharp.
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/mesh.h"
#include "gamma/vec.h"

namespace gammart {

// The default crease angle: edges sharper than this stay sharp.
constexpr float kDefaultCreaseDeg = 60.0f;

// Unit normals of every triangle corner, m*9 floats (corners in triangles()
// order).  Corners are grouped by vertex position (bit-equal coordinates),
// not by index, so a mesh whose triangles do not share vertex indices is
// smoothed as well.  A triangle with flat[t] != 0 (or every triangle when
// crease_deg <= 0) gets its own geometric normal at its three corners.
// `flat` is empty or holds one flag per triangle.  Deterministic: sums run
// in triangle order.
std::vector<float> corner_normals(const Mesh& mesh, const std::vector<uint8_t>& flat, float crease_deg);

// The shading normal at barycentric (u, v) of triangle t (Embree's
// convention: p = (1-u-v) p0 + u p1 + v p2), turned to the side of the
// unit geometric normal ng (which the caller has turned toward the viewer).
inline V3 shading_normal(const std::vector<float>& corners, uint32_t t, float u, float v, V3 ng) {
    if (corners.empty()) return ng;
    const float* c = corners.data() + 9 * size_t(t);
    const float w = 1.0f - u - v;
    V3 n = normalize(V3{w * c[0] + u * c[3] + v * c[6], w * c[1] + u * c[4] + v * c[7],
                        w * c[2] + u * c[5] + v * c[8]});
    if (dot(n, n) == 0.0f) return ng;
    return dot(n, ng) < 0.0f ? n * -1.0f : n;
}

}  // namespace gammart
