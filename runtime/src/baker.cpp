// Baking rows and colours at surface points (see gamma/baker.h).
#include "gamma/baker.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

void check_triangles(const RenderScene& rs, size_t k, const int32_t* triangles, const char* what) {
    const size_t count = rs.index.tri_surface().size();
    for (size_t i = 0; i < k; ++i)
        if (triangles[i] < 0 || size_t(triangles[i]) >= count)
            throw Error(std::string(what) + ": triangle " + std::to_string(triangles[i]) + " out of range");
}

// The smoothed rows (interpolate_row's sums) of the points at[0..n) (the
// first n points, in order, when `at` is null), and with look_out their
// looks too: the i-th of them written i-th.
// Runs of up to kBakeBlock consecutive points of one surface share one
// neighbour search (SceneIndex::smooth_block): texels come in rows, so a run
// is a few texels wide.  Runs are cut at fixed places, so the result does not
// depend on the thread count.
void smooth_points(const RenderScene& rs, size_t n, const uint32_t* at, const float* positions, const float* normals,
                   const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                   float* look_out) {
    constexpr size_t K = kSmoothingNeighbours;
    const int W = rs.state.width;
    const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
    const size_t blocks = (n + kBakeBlock - 1) / kBakeBlock;
    const float* state_rows = rs.state.rows.data();
    const float run_reach2 = rs.index.sigma() * rs.index.sigma();
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks, 16), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f);
            std::vector<uint32_t> idx(K * kBakeBlock);
            std::vector<double> w(K * kBakeBlock);
            std::vector<uint8_t> count(kBakeBlock);
            std::vector<float> run_points(3 * kBakeBlock);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            for (size_t b = r.begin(); b < r.end(); ++b) {
                const size_t end = std::min(n, (b + 1) * kBakeBlock);
                for (size_t start = b * kBakeBlock; start < end;) {
                    auto point = [&](size_t i) { return at ? size_t(at[i]) : i; };
                    // A run is one surface's points within a surfel spacing of its first:
                    // consecutive texels of a row can lie on charts far apart.
                    const int surface = tri_surface[size_t(triangles[point(start)])];
                    const float* p0 = positions + 3 * point(start);
                    auto near_first = [&](size_t i) {
                        const float* p = positions + 3 * point(i);
                        const float dx = p[0] - p0[0], dy = p[1] - p0[1], dz = p[2] - p0[2];
                        return dx * dx + dy * dy + dz * dz <= run_reach2;
                    };
                    size_t stop = start + 1;
                    while (stop < end && tri_surface[size_t(triangles[point(stop)])] == surface && near_first(stop))
                        ++stop;
                    const float* run = positions + 3 * start;
                    if (at) {
                        for (size_t i = start; i < stop; ++i)
                            std::copy_n(positions + 3 * point(i), 3, &run_points[3 * (i - start)]);
                        run = run_points.data();
                    }
                    rs.index.smooth_block(surface, run, stop - start, idx.data(), w.data(), count.data());
                    for (size_t i = start; i < stop; ++i) {
                        const size_t q = i - start, p = point(i);
                        float* row = rows_out + i * size_t(W);
                        // interpolate_row's sum, in its order
                        for (int c = 0; c < W; ++c) {
                            double acc = 0;
                            for (size_t j = 0; j < count[q]; ++j)
                                acc += w[K * q + j] * state_rows[size_t(idx[K * q + j]) * size_t(W) + size_t(c)];
                            row[c] = float(acc);
                        }
                        if (look_out)
                            look_of_row(rs, uint32_t(triangles[p]), positions + 3 * p, normals + 3 * p, none,
                                        uvs + 2 * p, iteration, mix64(kRenderKey ^ uint64_t(p)), row, tex.data(),
                                        look_out + size_t(GAMMA_LOOK_WIDTH) * i);
                    }
                    start = stop;
                }
            }
        });
    });
}

// bake_texels' lattice (see baker.h): which texels take their rows from the
// lattice points around them, and with what weights.
class TexelLattice {
public:
    static constexpr uint32_t kOwn = ~uint32_t(0);   // corner[4 * i]: the texel is smoothed itself

