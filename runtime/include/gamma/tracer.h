// The tracer: one iteration of gamma-tons (SPEC §13.3-13.4).  Each gamma-ton
// is emitted by its source, interacts with the nearest surfel of the hit
// triangle's surface (hit kernel, then the chosen outcome's kernel), has its
// motion probabilities deteriorated by that surfel's row, and moves by the
// motion table (motion.h) until it settles, escapes or is capped.  Rules'
// writes go through the chunk logs (surface_log.h).  Also the raw-ray
// benchmarks (environment rays; the tracer's own recorded rays) and the parabola check against a plane.
#pragma once
#include <atomic>
#include <array>
#include <cstdint>
#include <vector>

#include "gamma/cancel.h"
#include "gamma/config.h"
#include "gamma/kernel_table.h"
#include "gamma/motion.h"
#include "gamma/scene_index.h"
#include "gamma/sources.h"
#include "gamma/stats.h"
#include "gamma/surface_log.h"
#include "gamma/surfel_state.h"

namespace gammart {

// Chunks traced before their logs are summed (Config::trace_batch_chunks, or
// by default max(64, 8 x threads)): bounds the logs held during a pass.
int64_t trace_batch_chunks(const Config& c);

class Tracer {
public:
    // Keeps references: c, kernels and sources must outlive the tracer.
    Tracer(const Config& c, const KernelTable& kernels, const std::vector<SourceRt>& sources);

    // Traces iteration `iteration` (1-based) and adds the rules' deltas to
    // state.rows.  Every surface that has triangles in `index` must have
    // surfels (checked by the caller).
    TraceStats trace(int iteration, const SceneIndex& index, const SceneFrame& frame, SurfelState& state,
                     const CancelToken& cancel = CancelToken::never());

    // The same work in pieces, for tracing on other processes or machines:
    // the iteration's gamma-tons fall in num_chunks() chunks of kChunkSize;
    // trace_chunks traces chunks [first, last) against state.rows (left
    // unchanged) and returns their logs; merge_chunks applies the logs of
    // all chunks, in chunk order, exactly as trace() does after tracing.  A
    // chunk's log depends only on (config, scene, rows, iteration, chunk), so
    // the pieces give trace()'s bytes wherever they are traced.  Both throw
    // gammart::Error on chunks or logs that do not fit.  one_at_a_time: the
    // plain tracer (each gamma-ton followed to its end before the next
    // starts) instead of the batched one; the same logs, for tests.
    int64_t num_chunks(int iteration, const SurfelState& state, const SceneFrame& frame) const;
    std::vector<ChunkLog> trace_chunks(int iteration, int64_t first, int64_t last, const SceneIndex& index,
                                       const SceneFrame& frame, const SurfelState& state,
                                       bool one_at_a_time = false) const;
    TraceStats merge_chunks(int iteration, const std::vector<ChunkLog>& logs, SurfelState& state,
                            const SceneFrame& frame);

    // merge_chunks in batches, so a driver need not hold a pass's logs at
    // once: merge_begin, then merge_add with the next chunks of the pass in
    // chunk order (any batch sizes), then merge_end, which adds the sums to
    // state.rows and returns the summed counters (log_records_peak: the
    // records of the largest batch; trace_seconds: the time spent in the
    // three calls).  Each surfel's sum is formed in chunk order as in trace()
    // and merge_chunks, so the batches never change the bytes.  The rows are
    // untouched until merge_end; a batch that does not fit throws
    // gammart::Error and abandons the merge (rows unchanged).
    void merge_begin(int iteration, const SurfelState& state, const SceneFrame& frame);
    void merge_add(const std::vector<ChunkLog>& logs, const SurfelState& state);
    TraceStats merge_end(SurfelState& state);

    // While on, trace() keeps every ray it casts (chunk by chunk, in an
    // order fixed by the config, the same at any thread count);
    // take_recorded_rays() hands them over.
    void set_record_rays(bool on) { record_rays_ = on; }
    // The scene's mesh (surface sources start on its triangles); it must outlive the tracer.
    void set_mesh(const Mesh* mesh) { mesh_ = mesh; }
    std::vector<RecordedRay> take_recorded_rays();

    // Per surface: whether it has surfels that all hold the same reflectance
    // columns (bit for bit), and those columns.  An interaction on such a
    // surface needs its surfel only for the rules that run there (the
    // tracer looks it up then, not at every hit).
    struct UniformReflectance {
        std::vector<uint8_t> uniform;
        std::vector<std::array<float, GAMMA_ROW_HEADER>> columns;
    };
    static UniformReflectance uniform_reflectance(const SceneIndex& index, const SurfelState& state);

private:
    // Traces chunks [first, last) into out[0 .. last - first); with
    // rays_out, also keeps each chunk's cast rays in rays_out[0 .. last - first).
    // The iteration's schedule and its surface sources' tables (surface_emitters):
    // both follow from the rows at the iteration's start.
    struct Emission {
        std::vector<SurfaceEmitters> tables;
        std::vector<uint8_t> silent;
        EmissionSchedule sched;
        int64_t silent_tons = 0;      // the gamma-tons silent surface sources would have emitted
    };
    Emission emission(int iteration, const SurfelState& state, const SceneFrame& frame) const;
    void run_chunks(int iteration, int64_t first, int64_t last, const SceneIndex& index, const SceneFrame& frame,
                    const SurfelState& state, const UniformReflectance& reflectance, ChunkLog* out,
                    std::vector<RecordedRay>* rays_out, const CancelToken& cancel, bool one_at_a_time) const;

    const Config& cfg_;
    const KernelTable& kernels_;
    const std::vector<SourceRt>& sources_;
    size_t max_carry_ = 1;
    std::vector<ChunkLog> logs_;
    std::vector<float> merge_scratch_;
    struct BatchedMerge {                  // a merge_begin .. merge_end in progress
        bool active = false;
        int iteration = 0;
        int64_t nchunks = 0, merged = 0;   // chunks of the pass; chunks added so far
        int64_t silent = 0;                // TraceStats::silent of the pass
        bool any_record = false;
        TraceStats st;
        double seconds = 0;
    };
    BatchedMerge batched_;
    const Mesh* mesh_ = nullptr;
    bool record_rays_ = false;
    std::vector<std::vector<RecordedRay>> ray_logs_;  // per chunk
};

// Throughput benchmark of the BVH alone: n_rays environment-sphere rays
// (Philox stream 0 of `seed`), counting hits.
RaycastStats raw_raycast(const SceneIndex& index, const SceneFrame& frame, int64_t n_rays, int threads,
                         uint64_t seed);

// The raw rate for the tracer's own rays: casts `rays` (generated before the
// clock starts) with rtcIntersect1 and nothing else, counting hits.
RaycastStats cast_recorded(const SceneIndex& index, const std::vector<RecordedRay>& rays, int threads);

// Landing of a parabolic flight (g = 1, launch speed sqrt(D) along unit d) on
// the plane dot(x, up) = floor_height, up = -normalize(down): `traced` as the
// tracer's piecewise-linear chords meet the plane, `analytic` the exact
// parabola.  Throws gammart::Error if the flight never reaches the plane.
void parabola_landing(std::array<float, 3> p0, std::array<float, 3> d, float D, std::array<float, 3> down,
                      float floor_height, std::array<float, 3>& traced, std::array<float, 3>& analytic);

}  // namespace gammart
