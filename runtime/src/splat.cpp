#include "gamma/splat.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <utility>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "gamma/error.h"
#include "gamma/float_points.h"
#include "gamma/gmath.h"
#include "gamma/point_columns.h"

namespace gammart {

namespace {
// Large arrays, on huge pages (huge_pages.h).
template <class T>
using HugeArray = std::vector<T, HugePageAllocator<T>>;

constexpr float kRadiusInSigmas = 2.0f;
constexpr float kMinNormalDot = 0.5f;  // cos 60°
constexpr float kMaxPlaneOffsetInSigmas = 0.5f;  // a neighbour lies on the surfel's tangent plane

using Scatter = std::vector<std::vector<std::pair<uint32_t, float>>>;  // per source: (target, weight)

// The neighbourhood of source s, computed afresh: the surfels the tree finds
// within kRadiusInSigmas x sigma that pass the surface, normal and plane
// tests, and s itself, as (target, weight) in ascending target order.
// (The local update's form; build_splat_kernel finds the same sets by a
// sweep over columns.)
void radius_search(const FloatPointsKdTree& tree, const float* q, float r2,
                   std::vector<std::pair<uint32_t, float>>& found) {
    nanoflann::SearchParams params;
    params.sorted = false;
    tree.radiusSearch(q, r2, found, params);
}
template <class Search>
void fresh_neighbourhood(const Search& search, size_t s, const float* position, const float* normal,
                         const int32_t* surface, float sigma, std::vector<std::pair<uint32_t, float>>& found,
                         std::vector<double>& w, std::vector<std::pair<uint32_t, float>>& out) {
    const float r = kRadiusInSigmas * sigma;
    const float r2 = r * r;
    const double inv2s2 = sigma > 0 ? 1.0 / (2.0 * double(sigma) * double(sigma)) : 0.0;
    found.clear();
    out.clear();
    const float* ps = position + 3 * s;
    const float* ns = normal + 3 * s;
    if (r2 > 0) radius_search(search, ps, r2, found);
    double sum = 0;
    for (const auto& [j, d2] : found) {
        if (j == s || surface[j] != surface[s]) continue;
        const float* nj = normal + 3 * size_t(j);
        if (ns[0] * nj[0] + ns[1] * nj[1] + ns[2] * nj[2] < kMinNormalDot) continue;
        // Not on a parallel face nearby (the top of a step over the floor of a joint).
        const float* pj = position + 3 * size_t(j);
        const float off = (pj[0] - ps[0]) * ns[0] + (pj[1] - ps[1]) * ns[1] + (pj[2] - ps[2]) * ns[2];
        if (std::fabs(off) > kMaxPlaneOffsetInSigmas * sigma) continue;
        out.emplace_back(j, float(d2));
    }
    out.emplace_back(uint32_t(s), 0.0f);  // always in its own neighbourhood
    // by target (each target once: its distance never decides)
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    w.resize(out.size());
    for (size_t i = 0; i < out.size(); ++i) sum += (w[i] = double(gm::exp(float(-double(out[i].second) * inv2s2))));
    for (size_t i = 0; i < out.size(); ++i) out[i].second = float(w[i] / sum);
}

// The squared distance between surfels s and j as the kd-tree measures it
// from query s (float, term by term), 0 for s itself.
float kernel_distance2(const float* position, size_t s, size_t j) {
    if (s == j) return 0.0f;
    const float* ps = position + 3 * s;
    const float* pj = position + 3 * j;
    float d2 = 0.0f;
    for (int c = 0; c < 3; ++c) {
        const float d = ps[c] - pj[c];
        d2 += d * d;
    }
    return d2;
}

// The build's searches sweep columns: the surfels are binned into square
// columns over the two widest axes of their box (wider than the search
// reach, so a neighbour lies in the same column or one of the 8 around it)
// and sorted by the third coordinate within each; a column's surfels are
// taken in that order, so the first candidate in each neighbouring column
// only moves forward (no binary search per query).  The candidates are
// those whose third coordinate lies within the reach, as PointColumns scans
// them; the final test is the kd-tree's float metric.
struct SweepColumns {
    int u = 0, v = 1, w = 2;  // column axes, sorted axis
    int nu = 1, nv = 1;
    double lo_u = 0, lo_v = 0, inv_side = 1;
    std::vector<uint32_t> start;  // per column (u major), then the end
    HugeArray<uint32_t> id;        // sorted: original index
    HugeArray<float> key;          // sorted: the w coordinate (NaN as +inf: never within reach)
    HugeArray<float> pos, nrm;     // sorted positions and normals
    HugeArray<int32_t> surf;       // sorted surfaces


