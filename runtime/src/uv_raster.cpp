// UV-space rasterisation of a texture layout (see gamma/uv_raster.h).
#include "gamma/uv_raster.h"

#include <algorithm>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <vector>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

// A triangle in texel coordinates, with the texel rows its box covers.
struct UvTriangle {
    double x[3], y[3], det;
    int64_t i0, i1, j0, j1;
};

// Rows [first, end) of the band (rows local to row0): each texel's owner
// (the lowest-numbered triangle covering it, triangles taken in increasing
// order) and barycentrics.
void rasterise_rows(const std::vector<UvTriangle>& tris, const std::vector<int32_t>& order, int row0, size_t first,
                    size_t end, size_t cols, int32_t* owner, double* found) {
    for (int32_t t : order) {
        const UvTriangle& g = tris[size_t(t)];
        const int64_t i0 = std::max<int64_t>(g.i0, int64_t(row0) + int64_t(first));
        const int64_t i1 = std::min<int64_t>(g.i1, int64_t(row0) + int64_t(end) - 1);
        const double* x = g.x;
        const double* y = g.y;
        const double det = g.det;
        for (int64_t i = i0; i <= i1; ++i)
            for (int64_t j = g.j0; j <= g.j1; ++j) {
                const size_t at = size_t(i - row0) * cols + size_t(j);
                if (owner[at] >= 0) continue;  // a lower-numbered triangle has it
                const double px = double(j), py = double(i);
                const double l1 = ((y[1] - y[2]) * (px - x[2]) + (x[2] - x[1]) * (py - y[2])) / det;
                const double l2 = ((y[2] - y[0]) * (px - x[2]) + (x[0] - x[2]) * (py - y[2])) / det;
                const double l3 = 1 - l1 - l2;
                if (l1 >= -1e-9 && l2 >= -1e-9 && l3 >= -1e-9) {
                    owner[at] = int32_t(t);
                    found[3 * at] = l1;
                    found[3 * at + 1] = l2;
                    found[3 * at + 2] = l3;
                }
            }
    }
}

}  // namespace

UvRaster rasterise_uv(const double* uvs, size_t m, int size, int row0, int row1, int tile, int threads) {
    if (size < 1 || row0 < 0 || row1 > size || row0 > row1) throw Error("rasterise_uv: rows out of range");
    if (tile < 1) throw Error("rasterise_uv: the tile must be at least 1 texel");
    const size_t rows = size_t(row1 - row0), cols = size_t(size);
    auto clip = [&](double v) { return int64_t(std::min(std::max(v, 0.0), double(size - 1))); };
    std::vector<UvTriangle> tris(m);
    // Rows are rasterised in strips of whole tiles, in parallel: each strip
    // takes the triangles whose boxes reach it, in increasing order.
    const size_t T = size_t(tile);
    const size_t strip = std::max<size_t>(T, (16 + T - 1) / T * T);
    const size_t strips = (rows + strip - 1) / strip;
    std::vector<std::vector<int32_t>> in_strip(strips);
    for (size_t t = 0; t < m; ++t) {
        const double* c = uvs + 6 * t;
        UvTriangle& g = tris[t];
        bool finite = true;
        for (int k = 0; k < 3; ++k) {
            g.x[k] = c[2 * k] * size - 0.5;
            g.y[k] = (1 - c[2 * k + 1]) * size - 0.5;
            finite = finite && std::isfinite(g.x[k]) && std::isfinite(g.y[k]);
        }
        if (!finite) continue;
        const double* x = g.x;
        const double* y = g.y;
        g.det = (y[1] - y[2]) * (x[0] - x[2]) + (x[2] - x[1]) * (y[0] - y[2]);
        if (std::fabs(g.det) < 1e-18) continue;
        g.j0 = clip(std::floor(std::min({x[0], x[1], x[2]})));
        g.j1 = clip(std::ceil(std::max({x[0], x[1], x[2]})));
        g.i0 = std::max<int64_t>(clip(std::floor(std::min({y[0], y[1], y[2]}))), row0);
        g.i1 = std::min<int64_t>(clip(std::ceil(std::max({y[0], y[1], y[2]}))), row1 - 1);
        if (g.i0 > g.i1) continue;
        for (size_t s = size_t(g.i0 - row0) / strip; s <= size_t(g.i1 - row0) / strip; ++s)
            in_strip[s].push_back(int32_t(t));
    }
    std::vector<int32_t> owner(rows * cols, -1);
    std::vector<double> found(rows * cols * 3);
    std::vector<UvRaster> parts(strips);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, strips, 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t s = r.begin(); s < r.end(); ++s) {
                const size_t first = s * strip, end = std::min(rows, first + strip);
                rasterise_rows(tris, in_strip[s], row0, first, end, cols, owner.data(), found.data());
                // the strip's texels tile by tile (strips are whole tiles, so in the band's order)
                UvRaster& out = parts[s];
                for (size_t ti = first; ti < end; ti += T)
                    for (size_t tj = 0; tj < cols; tj += T)
                        for (size_t i = ti; i < std::min(end, ti + T); ++i)
                            for (size_t j = tj; j < std::min(cols, tj + T); ++j) {
                                const size_t at = i * cols + j;
                                if (owner[at] < 0) continue;
                                out.texels.push_back(int64_t(row0) * int64_t(cols) + int64_t(at));
                                out.tris.push_back(owner[at]);
                                out.bary.insert(out.bary.end(), found.begin() + long(3 * at),
                                                found.begin() + long(3 * at + 3));
                            }
            }
        });
    });
    UvRaster out;
    size_t total = 0;
    for (const UvRaster& p : parts) total += p.tris.size();
    out.texels.reserve(total);
    out.tris.reserve(total);
    out.bary.reserve(3 * total);
    for (const UvRaster& p : parts) {
        out.texels.insert(out.texels.end(), p.texels.begin(), p.texels.end());
        out.tris.insert(out.tris.end(), p.tris.begin(), p.tris.end());
        out.bary.insert(out.bary.end(), p.bary.begin(), p.bary.end());
    }
    return out;
}

}  // namespace gammart

