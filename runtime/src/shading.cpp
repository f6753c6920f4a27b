// Shading normals for the renders: see shading.h.
// Corners are grouped by position with a parallel sort of the vertices'
// (position bits, index) and a counting sort of the corners by position,
// rather than a hash map (a million-triangle mesh: seconds of cache misses);
// a group's members come out in corner order, which is the triangle order
// the sums run in, so the result is that of a serial loop.
#include "gamma/shading.h"

#include "gamma/gmath.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <cmath>
#include <cstring>

namespace gammart {

namespace {

// A corner (or a vertex) and its position's bits (-0 and +0 are one position).
struct CornerKey {
    uint32_t bits[3];
    uint32_t corner;
    bool operator<(const CornerKey& o) const {
        if (bits[0] != o.bits[0]) return bits[0] < o.bits[0];
        if (bits[1] != o.bits[1]) return bits[1] < o.bits[1];
        if (bits[2] != o.bits[2]) return bits[2] < o.bits[2];
        return corner < o.corner;
    }
    bool same_position(const CornerKey& o) const {
        return bits[0] == o.bits[0] && bits[1] == o.bits[1] && bits[2] == o.bits[2];
    }
};

CornerKey key_of(const float* p, uint32_t corner) {
    CornerKey k{};
    for (int c = 0; c < 3; ++c) {
        const float x = p[c] == 0.0f ? 0.0f : p[c];
        std::memcpy(&k.bits[c], &x, sizeof(float));
    }
    k.corner = corner;
    return k;
}

constexpr size_t kGrain = 4096;  // items per parallel work item

}  // namespace

std::vector<float> corner_normals(const Mesh& mesh, const std::vector<uint8_t>& flat, float crease_deg) {
    const size_t m = mesh.num_triangles();
    const float* V = mesh.vertices.data();
    const int32_t* T = mesh.triangles.data();
    // Area-weighted (unnormalised cross product) and unit face normals.
    std::vector<V3> weighted(m), unit_n(m);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, m, kGrain), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t t = r.begin(); t < r.end(); ++t) {
            const float* a = V + 3 * size_t(T[3 * t]);
            const float* b = V + 3 * size_t(T[3 * t + 1]);
            const float* c = V + 3 * size_t(T[3 * t + 2]);
            const V3 e1{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
            weighted[t] = cross(e1, e2);
            unit_n[t] = normalize(weighted[t]);
        }
    });
    std::vector<float> out(9 * m);
    auto put = [&](size_t t, size_t corner, V3 n) {
        out[9 * t + 3 * corner] = n.x;
        out[9 * t + 3 * corner + 1] = n.y;
        out[9 * t + 3 * corner + 2] = n.z;
    };
    auto own = [&](size_t t) { return !flat.empty() && flat[t]; };
    if (!(crease_deg > 0.0f)) {  // all flat
        tbb::parallel_for(tbb::blocked_range<size_t>(0, m, kGrain), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t t = r.begin(); t < r.end(); ++t)
                for (size_t corner = 0; corner < 3; ++corner) put(t, corner, unit_n[t]);
        });
        return out;
    }
    // Corners grouped by position, each group in corner order: the vertices
    // (a sixth as many as the corners) sorted by (position bits, index) give
    // each vertex its position's number, then a counting sort of the
    // corners by that number keeps their order within a group.
    const size_t nv = mesh.vertices.size() / 3;
    std::vector<CornerKey> vertex_keys(nv);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nv, kGrain), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t v = r.begin(); v < r.end(); ++v) vertex_keys[v] = key_of(V + 3 * v, uint32_t(v));
    });
    tbb::parallel_sort(vertex_keys.begin(), vertex_keys.end());
    std::vector<uint32_t> position_of(nv);
    uint32_t positions = 0;
    for (size_t i = 0; i < nv; ++i) {
        if (i > 0 && !vertex_keys[i].same_position(vertex_keys[i - 1])) ++positions;
        position_of[vertex_keys[i].corner] = positions;
    }
    positions += nv > 0 ? 1 : 0;
    std::vector<uint32_t> group_start(size_t(positions) + 1, 0);
    for (size_t i = 0; i < 3 * m; ++i) ++group_start[size_t(position_of[size_t(T[i])]) + 1];
    for (size_t g = 0; g < positions; ++g) group_start[g + 1] += group_start[g];
    std::vector<uint32_t> by_position(3 * m);
    {
        std::vector<uint32_t> cursor(group_start.begin(), group_start.end() - 1);
        for (size_t i = 0; i < 3 * m; ++i) by_position[cursor[position_of[size_t(T[i])]]++] = uint32_t(i);
    }
    const float cos_crease = gm::cos(crease_deg * 3.14159265358979f / 180.0f);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, positions, kGrain / 8), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t g = r.begin(); g < r.end(); ++g) {
            const size_t a = group_start[g], b = group_start[g + 1];
            for (size_t k = a; k < b; ++k) {
                const size_t t = by_position[k] / 3, corner = by_position[k] % 3;
                if (own(t)) {
                    put(t, corner, unit_n[t]);
                    continue;
                }
                V3 sum{0, 0, 0};
                for (size_t q = a; q < b; ++q) {
                    const size_t o = by_position[q] / 3;
                    if (o == t || (!own(o) && dot(unit_n[o], unit_n[t]) >= cos_crease)) sum += weighted[o];
                }
                const V3 n = normalize(sum);
                put(t, corner, dot(n, n) > 0.0f ? n : unit_n[t]);
            }
        }
    });
    return out;
}

}  // namespace gammart
