// Shading normals for the renders: see shading.h.
// Corners are grouped by position with a parallel sort of (position bits,
// corner) rather than a hash map (a million-triangle mesh: seconds of cache
// misses); a group's members come out in corner order, which is the
// triangle order the sums run in, so the result is that of a serial loop.
#include "gamma/shading.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <cmath>
#include <cstring>

namespace gammart {

namespace {

// A corner and its position's bits (-0 and +0 are one position).
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
    // Corners sorted by position, then corner: each position's corners are
    // a run, in triangle order.
    std::vector<CornerKey> sorted(3 * m);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, 3 * m, kGrain), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) sorted[i] = key_of(V + 3 * size_t(T[i]), uint32_t(i));
    });
    tbb::parallel_sort(sorted.begin(), sorted.end());
    const float cos_crease = std::cos(crease_deg * 3.14159265358979f / 180.0f);
    // Each work item handles the runs that start in its range.
    tbb::parallel_for(tbb::blocked_range<size_t>(0, sorted.size(), kGrain), [&](const tbb::blocked_range<size_t>& r) {
        size_t a = r.begin();
        while (a > 0 && a < sorted.size() && sorted[a].same_position(sorted[a - 1])) ++a;
        while (a < r.end()) {
            size_t b = a + 1;
            while (b < sorted.size() && sorted[b].same_position(sorted[a])) ++b;
            for (size_t k = a; k < b; ++k) {
                const size_t t = sorted[k].corner / 3, corner = sorted[k].corner % 3;
                if (own(t)) {
                    put(t, corner, unit_n[t]);
                    continue;
                }
                V3 sum{0, 0, 0};
                for (size_t q = a; q < b; ++q) {
                    const size_t o = sorted[q].corner / 3;
                    if (o == t || (!own(o) && dot(unit_n[o], unit_n[t]) >= cos_crease)) sum += weighted[o];
                }
                const V3 n = normalize(sum);
                put(t, corner, dot(n, n) > 0.0f ? n : unit_n[t]);
            }
            a = b;
        }
    });
    return out;
}

}  // namespace gammart