namespace gammart {

void dilate_charts(float* image, int32_t* label, size_t rows, size_t cols, size_t channels, int passes,
                   int threads) {
    if (rows == 0 || cols == 0) return;
    const size_t n = rows * cols, C = channels;
    const long dy[8] = {-1, -1, -1, 0, 0, 1, 1, 1}, dx[8] = {-1, 0, 1, -1, 1, -1, 0, 1};
    // The ring texel's neighbours in order: their flat index, or n off the image.
    auto neighbours = [&](size_t at, size_t out[8]) {
        const long i = long(at / cols), j = long(at % cols);
        for (int s = 0; s < 8; ++s) {
            const long r = i + dy[s], c = j + dx[s];
            out[s] = (r < 0 || r >= long(rows) || c < 0 || c >= long(cols)) ? n : size_t(r) * cols + size_t(c);
        }
    };
    std::vector<int32_t> queued(n, -1);  // the pass that queued a texel
    std::vector<size_t> ring, next;
    for (size_t at = 0; at < n; ++at) {
        if (label[at] >= 0) continue;
        size_t nb[8];
        neighbours(at, nb);
        for (size_t s : nb)
            if (s < n && label[s] >= 0) {
                ring.push_back(at);
                queued[at] = 0;
                break;
            }
    }
    std::vector<int32_t> best;
    std::vector<float> mean;
    for (int pass = 0; pass < passes && !ring.empty(); ++pass) {
        best.assign(ring.size(), -1);
        mean.assign(ring.size() * C, 0.0f);
        run_with_threads(threads, [&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, ring.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
                std::vector<double> sum(C);
                for (size_t q = r.begin(); q < r.end(); ++q) {
                    size_t nb[8];
                    neighbours(ring[q], nb);
                    int32_t around[8];
                    for (int s = 0; s < 8; ++s) around[s] = nb[s] < n ? label[nb[s]] : -1;
                    // the chart most neighbours belong to, the lowest-numbered on a tie
                    int32_t chosen = -1, chosen_votes = 0;
                    for (int s = 0; s < 8; ++s) {
                        if (around[s] < 0) continue;
                        int32_t votes = 0;
                        for (int t = 0; t < 8; ++t) votes += around[t] == around[s];
                        if (votes > chosen_votes || (votes == chosen_votes && around[s] < chosen)) {
                            chosen = around[s];
                            chosen_votes = votes;
                        }
                    }
                    best[q] = chosen;
                    std::fill(sum.begin(), sum.end(), 0.0);
                    int64_t count = 0;
                    for (int s = 0; s < 8; ++s) {
                        if (around[s] != chosen) continue;
                        const float* v = image + nb[s] * C;
                        for (size_t c = 0; c < C; ++c) sum[c] += double(v[c]);
                        ++count;
                    }
                    for (size_t c = 0; c < C; ++c) mean[q * C + c] = float(sum[c] / double(count));
                }
            });
        });
        for (size_t q = 0; q < ring.size(); ++q) {
            std::copy(mean.begin() + long(q * C), mean.begin() + long((q + 1) * C), image + ring[q] * C);
            label[ring[q]] = best[q];
        }
        if (pass + 1 == passes) break;
        // the next ring: empty neighbours of this one
        next.clear();
        for (size_t at : ring) {
            size_t nb[8];
            neighbours(at, nb);
            for (size_t s : nb)
                if (s < n && label[s] < 0 && queued[s] != pass + 1) {
                    queued[s] = pass + 1;
                    next.push_back(s);
                }
        }
        ring.swap(next);
    }
}

}  // namespace gammart
