// The deposit path of tracing: rules that write to a surfel append (surfel,
// delta of the property columns) to their chunk's log while tracing; after
// tracing, the logs are applied to the rows.  Rows never change during a
// trace, and every surfel's sum is formed in chunk order, so the result is
// bit-identical for any thread count.  A pass's logs need not be held all at
// once: summed into D batch by batch (accumulate_chunk_logs, in chunk
// order), they give the same D, hence the same rows, as in one go.
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gamma/splat.h"
#include "gamma/stats.h"

namespace gammart {

// Per-chunk log of surface deltas (property columns only) and counters;
// buffers are reused between iterations (cleared, capacity kept).
struct ChunkLog {
    std::vector<uint32_t> surfel;
    std::vector<float> delta;  // P floats per record
    TraceStats st;

    void clear() {
        surfel.clear();
        delta.clear();
    }
    void record(uint32_t s, const float* d, int P) {
        surfel.push_back(s);
        delta.insert(delta.end(), d, d + P);
    }
};

// D[s] = the sum of the records of surfel s over logs [0, nchunks) in chunk
// order; then, with a splat kernel, D is spread over each surfel's
// neighbourhood (SPEC §13.2); rows[s][header + j] += the result (j < P;
// rows are n x (header + P)).  Parallel over surfel ranges; `scratch` (2*n*P
// floats) is reused between calls.
void apply_chunk_logs(const std::vector<ChunkLog>& logs, int64_t nchunks, size_t n, int header, int P, float* rows,
                      std::vector<float>& scratch, int threads, const SplatKernel* splat = nullptr);

// The two halves of apply_chunk_logs.  accumulate_chunk_logs: D[s] += the
// records of surfel s in logs [0, nchunks), in chunk order (D: n x P floats);
// returns whether there was any record.  add_chunk_sums: D spread by the
// splat kernel (if any; S is n x P floats of scratch) is added to the rows.
bool accumulate_chunk_logs(const std::vector<ChunkLog>& logs, int64_t nchunks, size_t n, int P, float* D,
                           int threads);
void add_chunk_sums(float* D, float* S, size_t n, int header, int P, float* rows, int threads,
                    const SplatKernel* splat);

}  // namespace gammart