    TexelLattice(const RenderScene& rs, size_t k, const TexelGrid& grid, const float* positions,
                 const int32_t* triangles, int threads)
        : corner_(4 * k, kOwn), weight_(4 * k, 0.0f), smoothed_(k, 1) {
        std::vector<int32_t> slot(grid.width * grid.rows, -1);
        for (size_t i = 0; i < k; ++i) {
            if (grid.texel[i] < 0 || size_t(grid.texel[i]) >= slot.size())
                throw Error("bake_texels: texel " + std::to_string(grid.texel[i]) + " outside its band");
            slot[size_t(grid.texel[i])] = int32_t(i);
        }
        run_with_threads(threads, [&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 4096), [&](const tbb::blocked_range<size_t>& r) {
                for (size_t i = r.begin(); i < r.end(); ++i) find_corners(rs, grid, slot, positions, triangles, i);
            });
        });
    }

    bool smoothed(size_t i) const { return smoothed_[i] != 0; }
    // Texel i's q-th lattice point (kOwn: none) and its weight.
    uint32_t corner(size_t i, size_t q) const { return corner_[4 * i + q]; }
    float weight(size_t i, size_t q) const { return weight_[4 * i + q]; }

private:
    // Texel i's lattice points and weights, if they are all near enough;
    // the lattice points themselves (and texels without near ones) keep
    // kOwn and are smoothed themselves.
    void find_corners(const RenderScene& rs, const TexelGrid& grid, const std::vector<int32_t>& slot,
                      const float* positions, const int32_t* triangles, size_t i) {
        const std::vector<int32_t>& tri_surface = rs.index.tri_surface();
        const float reach = kLatticeReach * rs.index.sigma();
        constexpr size_t S = size_t(kLatticeStride);
        const size_t row = size_t(grid.texel[i]) / grid.width, column = size_t(grid.texel[i]) % grid.width;
        const size_t dy = (row + grid.first_row) % S, dx = column % S;
        if (dx == 0 && dy == 0) return;                             // a lattice point
        const double fy = double(dy) / double(S), fx = double(dx) / double(S);
        // multiples of 1 / S², exact in float
        const float w[4] = {float((1 - fy) * (1 - fx)), float((1 - fy) * fx), float(fy * (1 - fx)), float(fy * fx)};
        uint32_t c[4] = {kOwn, kOwn, kOwn, kOwn};
        for (int q = 0; q < 4; ++q) {
            if (w[q] == 0.0f) continue;
            if (row < dy) return;
            const size_t r = row - dy + (q >= 2 ? S : 0), col = column - dx + ((q & 1) ? S : 0);
            if (r >= grid.rows || col >= grid.width || slot[r * grid.width + col] < 0) return;
            const size_t j = size_t(slot[r * grid.width + col]);
            const float* a = positions + 3 * i;
            const float* b = positions + 3 * j;
            const float ex = a[0] - b[0], ey = a[1] - b[1], ez = a[2] - b[2];
            if (tri_surface[size_t(triangles[j])] != tri_surface[size_t(triangles[i])] ||
                !(ex * ex + ey * ey + ez * ez <= reach * reach))
                return;
            c[q] = uint32_t(j);
        }
        for (int q = 0; q < 4; ++q) {
            corner_[4 * i + size_t(q)] = c[q];
            weight_[4 * i + size_t(q)] = w[q];
        }
        smoothed_[i] = 0;
    }

    std::vector<uint32_t> corner_;   // 4 per texel: its lattice points (kOwn: none, or weight 0)
    std::vector<float> weight_;      // 4 per texel: their bilinear weights
    std::vector<uint8_t> smoothed_;  // per texel: its row comes from its own neighbour search
};

}  // namespace

void bake_points(const RenderScene& rs, size_t k, const float* positions, const float* normals,
                 const int32_t* triangles, const float* uvs, int iteration, int threads, float* rows_out,
                 float* look_out) {
    check_triangles(rs, k, triangles, "bake_points");
    smooth_points(rs, k, nullptr, positions, normals, triangles, uvs, iteration, threads, rows_out, look_out);
}

namespace {

// Where each texel's row lies among the smoothed ones (`at`, increasing).
std::vector<uint32_t> row_numbers(size_t k, const std::vector<uint32_t>& at) {
    std::vector<uint32_t> number(k, 0);
    for (size_t r = 0; r < at.size(); ++r) number[at[r]] = uint32_t(r);
    return number;
}

}  // namespace