    void build(const float* p, const float* normal, const int32_t* surface, size_t n, double reach) {
        double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
        bool any = false;
        for (size_t i = 0; i < n; ++i) {
            const float* q = p + 3 * i;
            if (!(std::isfinite(q[0]) && std::isfinite(q[1]) && std::isfinite(q[2]))) continue;
            for (int k = 0; k < 3; ++k) {
                lo[k] = any ? std::min(lo[k], double(q[k])) : double(q[k]);
                hi[k] = any ? std::max(hi[k], double(q[k])) : double(q[k]);
            }
            any = true;
        }
        int axes[3];
        axes_by_extent(lo, hi, axes);
        const double eu = hi[axes[0]] - lo[axes[0]], ev = hi[axes[1]] - lo[axes[1]];
        // Wider than the reach by far more than the rounding of the column
        // numbers; at most about 2 columns per point (column_layout) and 4096
        // a side.
        double side = std::max({reach * (1.0 + 1e-4), eu / 4096.0, ev / 4096.0});
        if (!(side > 0) || !std::isfinite(side)) side = std::max(eu, ev) + 1.0;
        const ColumnLayout g = column_layout(lo, hi, axes, side, n);
        u = g.u, v = g.v, w = g.w;
        lo_u = g.lo_u, lo_v = g.lo_v, inv_side = g.inv_side;
        nu = g.nu, nv = g.nv;
        const size_t ncol = size_t(nu) * size_t(nv);
        bin_into_columns(p, n, u, v, lo_u, lo_v, inv_side, nu, nv, start, id);
        key.resize(n);
        pos.resize(3 * n);
        nrm.resize(3 * n);
        surf.resize(n);
        const auto key_of = [&](size_t i) {
            const float z = p[3 * i + size_t(w)];
            return std::isnan(z) ? std::numeric_limits<float>::infinity() : z;
        };
        tbb::parallel_for(tbb::blocked_range<size_t>(0, ncol, 1024), [&](const tbb::blocked_range<size_t>& range) {
            for (size_t c = range.begin(); c < range.end(); ++c) {
                const uint32_t b = start[c], e = start[c + 1];
                // by the third coordinate, then index (a fixed order)
                std::sort(id.begin() + std::ptrdiff_t(b), id.begin() + std::ptrdiff_t(e), [&](uint32_t x, uint32_t y) {
                    const float zx = key_of(x), zy = key_of(y);
                    return zx < zy || (zx == zy && x < y);
                });
                for (uint32_t k = b; k < e; ++k) {
                    const size_t i = id[k];
                    key[k] = key_of(i);
                    for (size_t d = 0; d < 3; ++d) {
                        pos[3 * k + d] = p[3 * i + d];
                        nrm[3 * k + d] = normal[3 * i + d];
                    }
                    surf[k] = surface[i];
                }
            }
        });
    }
};

// A chunk of consecutive columns' targets, in sweep order, with their
// gather lists side by side: each entry's source and Gaussian (divided by
// the source's sum once every sum is known).
struct GatherChunk {
    size_t first_column = 0, end_column = 0;
    std::vector<uint32_t> target;
    HugeArray<uint32_t> source;
    HugeArray<double> gauss;
};
constexpr size_t kPointsPerChunk = 2048;

// How many of ids[0, count) are smaller than id (count a multiple of 4).
inline size_t rank_among(const uint32_t* ids, size_t count, uint32_t id) {
#if defined(__SSE2__)
    // unsigned order by a signed compare of the values with the top bit flipped
    const __m128i flip = _mm_set1_epi32(int32_t(0x80000000u));
    const __m128i key = _mm_xor_si128(_mm_set1_epi32(int32_t(id)), flip);
    __m128i acc = _mm_setzero_si128();
    for (size_t b = 0; b < count; b += 4) {
        const __m128i v = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i*>(ids + b)), flip);
        acc = _mm_sub_epi32(acc, _mm_cmplt_epi32(v, key));  // a lane's mask is -1 where smaller
    }
    acc = _mm_add_epi32(acc, _mm_shuffle_epi32(acc, _MM_SHUFFLE(1, 0, 3, 2)));
    acc = _mm_add_epi32(acc, _mm_shuffle_epi32(acc, _MM_SHUFFLE(2, 3, 0, 1)));
    return size_t(uint32_t(_mm_cvtsi128_si32(acc)));
#else
    size_t rank = 0;
    for (size_t b = 0; b < count; ++b) rank += ids[b] < id;
    return rank;
#endif
}

