#pragma once
#include <array>
#include <cmath>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "gamma/error.h"
#include "gamma/mesh.h"

namespace gamma_test {

// The message of the gammart::Error that f throws (a test failure if none).
inline std::string expect_error(const std::function<void()>& f) {
    try {
        f();
    } catch (const gammart::Error& e) {
        return e.what();
    }
    ADD_FAILURE() << "expected gammart::Error";
    return "";
}

// Closed icosphere of radius r centred at the origin.
inline gammart::Mesh icosphere(int subdiv, float r = 1.0f) {
    const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
    std::vector<std::array<float, 3>> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                           {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11},
                                         {1, 5, 9}, {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                         {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8}, {3, 8, 9},
                                         {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
    auto norm = [](std::array<float, 3> p) {
        float l = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        return std::array<float, 3>{p[0] / l, p[1] / l, p[2] / l};
    };
    for (auto& p : v) p = norm(p);
    for (int s = 0; s < subdiv; ++s) {
        std::map<std::pair<int, int>, int> mid;
        auto midpoint = [&](int a, int b) {
            auto key = std::make_pair(std::min(a, b), std::max(a, b));
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            std::array<float, 3> p{(v[a][0] + v[b][0]) / 2, (v[a][1] + v[b][1]) / 2, (v[a][2] + v[b][2]) / 2};
            v.push_back(norm(p));
            return mid[key] = int(v.size()) - 1;
        };
        std::vector<std::array<int, 3>> nf;
        for (auto& tri : f) {
            int a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
            nf.push_back({tri[0], a, c});
            nf.push_back({tri[1], b, a});
            nf.push_back({tri[2], c, b});
            nf.push_back({a, b, c});
        }
        f = nf;
    }
    std::vector<float> vf;
    for (auto& p : v) for (float c : p) vf.push_back(c * r);
    std::vector<int32_t> tf;
    for (auto& tri : f) for (int c : tri) tf.push_back(c);
    return gammart::Mesh::from_arrays(vf.data(), v.size(), tf.data(), f.size(), "icosphere");
}

// Unit square in the z=0 plane as three triangles of areas 0.15, 0.35, 0.5.
inline gammart::Mesh unit_square() {
    std::vector<float> v = {0, 0, 0, 0.3f, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    std::vector<int32_t> t = {0, 1, 4, 1, 2, 3, 1, 3, 4};
    return gammart::Mesh::from_arrays(v.data(), 5, t.data(), 3, "square");
}

// Simple mesh builder: quads (fan-split into two triangles) and triangles.
struct Builder {
    std::vector<float> v;
    std::vector<int32_t> t;
    int32_t vert(std::array<float, 3> p) {
        v.insert(v.end(), p.begin(), p.end());
        return int32_t(v.size() / 3 - 1);
    }
    void quad(std::array<float, 3> a, std::array<float, 3> b, std::array<float, 3> c, std::array<float, 3> d) {
        int32_t i = vert(a), j = vert(b), k = vert(c), l = vert(d);
        t.insert(t.end(), {i, j, k, i, k, l});
    }
    void add(const gammart::Mesh& m, std::array<float, 3> offset = {0, 0, 0}) {
        const int32_t base = int32_t(v.size() / 3);
        for (size_t i = 0; i < m.num_vertices(); ++i)
            for (int k = 0; k < 3; ++k) v.push_back(m.vertices[3 * i + k] + offset[k]);
        for (int32_t x : m.triangles) t.push_back(base + x);
    }
    size_t num_triangles() const { return t.size() / 3; }
    gammart::Mesh mesh(const char* name = "built") const {
        return gammart::Mesh::from_arrays(v.data(), v.size() / 3, t.data(), t.size() / 3, name);
    }
};

// Horizontal square [x0,x1] x [z0,z1] at height y (normal +y).
inline void floor_quad(Builder& b, float x0, float x1, float z0, float z1, float y = 0) {
    b.quad({x0, y, z0}, {x0, y, z1}, {x1, y, z1}, {x1, y, z0});
}

}  // namespace gamma_test
