// Shading normals for the renders: see shading.h.
#include "gamma/shading.h"

#include <cmath>
#include <cstring>
#include <unordered_map>

namespace gammart {

namespace {

struct PositionKey {
    uint32_t bits[3];
    bool operator==(const PositionKey& o) const {
        return bits[0] == o.bits[0] && bits[1] == o.bits[1] && bits[2] == o.bits[2];
    }
};

struct PositionHash {
    size_t operator()(const PositionKey& k) const {
        uint64_t h = 0xcbf29ce484222325ULL;
        for (uint32_t b : k.bits) h = (h ^ b) * 0x100000001b3ULL;
        return size_t(h);
    }
};

PositionKey key_of(const float* p) {
    PositionKey k{};
    for (int c = 0; c < 3; ++c) {
        const float x = p[c] == 0.0f ? 0.0f : p[c];  // -0 and +0 are one position
        std::memcpy(&k.bits[c], &x, sizeof(float));
    }
    return k;
}

}  // namespace

std::vector<float> corner_normals(const Mesh& mesh, const std::vector<uint8_t>& flat, float crease_deg) {
    const size_t m = mesh.num_triangles();
    const float* V = mesh.vertices.data();
    const int32_t* T = mesh.triangles.data();
    // Area-weighted (unnormalised cross product) and unit face normals.
    std::vector<V3> weighted(m), unit_n(m);
    for (size_t t = 0; t < m; ++t) {
        const float* a = V + 3 * size_t(T[3 * t]);
        const float* b = V + 3 * size_t(T[3 * t + 1]);
        const float* c = V + 3 * size_t(T[3 * t + 2]);
        const V3 e1{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2{c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        weighted[t] = cross(e1, e2);
        unit_n[t] = normalize(weighted[t]);
    }
    std::vector<float> out(9 * m);
    auto put = [&](size_t t, int corner, V3 n) {
        out[9 * t + 3 * size_t(corner)] = n.x;
        out[9 * t + 3 * size_t(corner) + 1] = n.y;
        out[9 * t + 3 * size_t(corner) + 2] = n.z;
    };
    const bool all_flat = !(crease_deg > 0.0f);
    // Corners grouped by position: for each group, the triangles around it in triangle order.
    std::unordered_map<PositionKey, uint32_t, PositionHash> group_of;
    std::vector<uint32_t> corner_group(3 * m);
    if (!all_flat) {
        group_of.reserve(mesh.num_vertices());
        for (size_t i = 0; i < 3 * m; ++i) {
            const auto ins = group_of.emplace(key_of(V + 3 * size_t(T[i])), uint32_t(group_of.size()));
            corner_group[i] = ins.first->second;
        }
    }
    std::vector<uint32_t> start(group_of.size() + 1, 0), members;
    if (!all_flat) {
        for (uint32_t g : corner_group) ++start[g + 1];
        for (size_t g = 0; g < group_of.size(); ++g) start[g + 1] += start[g];
        members.resize(3 * m);
        std::vector<uint32_t> fill(start.begin(), start.end() - 1);
        for (size_t i = 0; i < 3 * m; ++i) members[fill[corner_group[i]]++] = uint32_t(i / 3);
    }
    const float cos_crease = std::cos(crease_deg * 3.14159265358979f / 180.0f);
    for (size_t t = 0; t < m; ++t) {
        const bool own = all_flat || (!flat.empty() && flat[t]);
        for (int corner = 0; corner < 3; ++corner) {
            if (own) {
                put(t, corner, unit_n[t]);
                continue;
            }
            const uint32_t g = corner_group[3 * t + size_t(corner)];
            V3 sum{0, 0, 0};
            for (uint32_t k = start[g]; k < start[g + 1]; ++k) {
                const uint32_t o = members[k];
                if (o == t || ((flat.empty() || !flat[o]) && dot(unit_n[o], unit_n[t]) >= cos_crease))
                    sum += weighted[o];
            }
            const V3 n = normalize(sum);
            put(t, corner, dot(n, n) > 0.0f ? n : unit_n[t]);
        }
    }
    return out;
}

}  // namespace gammart