// Neighbourhoods up to this size are ordered by ranking (four comparisons at
// a time, no branch; ~h^2/4 steps), larger ones by a sort (h log h): a
// surface of normal density has ~12, stacked coincident sheets hundreds.
constexpr size_t kRankedHoodMax = 64;

struct HoodEntry {
    uint32_t id;
    float d2;
    uint32_t in;  // 1: in the target's own neighbourhood; 2: the target is in its
};

// The search radius and plane tests of a kernel of width sigma.
struct HoodLimits {
    float r2, max_offset;
    double inv2s2, reach;
    bool search;
    explicit HoodLimits(float sigma) {
        const float r = kRadiusInSigmas * sigma;
        r2 = r * r;
        inv2s2 = sigma > 0 ? 1.0 / (2.0 * double(sigma) * double(sigma)) : 0.0;
        max_offset = kMaxPlaneOffsetInSigmas * sigma;
        search = r2 > 0;
        // |q_k - p_k| <= sqrt(d2) * (1 + 2e-7) for the float metric: a pad of
        // 1e-5 relative covers it many times over (as PointColumns).
        reach = search ? std::sqrt(double(r2)) * (1.0 + 1e-5) + 1e-30 : 0.0;
    }
};

// Consecutive columns in chunks of about kPointsPerChunk targets.
std::vector<GatherChunk> gather_chunks(const SweepColumns& cols) {
    std::vector<GatherChunk> chunks;
    const size_t ncol = cols.start.size() - 1;
    size_t first = 0;
    for (size_t c = 0; c < ncol; ++c)
        if (cols.start[c + 1] - cols.start[first] >= kPointsPerChunk || c + 1 == ncol) {
            chunks.emplace_back();
            chunks.back().first_column = first;
            chunks.back().end_column = c + 1;
            first = c + 1;
        }
    return chunks;
}

// The candidates of one column's targets: a window into each of the (up to
// nine) columns around it, sliding forward along the sweep axis as the
// targets do.
struct ColumnWindows {
    uint32_t next[9], last[9], stop[9];
    int m = 0;
    ColumnWindows(const SweepColumns& cols, size_t c) {
        const int ci = int(c / size_t(cols.nv)), cj = int(c % size_t(cols.nv));
        for (int i = std::max(ci - 1, 0); i <= std::min(ci + 1, cols.nu - 1); ++i)
            for (int j = std::max(cj - 1, 0); j <= std::min(cj + 1, cols.nv - 1); ++j) {
                const size_t nc = size_t(i) * size_t(cols.nv) + size_t(j);
                if (cols.start[nc] == cols.start[nc + 1]) continue;
                next[m] = last[m] = cols.start[nc];
                stop[m] = cols.start[nc + 1];
                ++m;
            }
    }
};

// One thread's work on its chunks of targets, with its scratch.
class HoodGatherer {
public:
    HoodGatherer(const SweepColumns& cols, const HoodLimits& lim, HugeArray<uint32_t>& count, HugeArray<double>& sum)
        : cols_(cols), lim_(lim), count_(count), sum_(sum) {}

