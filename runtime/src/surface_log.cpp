// Applying the chunk logs to the rows (see gamma/surface_log.h).
#include "gamma/surface_log.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include "gamma/threads.h"

namespace gammart {

// Each task scans the chunk logs in chunk order and adds only the records of
// its own surfels, so each surfel's sum has the same order for any partition.
bool accumulate_chunk_logs(const std::vector<ChunkLog>& logs, int64_t nchunks, size_t n, int P, float* D,
                           int threads) {
    bool any = false;
    for (int64_t ci = 0; ci < nchunks; ++ci) any = any || !logs[size_t(ci)].surfel.empty();
    if (!any || P <= 0) return any;
    const size_t nranges = size_t(resolve_threads(threads));
    const size_t per = (n + nranges - 1) / nranges;
    run_with_threads(threads, [&] {
        tbb::parallel_for(size_t(0), nranges, [&](size_t ri) {
            const uint32_t lo = uint32_t(std::min(n, ri * per)), hi = uint32_t(std::min(n, (ri + 1) * per));
            if (lo >= hi) return;
            for (int64_t ci = 0; ci < nchunks; ++ci) {
                const ChunkLog& log = logs[size_t(ci)];
                const uint32_t* sv = log.surfel.data();
                const size_t nrec = log.surfel.size();
                for (size_t k = 0; k < nrec; ++k) {
                    const uint32_t s = sv[k];
                    if (s < lo || s >= hi) continue;
                    const float* rec = log.delta.data() + k * size_t(P);
                    float* d = D + size_t(s) * P;
                    for (int j = 0; j < P; ++j) d[j] += rec[j];
                }
            }
        });
    });
    return true;
}

void add_chunk_sums(float* D, float* S, size_t n, int header, int P, float* rows, int threads,
                    const SplatKernel* splat) {
    if (P <= 0) return;
    const int W = header + P;
    const bool spread = splat && splat->offset.size() == n + 1;
    const float* add = spread ? S : D;
    run_with_threads(threads, [&] {
        if (spread) apply_splat(*splat, D, S, n, P);
        tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t s = r.begin(); s < r.end(); ++s)
                for (int j = 0; j < P; ++j) rows[s * W + header + j] += add[s * P + j];
        });
    });
}

void apply_chunk_logs(const std::vector<ChunkLog>& logs, int64_t nchunks, size_t n, int header, int P, float* rows,
                      std::vector<float>& scratch, int threads, const SplatKernel* splat) {
    bool any = false;
    for (int64_t ci = 0; ci < nchunks; ++ci) any = any || !logs[size_t(ci)].surfel.empty();
    if (!any || P <= 0) return;
    const bool spread = splat && splat->offset.size() == n + 1;
    scratch.assign((spread ? 2 : 1) * n * size_t(P), 0.0f);
    accumulate_chunk_logs(logs, nchunks, n, P, scratch.data(), threads);
    add_chunk_sums(scratch.data(), spread ? scratch.data() + n * size_t(P) : nullptr, n, header, P, rows, threads,
                   splat);
}

}  // namespace gammart
