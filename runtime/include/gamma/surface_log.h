// The deposit path of tracing: rules that write to a surfel append (surfel,
// delta of the property columns) to their chunk's log while tracing; after
// tracing, the logs are applied to the rows.  Rows never change during a
// trace, and every surfel's sum is formed in chunk order, so the result is
// bit-identical for any thread count.
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

}  // namespace gammart