    void gather(GatherChunk& G) {
        const size_t points = cols_.start[G.end_column] - cols_.start[G.first_column];
        G.target.reserve(points);
        G.source.resize(points * 16);
        G.gauss.resize(points * 16);
        size_t gn = 0;  // entries written
        for (size_t c = G.first_column; c < G.end_column; ++c) {
            if (cols_.start[c] == cols_.start[c + 1]) continue;
            ColumnWindows win(cols_, c);
            for (uint32_t t = cols_.start[c]; t < cols_.start[c + 1]; ++t) gn = add_target(G, gn, win, t);
        }
        G.source.resize(gn);
        G.gauss.resize(gn);
    }

private:
    // Target t's entries after the first gn of G; returns the new count.
    size_t add_target(GatherChunk& G, size_t gn, ColumnWindows& win, uint32_t t) {
        const float* q = &cols_.pos[3 * size_t(t)];
        size_t nh = 0;
        if (lim_.search && std::isfinite(q[0]) && std::isfinite(q[1]) && std::isfinite(q[2]))
            nh = plane_tests(t, within_radius(win, q));
        const uint32_t tid = cols_.id[t];
        if (hood_.size() < nh + 1) hood_.resize(nh + 1);
        hood_[nh++] = {tid, 0.0f, 3u};  // always in its own neighbourhood
        sort_by_neighbour(nh);
        double s = 0;
        if (G.source.size() < gn + nh) {
            G.source.resize(std::max(2 * G.source.size(), gn + nh));
            G.gauss.resize(G.source.size());
        }
        const size_t g0 = gn;
        for (size_t a = 0; a < nh; ++a) {
            const HoodEntry& h = sorted_[a];
            const double g = double(gm::exp(float(-double(h.d2) * lim_.inv2s2)));
            s += (h.in & 1u) ? g : 0.0;  // (adding 0 to a sum of positive terms: the same sum)
            G.source[gn] = h.id;
            G.gauss[gn] = g;
            gn += h.in >> 1;
        }
        sum_[tid] = s;
        count_[tid] = uint32_t(gn - g0);
        G.target.push_back(tid);
        return gn;
    }

    // The candidates within the radius of q (found_[0, returned)), by the
    // float metric (PointColumns::metric, the kd-tree's, spelt out).
    size_t within_radius(ColumnWindows& win, const float* q) {
        const double cw = double(q[cols_.w]);
        const float c0 = float(cw - lim_.reach), c1 = float(cw + lim_.reach);
        size_t nf = 0;
        const float* key = cols_.key.data();
        const float* pos = cols_.pos.data();
        for (int b = 0; b < win.m; ++b) {
            // both ends of the window only move forward (c0 and c1 do)
            uint32_t x = win.next[b], y = win.last[b];
            while (x < win.stop[b] && key[x] < c0) ++x;
            y = std::max(x, y);
            while (y < win.stop[b] && !(key[y] > c1)) ++y;
            win.next[b] = x;
            win.last[b] = y;
            // every candidate written, the end advanced past those within only
            if (found_.size() < nf + (y - x)) found_.resize(std::max(2 * found_.size(), nf + (y - x)));
            std::pair<uint32_t, float>* o = found_.data();
            for (; x < y; ++x) {
                const float* p = pos + 3 * size_t(x);
                const float d0 = q[0] - p[0], d1 = q[1] - p[1], dz = q[2] - p[2];
                const float d2 = d0 * d0 + d1 * d1 + dz * dz;
                o[nf] = {x, d2};
                nf += d2 < lim_.r2;
            }
        }
        return nf;
    }

    // Of found_[0, nf): those of t's surface with normals within 60 degrees,
    // in t's neighbourhood (on its tangent plane) or t in theirs, into
    // hood_[0, returned).
    size_t plane_tests(uint32_t t, size_t nf) {
        const float* q = &cols_.pos[3 * size_t(t)];
        const float* nq = &cols_.nrm[3 * size_t(t)];
        const int32_t sq = cols_.surf[t];
        // every candidate written, the end advanced past those kept only
        if (hood_.size() < nf + 1) hood_.resize(2 * (nf + 1));
        size_t nh = 0;
        for (size_t f = 0; f < nf; ++f) {
            const uint32_t x = found_[f].first;
            const float* nx = &cols_.nrm[3 * size_t(x)];
            const float* px = &cols_.pos[3 * size_t(x)];
            // off the target's tangent plane, and the target off x's
            const float off_t = (px[0] - q[0]) * nq[0] + (px[1] - q[1]) * nq[1] + (px[2] - q[2]) * nq[2];
            const float off_x = (q[0] - px[0]) * nx[0] + (q[1] - px[1]) * nx[1] + (q[2] - px[2]) * nx[2];
            const bool pair = (x != t) & (cols_.surf[x] == sq) &
                              !(nq[0] * nx[0] + nq[1] * nx[1] + nq[2] * nx[2] < kMinNormalDot);
            const uint32_t in = ((std::fabs(off_t) > lim_.max_offset ? 0u : 1u) |
                                 (std::fabs(off_x) > lim_.max_offset ? 0u : 2u)) &
                                (0u - uint32_t(pair));
            hood_[nh] = {cols_.id[x], found_[f].second, in};
            nh += in != 0;
        }
        return nh;
    }

