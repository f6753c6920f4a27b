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
                 float* rgb_out) {
    const int W = rs.state.width;
    const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= tri_surface.size())
            throw Error("bake_points: triangle " + std::to_string(triangles[i]) + " out of range");
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 1024), [&](const tbb::blocked_range<size_t>& r) {
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f), scratch(static_cast<size_t>(W), 0.0f);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const uint32_t tri = uint32_t(triangles[i]);
                float* row = rows_out + i * size_t(W);
                // The row as the surface holds it, whether or not it has an appearance.
                interpolate_row(rs, tri_surface[tri], positions + 3 * i, row);
                albedo_at(rs, tri, positions + 3 * i, normals + 3 * i, none, uvs + 2 * i, iteration,
                          mix64(kRenderKey ^ uint64_t(i)), scratch.data(), tex.data(), rgb_out + 3 * i);
            }
        });
    });
}

}  // namespace gammart