void bake_texels(const RenderScene& rs, const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                 const TexelGrid* grid, const ChannelSlots& slots, int iteration, int threads, float* channels_out) {
    for (size_t i = 0; i < k; ++i)
        if (tris[i] < 0 || size_t(tris[i]) >= layout.faces)
            throw Error("bake_texels: layout triangle " + std::to_string(tris[i]) + " out of range");
    for (size_t t = 0; t < layout.faces; ++t)
        if (layout.scene_triangle[t] < 0 || size_t(layout.scene_triangle[t]) >= slots.triangles)
            throw Error("bake_texels: scene triangle " + std::to_string(layout.scene_triangle[t]) + " has no surface");
    // the texels' points and scene triangles (the lattice needs every point first)
    std::vector<float> positions(3 * k);
    std::vector<int32_t> triangles(k);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 4096), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            for (size_t i = r.begin(); i < r.end(); ++i) {
                const size_t t = size_t(tris[i]);
                const double* b = bary + 3 * i;
                for (int d = 0; d < 3; ++d) {
                    double p = 0;
                    for (int c = 0; c < 3; ++c)
                        p += b[c] * double(layout.positions[3 * size_t(layout.corners[3 * t + size_t(c)]) + size_t(d)]);
                    positions[3 * i + size_t(d)] = float(p);
                }
                triangles[i] = layout.scene_triangle[t];
            }
        });
    });
    check_triangles(rs, k, triangles.data(), "bake_texels");
    std::optional<TexelLattice> lattice;
    std::vector<uint32_t> at;
    if (grid) {
        lattice.emplace(rs, k, *grid, positions.data(), triangles.data(), threads);
        for (size_t i = 0; i < k; ++i)
            if (lattice->smoothed(i)) at.push_back(uint32_t(i));
    } else {
        at.resize(k);
        for (size_t i = 0; i < k; ++i) at[i] = uint32_t(i);
    }
    const size_t W = size_t(rs.state.width);
    std::vector<float> rows(at.size() * W);
    smooth_points(rs, at.size(), grid ? at.data() : nullptr, positions.data(), nullptr, triangles.data(), nullptr,
                  iteration, threads, rows.data(), nullptr);
    const std::vector<uint32_t> number = row_numbers(k, at);
    // Then per texel its row (its own, or its lattice points'), its look and its channels.
    const size_t P = slots.properties, C = kTextureChannels + P;
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, k, 4096), [&](const tbb::blocked_range<size_t>& r) {
            rs.cancel.check("the bake");
            std::vector<float> tex(3 * rs.textures.size() + 3, 0.0f), row(W);
            const float none[3] = {0.0f, 0.0f, 0.0f};
            float look[GAMMA_LOOK_WIDTH];
            for (size_t i = r.begin(); i < r.end(); ++i) {
                if (!lattice || lattice->smoothed(i)) {
                    std::copy_n(&rows[size_t(number[i]) * W], W, row.begin());
                } else {
                    for (size_t c = 0; c < W; ++c) {
                        double acc = 0;
                        for (size_t q = 0; q < 4; ++q) {
                            const uint32_t j = lattice->corner(i, q);
                            if (j != TexelLattice::kOwn)
                                acc += double(lattice->weight(i, q)) * double(rows[size_t(number[j]) * W + c]);
                        }
                        row[c] = float(acc);
                    }
                }
                const size_t t = size_t(tris[i]);
                const double* b = bary + 3 * i;
                double n[3];
                for (int d = 0; d < 3; ++d) {
                    double m = 0;
                    for (int c = 0; c < 3; ++c)
                        m += b[c] * double(layout.normals[3 * size_t(layout.corners[3 * t + size_t(c)]) + size_t(d)]);
                    n[d] = m;
                }
                const double length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                float normal[3], uv[2] = {0.0f, 0.0f};
                for (int d = 0; d < 3; ++d) normal[d] = float(n[d] / std::max(length, 1e-30));
                if (layout.lookup_uvs)
                    for (int d = 0; d < 2; ++d) {
                        double u = 0;
                        for (int c = 0; c < 3; ++c) u += b[c] * double(layout.lookup_uvs[6 * t + 2 * size_t(c) + size_t(d)]);
                        uv[d] = float(u);
                    }
                look_of_row(rs, uint32_t(triangles[i]), &positions[3 * i], normal, none, uv, iteration,
                            mix64(kRenderKey ^ uint64_t(i)), row.data(), tex.data(), look);
                float* o = channels_out + C * i;
                for (int c = 0; c < 3; ++c) o[c] = look[GAMMA_LOOK_COLOR + c];
                o[3] = look[GAMMA_LOOK_OCCLUSION];
                o[4] = look[GAMMA_LOOK_ROUGHNESS];
                o[5] = look[GAMMA_LOOK_METALLIC];
                o[6] = look[GAMMA_LOOK_DISPLACEMENT];
                const size_t s = size_t(slots.surface_of_triangle[size_t(triangles[i])]);
                for (size_t p = 0; p < P; ++p) {
                    const int32_t slot = s < slots.surfaces ? slots.slots[s * P + p] : -1;
                    o[kTextureChannels + p] = slot >= 0 && size_t(slot) < W ? row[size_t(slot)] : 0.0f;
                }
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