    // hood_[0, nh) into sorted_ by neighbour (each once): each entry placed
    // at its rank (a count of smaller ones, no branch on the comparisons);
    // ranking is quadratic, so a crowd (stacked sheets) is sorted instead
    // (ids are distinct: the same order).
    void sort_by_neighbour(size_t nh) {
        if (sorted_.size() < nh) sorted_.resize(hood_.size());
        if (nh <= kRankedHoodMax) {
            const size_t padded = (nh + 3) & ~size_t(3);
            if (ids_.size() < padded) ids_.resize(2 * padded);
            for (size_t a = 0; a < nh; ++a) ids_[a] = hood_[a].id;
            for (size_t a = nh; a < padded; ++a) ids_[a] = UINT32_MAX;  // never smaller
            for (size_t a = 0; a < nh; ++a) sorted_[rank_among(ids_.data(), padded, ids_[a])] = hood_[a];
        } else {
            std::copy(hood_.begin(), hood_.begin() + std::ptrdiff_t(nh), sorted_.begin());
            std::sort(sorted_.begin(), sorted_.begin() + std::ptrdiff_t(nh),
                      [](const HoodEntry& a, const HoodEntry& b) { return a.id < b.id; });
        }
    }

    const SweepColumns& cols_;
    const HoodLimits& lim_;
    HugeArray<uint32_t>& count_;   // each target's gather entries
    HugeArray<double>& sum_;       // each source's sum of weights
    std::vector<std::pair<uint32_t, float>> found_;  // (sorted index, d2)
    std::vector<HoodEntry> hood_, sorted_;
    std::vector<uint32_t> ids_;  // the hood's, padded to a multiple of 4
};

// The kernel from the chunks' gather lists, once every source's sum is known.
void write_kernel(SplatKernel& k, const std::vector<GatherChunk>& chunks, const HugeArray<uint32_t>& count,
                  const HugeArray<double>& sum, size_t n) {
    for (size_t j = 0; j < n; ++j) {
        if (uint64_t(k.offset[j]) + count[j] > uint64_t(UINT32_MAX)) throw Error("splat kernel: too many entries");
        k.offset[j + 1] = k.offset[j] + count[j];
    }
    const size_t total = k.offset[n];
    k.source.resize(total);
    k.weight.resize(total);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, chunks.size(), 1), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t ch = range.begin(); ch < range.end(); ++ch) {
            const GatherChunk& G = chunks[ch];
            size_t at = 0;
            for (const uint32_t t : G.target)
                for (uint32_t e = k.offset[t]; e < k.offset[size_t(t) + 1]; ++e, ++at) {
                    const uint32_t s = G.source[at];
                    k.source[e] = s;
                    k.weight[e] = float(G.gauss[at] / sum[s]);
                }
        }
    });
    k.mean_neighbours = double(total) / double(n);
}
}  // namespace

