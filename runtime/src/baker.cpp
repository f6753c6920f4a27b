// Baking rows and colours at surface points (see gamma/baker.h).
#include "gamma/baker.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {

void bake_points(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                 const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                 float* look_out) {
    const int W = rs.state.width;
    const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= tri_surface.size())
            throw Error("bake_points: triangle " + std::to_string(triangles[i]) + " out of range");
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 1024), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const uint32_t tri = uint32_t(triangles[i]);
                float* row = rows_out + i * size_t(W);
                // The row as the surface holds it, whether or not it has an appearance.
                interpolate_row(rs, tri_surface[tri], positions + 3 * i, row);
                look_of_row(rs, tri, positions + 3 * i, normals + 3 * i, none, uvs + 2 * i, iteration,
                              mix64(kRenderKey ^ uint64_t(i)), row, tex.data(), look_out + size_t(GAMMA_LOOK_WIDTH) * i);
            }
        });
    });
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
