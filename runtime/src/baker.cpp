// Baking rows and colours at surface points (see gamma/baker.h).
#include "gamma/baker.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {

void bake_points(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                 const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                 float* look_out) {
    constexpr size_t K = kSmoothingNeighbours;
    const int W = rs.state.width;
    const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= tri_surface.size())
            throw Error("bake_points: triangle " + std::to_string(triangles[i]) + " out of range");
    // Runs of up to kBakeBlock consecutive points of one surface share one
    // neighbour search (SceneIndex::smooth_block): texels come in rows, so a
    // run is a few texels wide.  Runs are cut at fixed places, so the result
    // does not depend on the thread count.
    const size_t blocks = (k + kBakeBlock - 1) / kBakeBlock;
    const float* state_rows = rs.state.rows.data();
    const float run_reach2 = rs.index.sigma() * rs.index.sigma();
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks, 16), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f);
            std::vector<uint32_t> idx(K * kBakeBlock);
            std::vector<double> w(K * kBakeBlock);
            std::vector<uint8_t> count(kBakeBlock);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t b = r.begin(); b < r.end(); ++b) {
                const size_t end = std::min(k, (b + 1) * kBakeBlock);
                for (size_t start = b * kBakeBlock; start < end;) {
                    // A run is one surface's points within a surfel spacing of its first:
                    // consecutive texels of a row can lie on charts far apart.
                    const int surface = tri_surface[size_t(triangles[start])];
                    const float* p0 = positions + 3 * start;
                    auto near_first = [&](size_t i) {
                        const float* p = positions + 3 * i;
                        const float dx = p[0] - p0[0], dy = p[1] - p0[1], dz = p[2] - p0[2];
                        return dx * dx + dy * dy + dz * dz <= run_reach2;
                    };
                    size_t stop = start + 1;
                    while (stop < end && tri_surface[size_t(triangles[stop])] == surface && near_first(stop)) ++stop;
                    rs.index.smooth_block(surface, positions + 3 * start, stop - start, idx.data(), w.data(),
                                          count.data());
                    for (size_t i = start; i < stop; ++i) {
                        const size_t q = i - start;
                        float* row = rows_out + i * size_t(W);
                        // interpolate_row's sum, in its order
                        for (int c = 0; c < W; ++c) {
                            double acc = 0;
                            for (size_t j = 0; j < count[q]; ++j)
                                acc += w[K * q + j] * state_rows[size_t(idx[K * q + j]) * size_t(W) + size_t(c)];
                            row[c] = float(acc);
                        }
                        look_of_row(rs, uint32_t(triangles[i]), positions + 3 * i, normals + 3 * i, none, uvs + 2 * i,
                                    iteration, mix64(kRenderKey ^ uint64_t(i)), row, tex.data(),
                                    look_out + size_t(GAMMA_LOOK_WIDTH) * i);
                    }
                    start = stop;
                }
            }
        });
    });
}

void bake_texels(const RenderScene& rs, const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                 int iteration, int threads, float* rows_out, float* look_out) {
    for (size_t i = 0; i < k; ++i)
        if (tris[i] < 0 || size_t(tris[i]) >= layout.faces)
            throw Error("bake_texels: layout triangle " + std::to_string(tris[i]) + " out of range");
    std::vector<float> positions(3 * k), normals(3 * k), uvs(2 * k, 0.0f);
    std::vector<int32_t> triangles(k);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 4096), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const size_t t = size_t(tris[i]);
                const double* b = bary + 3 * i;
                double n[3];
                for (int d = 0; d < 3; ++d) {
                    double p = 0, m = 0;
                    for (int c = 0; c < 3; ++c) {
                        const size_t v = size_t(layout.corners[3 * t + size_t(c)]);
                        p += b[c] * double(layout.positions[3 * v + size_t(d)]);
                        m += b[c] * double(layout.normals[3 * v + size_t(d)]);
                    }
                    positions[3 * i + size_t(d)] = float(p);
                    n[d] = m;
                }
                const double length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                for (int d = 0; d < 3; ++d) normals[3 * i + size_t(d)] = float(n[d] / std::max(length, 1e-30));
                if (layout.lookup_uvs)
                    for (int d = 0; d < 2; ++d) {
                        double u = 0;
                        for (int c = 0; c < 3; ++c) u += b[c] * double(layout.lookup_uvs[6 * t + 2 * size_t(c) + size_t(d)]);
                        uvs[2 * i + size_t(d)] = float(u);
                    }
                triangles[i] = layout.scene_triangle[t];
            }
        });
    });
    bake_points(rs, k, positions.data(), normals.data(), triangles.data(), uvs.data(), iteration, threads, rows_out,
                look_out);
}

BakePoints BakePoints::prepare(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                               const int32_t* triangles, const float* uvs, int threads) {
    const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= tri_surface.size())
            throw Error("prepare_points: triangle " + std::to_string(triangles[i]) + " out of range");
    constexpr size_t K = kSmoothingNeighbours;
    BakePoints b;
    b.positions.assign(positions, positions + 3 * k);
    b.normals.assign(normals, normals + 3 * k);
    b.uvs.assign(uvs, uvs + 2 * k);
    b.triangles.assign(triangles, triangles + k);
    b.neighbour.assign(K * k, 0);
    b.weight.assign(K * k, 0.0);
    b.count.assign(k, 0);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 1024), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            for (size_t i = r.begin(); i < r.end(); ++i)
                b.count[i] = uint8_t(rs.index.smooth(tri_surface[size_t(triangles[i])], positions + 3 * i,
                                                     &b.neighbour[K * i], &b.weight[K * i]));
        });
    });
    return b;
}

void bake_prepared(const RenderScene& rs, const BakePoints& points, int iteration, int threads, float* rows_out,
                   float* look_out) {
    constexpr size_t K = kSmoothingNeighbours;
    const int W = rs.state.width;
    const float* rows = rs.state.rows.data();
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 1024),
                          [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t i = r.begin(); i < r.end(); ++i) {
                float* row = rows_out + i * size_t(W);
                // interpolate_row's sum, in its order
                for (int c = 0; c < W; ++c) {
                    double acc = 0;
                    for (size_t j = 0; j < points.count[i]; ++j)
                        acc += points.weight[K * i + j] * rows[size_t(points.neighbour[K * i + j]) * size_t(W) + size_t(c)];
                    row[c] = float(acc);
                }
                look_of_row(rs, uint32_t(points.triangles[i]), &points.positions[3 * i], &points.normals[3 * i], none,
                              &points.uvs[2 * i], iteration, mix64(kRenderKey ^ uint64_t(i)), row, tex.data(),
                              look_out + size_t(GAMMA_LOOK_WIDTH) * i);
            }
        });
    });
}

}  // namespace gammart
