// The deposit path on its own: chunk logs applied to rows in chunk order,
// bit-identical at any thread count.
#include <gtest/gtest.h>

#include <cstring>

#include "gamma/surface_log.h"

using namespace gammart;

TEST(SurfaceLog, RecordsAreSummedPerSurfelInChunkOrder) {
    const size_t n = 1000;
    const int header = 3, P = 2, W = header + P;
    std::vector<ChunkLog> logs(37);
    uint64_t x = 12345;
    auto next = [&] {
        x = x * 6364136223846793005ULL + 1442695040888963407ULL;
        return x >> 33;
    };
    for (ChunkLog& log : logs)
        for (int k = 0; k < 300; ++k) {
            const float d[2] = {float(next() % 1000) * 1e-3f, float(next() % 7) * 0.1f + 1e-7f};
            log.record(uint32_t(next() % n), d, P);
        }
    // Reference: sequential, chunk order.
    std::vector<float> ref(n * W, 1.0f), sums(n * P, 0.0f);
    for (const ChunkLog& log : logs)
        for (size_t k = 0; k < log.surfel.size(); ++k)
            for (int j = 0; j < P; ++j) sums[log.surfel[k] * P + j] += log.delta[k * P + j];
    for (size_t s = 0; s < n; ++s)
        for (int j = 0; j < P; ++j) ref[s * W + header + j] += sums[s * P + j];
    for (int threads : {1, 2, 3, 4}) {
        std::vector<float> rows(n * W, 1.0f), scratch;
        apply_chunk_logs(logs, int64_t(logs.size()), n, header, P, rows.data(), scratch, threads);
        EXPECT_EQ(0, std::memcmp(rows.data(), ref.data(), sizeof(float) * rows.size())) << threads << " threads";
    }
    // Only the first nchunks logs count.
    std::vector<float> rows(n * W, 1.0f), scratch;
    apply_chunk_logs(logs, 0, n, header, P, rows.data(), scratch, 2);
    for (float v : rows) EXPECT_EQ(v, 1.0f);
}