// The neighbour relation before the plane test (within the radius by the
// float metric, same surface, normals within 60 degrees) is symmetric bit
// for bit: the metric squares differences that only change sign and sums
// them in axis order, the dot product's products commute (splat.cpp is
// built without contraction into fused multiply-adds, so both orders round
// alike on any target); so is the Gaussian of the distance.  So one pass
// over target t's candidates gives both t's own neighbourhood (the plane
// test against t's tangent plane: t's sum of weights, in ascending
// neighbour order as fresh_neighbourhood sums it) and the sources whose
// neighbourhood holds t (the test against theirs: t's gather list, in
// ascending source order), and the kernel needs no transposition: once
// every sum is known, each entry is its Gaussian over its source's sum.
// Entries, sums and weights are fresh_neighbourhood's bit for bit.
SplatKernel build_splat_kernel(const float* position, const float* normal, const int32_t* surface, size_t n,
                               float sigma) {
    SplatKernel k;
    k.offset.assign(n + 1, 0);
    if (n == 0) return k;
    const HoodLimits lim(sigma);
    SweepColumns cols;
    cols.build(position, normal, surface, n, lim.search ? lim.reach : 1.0);
    std::vector<GatherChunk> chunks = gather_chunks(cols);
    HugeArray<uint32_t> count(n);
    HugeArray<double> sum(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, chunks.size(), 1), [&](const tbb::blocked_range<size_t>& range) {
        HoodGatherer gatherer(cols, lim, count, sum);
        for (size_t ch = range.begin(); ch < range.end(); ++ch) gatherer.gather(chunks[ch]);
    });
    // only the order of the targets is needed from here on: the rest of the
    // columns freed before the kernel's arrays are allocated (a lower peak)
    HugeArray<float>().swap(cols.key);
    HugeArray<float>().swap(cols.pos);
    HugeArray<float>().swap(cols.nrm);
    HugeArray<int32_t>().swap(cols.surf);
    write_kernel(k, chunks, count, sum, n);
    return k;
}

SplatKernel update_splat_kernel(const SplatKernel& old, const float* position, const float* normal,
                                const int32_t* surface, size_t n, float sigma, const std::vector<uint32_t>& replaced,
                                const FloatPointsKdTree* given) {
    if (old.offset.size() != n + 1) return build_splat_kernel(position, normal, surface, n, sigma);
    // The searches need exact sets only: the caller's tree over the same
    // points answers them as one built here would.
    FloatPoints pts{position, n};
    std::unique_ptr<FloatPointsKdTree> own;
    if (!given) {
        own = std::make_unique<FloatPointsKdTree>(3, pts, nanoflann::KDTreeSingleIndexAdaptorParams(10));
        own->buildIndex();
    }
    const FloatPointsKdTree& tree = given ? *given : *own;
    // Which sources get a fresh neighbourhood: the replaced surfels, the
    // sources whose neighbourhood held one (they lost a target), and every
    // surfel within the kernel radius of a replaced surfel's new position
    // (it may gain one).  The radius test is symmetric (the same float
    // metric both ways), so no source the fresh rule would give a new
    // surfel keeps its old neighbourhood.
    std::vector<uint8_t> fresh(n, 0);
    for (uint32_t r : replaced) {
        fresh[r] = 1;
        for (uint32_t e = old.offset[r]; e < old.offset[size_t(r) + 1]; ++e) fresh[old.source[e]] = 1;
    }
    const float radius = kRadiusInSigmas * sigma;
    std::vector<std::vector<std::pair<uint32_t, float>>> near(replaced.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, replaced.size(), 64), [&](const tbb::blocked_range<size_t>& range) {
        nanoflann::SearchParams params;
        params.sorted = false;
        for (size_t k = range.begin(); k < range.end(); ++k)
            if (radius > 0) tree.radiusSearch(position + 3 * size_t(replaced[k]), radius * radius, near[k], params);
    });
    for (const auto& found : near)
        for (const auto& f : found) fresh[f.first] = 1;
    // The others keep their targets: the old kernel turned into scatter
    // form by a counting pass over flat arrays (iterating targets in
    // ascending order leaves every source's targets ascending), weighted as
    // reweight_splat_kernel does (the same exponentials, each source's sum
    // in ascending target order).
    std::vector<uint32_t> kept_at(n + 1, 0);
    for (size_t e = 0; e < old.source.size(); ++e)
        if (!fresh[old.source[e]]) ++kept_at[size_t(old.source[e]) + 1];
    for (size_t s = 0; s < n; ++s) kept_at[s + 1] += kept_at[s];
    std::vector<uint32_t> kept_target(kept_at[n]);
    std::vector<float> kept_weight(kept_at[n]);
    {
        std::vector<uint32_t> fill(kept_at.begin(), kept_at.end() - 1);
        for (size_t j = 0; j < n; ++j)
            for (uint32_t e = old.offset[j]; e < old.offset[j + 1]; ++e)
                if (!fresh[old.source[e]]) kept_target[fill[old.source[e]]++] = uint32_t(j);
    }
    std::vector<uint32_t> fresh_sources;
    for (size_t s = 0; s < n; ++s)
        if (fresh[s]) fresh_sources.push_back(uint32_t(s));
    Scatter fresh_lists(fresh_sources.size());
    const double inv2s2 = sigma > 0 ? 1.0 / (2.0 * double(sigma) * double(sigma)) : 0.0;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, fresh_sources.size(), 64),
                      [&](const tbb::blocked_range<size_t>& range) {
                          std::vector<std::pair<uint32_t, float>> found;
                          std::vector<double> w;
                          for (size_t k = range.begin(); k < range.end(); ++k)
                              fresh_neighbourhood(tree, fresh_sources[k], position, normal, surface, sigma, found, w,
                                                  fresh_lists[k]);
                      });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
        std::vector<double> w;
        for (size_t s = range.begin(); s < range.end(); ++s) {
            const uint32_t b = kept_at[s], e = kept_at[s + 1];
            w.resize(e - b);
            double sum = 0;
            for (uint32_t i = b; i < e; ++i)
                sum += (w[i - b] = double(gm::exp(float(-double(kernel_distance2(position, s, kept_target[i])) * inv2s2))));
            for (uint32_t i = b; i < e; ++i) kept_weight[i] = float(w[i - b] / sum);
        }
    });
    // Gather form, sources in ascending order (as build_splat_kernel).
    SplatKernel k;
    k.offset.assign(n + 1, 0);
    size_t total = kept_at[n];
    for (uint32_t t : kept_target) ++k.offset[size_t(t) + 1];
    for (const auto& list : fresh_lists) {
        total += list.size();
        for (const auto& e : list) ++k.offset[size_t(e.first) + 1];
    }
    for (size_t j = 0; j < n; ++j) k.offset[j + 1] += k.offset[j];
    k.source.resize(total);
    k.weight.resize(total);
    std::vector<uint32_t> fill(k.offset.begin(), k.offset.end() - 1);
    size_t next_fresh = 0;
    for (size_t s = 0; s < n; ++s) {
        if (fresh[s]) {
            for (const auto& [j, w] : fresh_lists[next_fresh++]) {
                const uint32_t at = fill[j]++;
                k.source[at] = uint32_t(s);
                k.weight[at] = w;
            }
            continue;
        }
        for (uint32_t i = kept_at[s]; i < kept_at[s + 1]; ++i) {
            const uint32_t at = fill[kept_target[i]]++;
            k.source[at] = uint32_t(s);
            k.weight[at] = kept_weight[i];
        }
    }
    k.mean_neighbours = double(total) / double(n);
    return k;
}

