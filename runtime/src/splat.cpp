#include "gamma/splat.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <utility>

#include "gamma/error.h"
#include "gamma/float_points.h"
#include "gamma/point_columns.h"

namespace gammart {

namespace {
constexpr float kRadiusInSigmas = 2.0f;
constexpr double kColumnSpacings = 2.0;  // column width of the build's index, in sigmas
constexpr float kMinNormalDot = 0.5f;  // cos 60°
constexpr float kMaxPlaneOffsetInSigmas = 0.5f;  // a neighbour lies on the surfel's tangent plane

using Scatter = std::vector<std::vector<std::pair<uint32_t, float>>>;  // per source: (target, weight)

// The neighbourhood of source s, computed afresh: the surfels the tree finds
// within kRadiusInSigmas x sigma that pass the surface, normal and plane
// tests, and s itself, as (target, weight) in ascending target order.
// `search` is a kd-tree or a PointColumns over the same positions (the same
// sets, in different orders; only the set matters here).
void radius_search(const FloatPointsKdTree& tree, const float* q, float r2,
                   std::vector<std::pair<uint32_t, float>>& found) {
    nanoflann::SearchParams params;
    params.sorted = false;
    tree.radiusSearch(q, r2, found, params);
}
void radius_search(const PointColumns& cols, const float* q, float r2,
                   std::vector<std::pair<uint32_t, float>>& found) {
    cols.append_within(q, r2, found, [](uint32_t i, float d2) { return std::pair<uint32_t, float>(i, d2); });
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
    for (size_t i = 0; i < out.size(); ++i) sum += (w[i] = std::exp(-double(out[i].second) * inv2s2));
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

// The neighbourhoods of kSourcesPerBlock consecutive sources, side by side
// (one allocation per block, not per source): source `first + i`'s entries
// are entries[i ? end[i - 1] : 0, end[i]).
constexpr size_t kSourcesPerBlock = 256;
struct ScatterBlock {
    std::vector<std::pair<uint32_t, float>> entries;
    std::vector<uint32_t> end;
};

SplatKernel gather_form(const std::vector<ScatterBlock>& blocks, size_t n);
}  // namespace

SplatKernel build_splat_kernel(const float* position, const float* normal, const int32_t* surface, size_t n,
                               float sigma) {
    SplatKernel k;
    k.offset.assign(n + 1, 0);
    if (n == 0) return k;
    // The neighbourhoods' radius searches on a column index (the sets a
    // kd-tree gives, found in contiguous memory).
    PointColumns cols;
    cols.build(position, n, kColumnSpacings * double(sigma));
    // Scatter lists per source surfel: (target, weight), computed in parallel.
    std::vector<ScatterBlock> blocks((n + kSourcesPerBlock - 1) / kSourcesPerBlock);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, blocks.size(), 1), [&](const tbb::blocked_range<size_t>& range) {
        std::vector<std::pair<uint32_t, float>> found, out;
        std::vector<double> w;
        for (size_t b = range.begin(); b < range.end(); ++b) {
            ScatterBlock& B = blocks[b];
            for (size_t s = b * kSourcesPerBlock; s < std::min(n, (b + 1) * kSourcesPerBlock); ++s) {
                fresh_neighbourhood(cols, s, position, normal, surface, sigma, found, w, out);
                B.entries.insert(B.entries.end(), out.begin(), out.end());
                B.end.push_back(uint32_t(B.entries.size()));
            }
        }
    });
    return gather_form(blocks, n);
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
                sum += (w[i - b] = std::exp(-double(kernel_distance2(position, s, kept_target[i])) * inv2s2));
            for (uint32_t i = b; i < e; ++i) kept_weight[i] = float(w[i - b] / sum);
        }
    });
    // Gather form, sources in ascending order (as gather_form).
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