void reweight_splat_kernel(SplatKernel& k, const float* position, size_t n, float sigma) {
    if (k.offset.size() != n + 1) return;  // no kernel (spreading off): nothing to refresh
    const double inv2s2 = sigma > 0 ? 1.0 / (2.0 * double(sigma) * double(sigma)) : 0.0;
    std::vector<double> w(k.source.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t j = range.begin(); j < range.end(); ++j)
            for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e)
                w[e] = double(gm::exp(float(-double(kernel_distance2(position, k.source[e], j)) * inv2s2)));
    });
    // Each source's sum over its targets in ascending target order, as at build.
    std::vector<double> sum(n, 0.0);
    for (size_t j = 0; j < n; ++j)
        for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) sum[k.source[e]] += w[e];
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t j = range.begin(); j < range.end(); ++j)
            for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) k.weight[e] = float(w[e] / sum[k.source[e]]);
    });
}

void apply_splat(const SplatKernel& k, const float* in, float* out, size_t n, int P) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t j = range.begin(); j < range.end(); ++j) {
            float* o = out + j * size_t(P);
            std::fill(o, o + P, 0.0f);
            for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e) {
                const float w = k.weight[e];
                const float* src = in + size_t(k.source[e]) * size_t(P);
                for (int c = 0; c < P; ++c) o[c] += w * src[c];
            }
        }
    });
}

}  // namespace gammart