namespace {
// The transposition below cuts the targets into at most kMaxRanges ranges
// of at least kMinTargetsPerRange (a target's place in its range is held in
// 16 bits: at most 65536 per range), and the blocks of sources into at most
// kMaxChunks chunks of consecutive blocks: its table of counts has at most
// kMaxRanges x kMaxChunks entries whatever the surfel count (per range and
// per block it grew as n^2: ~1.5 GB at 20M surfels).
constexpr size_t kMinTargetsPerRange = 4096, kMaxRanges = 1024, kMaxChunks = 256;

// The transposition into gather form, in parallel and the same, entry for
// entry, as one pass over the sources in ascending order (which leaves every
// target's list sorted by source): the targets are cut into ranges; each
// chunk of blocks of sources counts its entries per range; the entries are
// then moved into their range's stretch of the result, the chunks' parts in
// chunk order and within a chunk in block order (so by ascending source);
// and each range orders its stretch by target, a stable counting sort (the
// sources stay ascending).  Neither the ranges nor the chunks depend on the
// thread count.
SplatKernel gather_form(const std::vector<ScatterBlock>& blocks, size_t n) {
    SplatKernel k;
    k.offset.assign(n + 1, 0);
    if (n == 0) return k;
    const size_t nblocks = blocks.size();
    const size_t nranges = std::min((n + kMinTargetsPerRange - 1) / kMinTargetsPerRange, kMaxRanges);
    const size_t per_range = (n + nranges - 1) / nranges;
    if (per_range > 65536) throw Error("splat kernel: too many surfels for the transposition");
    const size_t nchunks = std::max<size_t>(std::min(nblocks, kMaxChunks), 1);
    const size_t per_chunk = (nblocks + nchunks - 1) / nchunks;
    // at[c * nranges + r]: chunk c's entries in range r, then where they go
    // (the offsets are 32-bit: so are these)
    std::vector<uint32_t> at(nchunks * nranges, 0);
    tbb::parallel_for(size_t(0), nchunks, [&](size_t c) {
        uint32_t* count = &at[c * nranges];
        for (size_t b = c * per_chunk; b < std::min(nblocks, (c + 1) * per_chunk); ++b)
            for (const auto& e : blocks[b].entries) ++count[e.first / per_range];
    });
    std::vector<size_t> range_at(nranges + 1, 0);
    for (size_t c = 0; c < nchunks; ++c)
        for (size_t r = 0; r < nranges; ++r) range_at[r + 1] += at[c * nranges + r];
    for (size_t r = 0; r < nranges; ++r) range_at[r + 1] += range_at[r];
    {
        std::vector<uint32_t> next(nranges);
        for (size_t r = 0; r < nranges; ++r) next[r] = uint32_t(range_at[r]);
        for (size_t c = 0; c < nchunks; ++c)
            for (size_t r = 0; r < nranges; ++r) next[r] += std::exchange(at[c * nranges + r], next[r]);
    }
    const size_t total = range_at[nranges];
    k.source.resize(total);
    k.weight.resize(total);
    std::vector<uint16_t> in_range(total);   // each moved entry's target, less its range's first
    tbb::parallel_for(size_t(0), nchunks, [&](size_t c) {
        uint32_t* next = &at[c * nranges];
        for (size_t b = c * per_chunk; b < std::min(nblocks, (c + 1) * per_chunk); ++b) {
            const ScatterBlock& B = blocks[b];
            for (size_t i = 0; i < B.end.size(); ++i) {
                const uint32_t s = uint32_t(b * kSourcesPerBlock + i);
                for (uint32_t e = i ? B.end[i - 1] : 0; e < B.end[i]; ++e) {
                    const auto& [j, w] = B.entries[e];
                    const size_t to = next[j / per_range]++;
                    k.source[to] = s;
                    k.weight[to] = w;
                    in_range[to] = uint16_t(j % per_range);
                }
            }
        }
    });
    tbb::parallel_for(size_t(0), nranges, [&](size_t r) {
        const size_t first = r * per_range, targets = first < n ? std::min(n - first, per_range) : 0;
        const size_t begin = range_at[r], end = range_at[r + 1];
        std::vector<uint32_t> fill(targets + 1, 0);
        for (size_t e = begin; e < end; ++e) ++fill[size_t(in_range[e]) + 1];
        for (size_t t = 0; t < targets; ++t) {
            fill[t + 1] += fill[t];
            k.offset[first + t + 1] = uint32_t(begin + fill[t + 1]);
        }
        const std::vector<uint32_t> source(k.source.begin() + std::ptrdiff_t(begin), k.source.begin() + std::ptrdiff_t(end));
        const std::vector<float> weight(k.weight.begin() + std::ptrdiff_t(begin), k.weight.begin() + std::ptrdiff_t(end));
        for (size_t e = begin; e < end; ++e) {
            const size_t to = begin + fill[in_range[e]]++;
            k.source[to] = source[e - begin];
            k.weight[to] = weight[e - begin];
        }
    });
    k.mean_neighbours = double(total) / double(n);
    return k;
}
}  // namespace

void reweight_splat_kernel(SplatKernel& k, const float* position, size_t n, float sigma) {
    if (k.offset.size() != n + 1) return;  // no kernel (spreading off): nothing to refresh
    const double inv2s2 = sigma > 0 ? 1.0 / (2.0 * double(sigma) * double(sigma)) : 0.0;
    std::vector<double> w(k.source.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
        for (size_t j = range.begin(); j < range.end(); ++j)
            for (uint32_t e = k.offset[j]; e < k.offset[j + 1]; ++e)
                w[e] = std::exp(-double(kernel_distance2(position, k.source[e], j)) * inv2s2);
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
