// The gamma-ton loop of one iteration (see gamma/tracer.h).
#include "gamma/tracer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "gamma/error.h"
#include "gamma/motion.h"
#include "gamma/philox.h"
#include "gamma/sampling.h"
#include "gamma/threads.h"

namespace gammart {

namespace {
// Gamma-tons emitted and cast ahead together (see run_chunks): enough casts
// to hide a miss each, few enough that their heads and rows stay in L1/L2.
constexpr int64_t kEmitGroup = 32;
// Casts between the fetch of a hit's lookup head and the fetch it enables.
constexpr size_t kRestLag = 4;
// Interactions of a group's paths stored before the rounds stop (a round
// may pass it by up to kEmitGroup - 1): the paths still alive then go on one
// interaction at a time in the kernel pass, so a thread holds ~3.4 MB of
// steps at most, however long the lives (--max-interactions up to 1e6).
constexpr int64_t kStepBudget = 65536;
}  // namespace

int64_t trace_batch_chunks(const Config& c) {
    if (c.trace_batch_chunks > 0) return c.trace_batch_chunks;
    return std::max<int64_t>(64, 8 * int64_t(resolve_threads(c.threads)));
}

Tracer::Tracer(const Config& c, const KernelTable& kernels, const std::vector<SourceRt>& sources)
    : cfg_(c), kernels_(kernels), sources_(sources), max_carry_(max_carry(c)) {}

Tracer::Emission Tracer::emission(int iteration, const SurfelState& state, const SceneFrame& frame) const {
    Emission e;
    bool any_surface = false;
    for (const SourceRt& s : sources_) any_surface = any_surface || s.kind == SourceKind::Surface;
    if (any_surface) {
        e.tables = surface_emitters(sources_, state, frame, iteration, cfg_.seed, cfg_.threads);
        e.silent = silent_sources(e.tables);
        const EmissionSchedule all = schedule(cfg_.sources, iteration);
        for (size_t k = 0; k < all.active.size(); ++k)
            if (e.silent[all.active[k]]) e.silent_tons += all.start[k + 1] - all.start[k];
    }
    e.sched = schedule(cfg_.sources, iteration, e.silent);
    return e;
}

int64_t Tracer::num_chunks(int iteration, const SurfelState& state, const SceneFrame& frame) const {
    return (emission(iteration, state, frame).sched.total() + kChunkSize - 1) / kChunkSize;
}

TraceStats Tracer::trace(int iteration, const SceneIndex& index, const SceneFrame& frame, SurfelState& state,
                         const CancelToken& cancel) {
    cancel.check("the trace");   // (also when the pass has no chunk to check it in)
    const auto t0 = std::chrono::steady_clock::now();
    const Emission plan = emission(iteration, state, frame);
    const int64_t nchunks = (plan.sched.total() + kChunkSize - 1) / kChunkSize;
    const int P = state.width - GAMMA_ROW_HEADER;
    // Chunks are traced in batches and each batch's logs summed before the
    // next: the logs held at once are those of one batch, whatever the pass's
    // size (--tons 1e9 would otherwise hold a record per write of every
    // gamma-ton).  The sums are formed in chunk order either way, so the
    // batch size never changes the result.  A cancelled pass throws from
    // run_chunks before its sums reach the rows.
    const int64_t batch = trace_batch_chunks(cfg_);
    const UniformReflectance reflectance = uniform_reflectance(index, state);
    if (logs_.size() < size_t(std::min(batch, nchunks))) logs_.resize(size_t(std::min(batch, nchunks)));
    ray_logs_.assign(record_rays_ ? size_t(nchunks) : 0, {});
    TraceStats total_st;
    total_st.mass.assign(cfg_.mass_properties.size(), MassBooks{});
    const size_t n = state.size();
    bool any_record = false;
    // The batches, their sums and the splat run in one arena: each of these
    // steps would otherwise make its own (run_with_threads) and wait for the
    // workers to join it, ~2 per batch.
    run_with_threads(cfg_.threads, [&] {
        for (int64_t first = 0; first < nchunks; first += batch) {
            const int64_t last = std::min(nchunks, first + batch);
            run_chunks(iteration, first, last, index, frame, state, reflectance, logs_.data(),
                       record_rays_ ? ray_logs_.data() + first : nullptr, cancel, /*one_at_a_time=*/false);
            int64_t held = 0;
            for (int64_t k = 0; k < last - first; ++k) {
                total_st.add(logs_[size_t(k)].st);
                held += int64_t(logs_[size_t(k)].surfel.size());
            }
            total_st.log_records_peak = std::max(total_st.log_records_peak, held);
            if (held == 0 || P <= 0) continue;
            if (!any_record)   // D, then (with a splat kernel) its spread
                merge_scratch_.assign((state.splat.offset.size() == n + 1 ? 2 : 1) * n * size_t(P), 0.0f);
            any_record = true;
            accumulate_chunk_logs(logs_, last - first, n, P, merge_scratch_.data(), cfg_.threads);
        }
        if (any_record) {
            float* spread = merge_scratch_.size() > n * size_t(P) ? merge_scratch_.data() + n * size_t(P) : nullptr;
            add_chunk_sums(merge_scratch_.data(), spread, n, GAMMA_ROW_HEADER, P, state.rows.data(), cfg_.threads,
                           &state.splat);
        }
    });
    total_st.silent = plan.silent_tons;
    total_st.trace_seconds = seconds_since(t0);
    return total_st;
}

std::vector<ChunkLog> Tracer::trace_chunks(int iteration, int64_t first, int64_t last, const SceneIndex& index,
                                           const SceneFrame& frame, const SurfelState& state,
                                           bool one_at_a_time) const {
    const int64_t nchunks = num_chunks(iteration, state, frame);
    if (first < 0 || last > nchunks || first > last)
        throw Error("trace_chunks: chunks [" + std::to_string(first) + ", " + std::to_string(last) +
                    ") are not within the " + std::to_string(nchunks) + " chunks of iteration " +
                    std::to_string(iteration));
    std::vector<ChunkLog> logs(size_t(last - first));
    run_chunks(iteration, first, last, index, frame, state, uniform_reflectance(index, state), logs.data(), nullptr,
               CancelToken::never(), one_at_a_time);
    return logs;
}

TraceStats Tracer::merge_chunks(int iteration, const std::vector<ChunkLog>& logs, SurfelState& state,
                                 const SceneFrame& frame) {
    const int64_t nchunks = num_chunks(iteration, state, frame);
    if (int64_t(logs.size()) != nchunks)
        throw Error("merge_chunks: iteration " + std::to_string(iteration) + " has " + std::to_string(nchunks) +
                    " chunks, not " + std::to_string(logs.size()));
    merge_begin(iteration, state, frame);
    merge_add(logs, state);
    return merge_end(state);
}

void Tracer::merge_begin(int iteration, const SurfelState& state, const SceneFrame& frame) {
    const auto t0 = std::chrono::steady_clock::now();
    batched_ = BatchedMerge{};
    batched_.iteration = iteration;
    const Emission plan = emission(iteration, state, frame);
    batched_.nchunks = (plan.sched.total() + kChunkSize - 1) / kChunkSize;
    batched_.silent = plan.silent_tons;
    batched_.st.mass.assign(cfg_.mass_properties.size(), MassBooks{});
    batched_.active = true;
    batched_.seconds = seconds_since(t0);
}

void Tracer::merge_add(const std::vector<ChunkLog>& logs, const SurfelState& state) {
    const auto t0 = std::chrono::steady_clock::now();
    BatchedMerge& m = batched_;
    if (!m.active) throw Error("merge_chunks: no merge begun (merge_begin), or it was abandoned");
    m.active = false;  // until this batch is known to fit
    const int P = state.width - GAMMA_ROW_HEADER;
    if (m.merged + int64_t(logs.size()) > m.nchunks)
        throw Error("merge_chunks: iteration " + std::to_string(m.iteration) + " has " + std::to_string(m.nchunks) +
                    " chunks, not " + std::to_string(m.merged + int64_t(logs.size())) + " or more");
    int64_t held = 0;
    for (const ChunkLog& log : logs) {
        if (log.delta.size() != log.surfel.size() * size_t(std::max(P, 0)))
            throw Error("merge_chunks: a chunk's deltas do not match its surfels");
        if (log.st.mass.size() != cfg_.mass_properties.size())
            throw Error("merge_chunks: a chunk has mass books for " + std::to_string(log.st.mass.size()) +
                        " properties, not " + std::to_string(cfg_.mass_properties.size()));
        for (uint32_t s : log.surfel)
            if (s >= state.size()) throw Error("merge_chunks: surfel " + std::to_string(s) + " out of range");
        held += int64_t(log.surfel.size());
    }
    for (const ChunkLog& log : logs) m.st.add(log.st);
    m.st.log_records_peak = std::max(m.st.log_records_peak, held);
    const size_t n = state.size();
    if (held > 0 && P > 0) {
        // D, then (with a splat kernel) its spread: as trace() sizes it
        if (!m.any_record) merge_scratch_.assign((state.splat.offset.size() == n + 1 ? 2 : 1) * n * size_t(P), 0.0f);
        m.any_record = true;
        accumulate_chunk_logs(logs, int64_t(logs.size()), n, P, merge_scratch_.data(), cfg_.threads);
    }
    m.merged += int64_t(logs.size());
    m.active = true;
    m.seconds += seconds_since(t0);
}

TraceStats Tracer::merge_end(SurfelState& state) {
    const auto t0 = std::chrono::steady_clock::now();
    BatchedMerge& m = batched_;
    if (!m.active) throw Error("merge_chunks: no merge begun (merge_begin), or it was abandoned");
    m.active = false;
    if (m.merged != m.nchunks)
        throw Error("merge_chunks: iteration " + std::to_string(m.iteration) + " has " + std::to_string(m.nchunks) +
                    " chunks, not " + std::to_string(m.merged));
    const int P = state.width - GAMMA_ROW_HEADER;
    const size_t n = state.size();
    // The splat spreads each deposit exactly as trace() does (state.splat is
    // the driver's own; workers only trace).
    if (m.any_record) {
        float* spread = merge_scratch_.size() > n * size_t(P) ? merge_scratch_.data() + n * size_t(P) : nullptr;
        add_chunk_sums(merge_scratch_.data(), spread, n, GAMMA_ROW_HEADER, P, state.rows.data(), cfg_.threads,
                       &state.splat);
    }
    TraceStats st = std::move(m.st);
    st.silent = m.silent;
    st.trace_seconds = m.seconds + seconds_since(t0);
    return st;
}

Tracer::UniformReflectance Tracer::uniform_reflectance(const SceneIndex& index, const SurfelState& state) {
    const size_t n_surfaces = size_t(std::max(index.n_surfaces(), 0));
    UniformReflectance r;
    r.uniform.assign(n_surfaces, 0);
    r.columns.assign(n_surfaces, {});
    std::vector<uint8_t> seen(n_surfaces, 0);
    const size_t W = size_t(state.width);
    for (size_t s = 0; s < state.size(); ++s) {
        const int32_t surface = state.surface[s];
        if (surface < 0 || size_t(surface) >= n_surfaces) continue;
        const float* row = state.rows.data() + s * W;
        auto& columns = r.columns[size_t(surface)];
        if (!seen[size_t(surface)]) {
            seen[size_t(surface)] = 1;
            r.uniform[size_t(surface)] = 1;
            std::memcpy(columns.data(), row, sizeof(columns));
        } else if (r.uniform[size_t(surface)] && std::memcmp(columns.data(), row, sizeof(columns)) != 0) {
            r.uniform[size_t(surface)] = 0;
        }
    }
    // the lookup finds a surfel of the triangle's own surface only where
    // that surface has surfels in the index too
    for (size_t f = 0; f < n_surfaces; ++f)
        if (!index.has_surfels(int(f))) r.uniform[f] = 0;
    return r;
}

namespace {

// What every chunk of one pass reads.
struct PassInputs {
    const Config& c;
    const KernelTable& K;
    const SceneIndex& index;
    const SceneFrame& frame;
    const SurfelState& state;
    const Tracer::UniformReflectance& reflectance;
    const EmissionSchedule& sched;
    std::vector<SourceRt> sources;   // surface sources bound to this iteration's tables
    std::vector<float> weight;       // of each active source's gamma-tons
    size_t max_carry;
    int iteration;
};

// Half the mean surfel spacing, sqrt(A / n): how far from its surfel a
// surface source's gamma-ton starts.
float surface_source_spread(const Mesh& mesh, size_t surfels) {
    double area = 0.0;
    const std::vector<float>& v = mesh.vertices;
    const std::vector<int32_t>& t = mesh.triangles;
    for (size_t k = 0; k + 2 < t.size(); k += 3) {
        const V3 a{v[3 * size_t(t[k])], v[3 * size_t(t[k]) + 1], v[3 * size_t(t[k]) + 2]};
        const V3 b{v[3 * size_t(t[k + 1])], v[3 * size_t(t[k + 1]) + 1], v[3 * size_t(t[k + 1]) + 2]};
        const V3 c{v[3 * size_t(t[k + 2])], v[3 * size_t(t[k + 2]) + 1], v[3 * size_t(t[k + 2]) + 2]};
        area += 0.5 * double(length(cross(b - a, c - a)));
    }
    return float(0.5 * std::sqrt(area / double(surfels)));
}

// The pass's sources: surface sources emit from this iteration's table of
// their surfels.
std::vector<SourceRt> sources_of_pass(const std::vector<SourceRt>& sources, const std::vector<SurfaceEmitters>& tables,
                                      const SurfelState& state, const Mesh* mesh) {
    std::vector<SourceRt> out = sources;
    const float spread = mesh != nullptr && state.size() > 0 ? surface_source_spread(*mesh, state.size()) : 0.0f;
    for (size_t i = 0; i < out.size(); ++i)
        if (out[i].kind == SourceKind::Surface) {
            if (mesh == nullptr) throw Error("a surface source needs the scene's mesh (Tracer::set_mesh)");
            out[i].table = &tables[i];
            out[i].positions = state.surf.position.data();
            out[i].normals = state.surf.normal.data();
            out[i].surfel_triangle = state.surf.triangle.data();
            out[i].mesh_vertices = mesh->vertices.data();
            out[i].mesh_triangles = mesh->triangles.data();
            out[i].spread = spread;
        }
    return out;
}

// Weight of each active source's gamma-tons (SPEC §13.2): strength * n / N.
std::vector<float> source_weights(const Config& c, const EmissionSchedule& sched, size_t surfels) {
    std::vector<float> weight;
    for (size_t k = 0; k < sched.active.size(); ++k) {
        const Source& so = c.sources[sched.active[k]];
        weight.push_back(so.strength > 0 && so.count > 0
                             ? float(double(so.strength) * double(surfels) / double(so.count))
                             : 1.0f);
    }
    return weight;
}

// One chunk's gamma-tons.  trace_batched takes them in groups of kEmitGroup,
// phase by phase: emit every gamma-ton of the group, cast every emission ray
// (starting the fetch of each hit triangle's lookup head), find each hit's
// surfel (starting the fetch of its row), advance the group's paths
// together one interaction per round, then replay the rules of each
// gamma-ton's interactions in gamma-ton order.  The dependent cache misses of
// an interaction (head, then row) overlap with the other gamma-tons' work
// instead of following one another.  Emission, casts and paths depend only
// on the gamma-ton's own stream, the scene and the rows, and the rules run in
// the order the lives run one by one: the same draws, rays, records and
// sums, the same bytes as trace_one_at_a_time, the plain form (each
// gamma-ton followed to its end, its rules run at each interaction, before
// the next starts) that tests compare the batched one against.
class ChunkTracer {
public:
    ChunkTracer(const PassInputs& in, ChunkLog& log, std::vector<RecordedRay>* rays);
    void trace_batched(int64_t begin, int64_t end);
    void trace_one_at_a_time(int64_t begin, int64_t end);
    const TraceStats& stats() const { return st_; }

private:
    enum class LifeEnd : uint8_t { Missed, Escaped, Settled, Capped, Alive };
    static constexpr uint32_t kNoStep = UINT32_MAX;
    static constexpr uint32_t kNoSurfel = UINT32_MAX;
    // A gamma-ton as emitted and cast.
    struct Emitted {
        PhiloxStream rng;
        V3 org, d0, p, n;
        uint32_t prim, s;
        size_t a;    // active source
        int event;   // of the first interaction (plan)
        bool hit, need_surfel;
    };
    // A gamma-ton's path while the group's paths advance.
    struct Path {
        float ks, kp, kf;
        int inter;
        V3 p, n, dir;
        uint32_t prim, s;  // s: kNoSurfel where the interaction needs none (plan)
        uint32_t first_step, last_step;
        int event;         // of the interaction at p (plan)
        bool need_surfel;
        LifeEnd end;
    };
    // One interaction of a path (the steps of one gamma-ton linked in order).
    struct Step {
        V3 p, n, dir;
        uint32_t s;
        int inter, event;
        uint32_t next;
    };

    // the phases of a group [g0, g0 + n)
    void emit(int64_t g0, int64_t g1);
    void cast(size_t n);
    void find_first_surfels(size_t n);
    void start_paths(size_t n);
    void advance_paths();
    void replay_rules(int64_t g0, size_t n);
    // their parts
    bool plan(PhiloxStream& rng, float ks, float kp, float kf, int type, uint32_t prim, int& event) const;
    void find_surfel(Path& path) const;
    bool advance(uint32_t k, Step& step);
    void run_rules(const Step& step, int type, int64_t g);
    void call(const TransportSlot& sl, uint32_t s, GammaContext& ctx, uint64_t interaction_key);
    void end_life(int type, bool settled);
    void missed(int type);
    int ton_type_of(const Emitted& e) const { return c_.sources[sched_.active[e.a]].ton_type; }
    double carried(size_t j, int type) const {
        const int ci = MP_[j].carry[size_t(type)];
        return ci >= 0 ? double(carry_[size_t(ci)]) : 0.0;
    }

    const PassInputs& in_;
    const Config& c_;
    const KernelTable& K_;
    const SceneIndex& index_;
    const EmissionSchedule& sched_;
    const std::vector<MassProperty>& MP_;
    const std::vector<int32_t>& tri_surface_;
    const SurfelMeasures& measures_;
    const float* rows_;
    const int32_t* surf_of_;
    const int W_, P_;
    const size_t M_;
    const bool need_normal_, need_uv_;
    ChunkLog& log_;
    TraceStats st_;
    Walker w_;
    std::vector<float> carry_, delta_, scratch_, carried_before_;
    float ton_weight_ = 1.0f;
    size_t a_ = 0;   // the active source of the next gamma-ton to emit
    std::array<Emitted, kEmitGroup> group_;
    std::array<Path, kEmitGroup> paths_;
    std::vector<Step> steps_;
    std::vector<uint32_t> alive_;
    std::array<PhiloxStream, kEmitGroup> run_rng_;
    std::array<V3, kEmitGroup> run_org_, run_dir_;
};

ChunkTracer::ChunkTracer(const PassInputs& in, ChunkLog& log, std::vector<RecordedRay>* rays)
    : in_(in), c_(in.c), K_(in.K), index_(in.index), sched_(in.sched), MP_(in.c.mass_properties),
      tri_surface_(in.index.tri_surface()), measures_(in.state.measures), rows_(in.state.rows.data()),
      surf_of_(in.state.surface.data()), W_(in.state.width), P_(in.state.width - GAMMA_ROW_HEADER),
      M_(in.c.mass_properties.size()),
      need_normal_(!in.state.measures.accessibility.empty() || !in.state.measures.curvature.empty()),
      need_uv_(!in.state.measures.uv.empty()), log_(log), w_(in.index, in.frame, st_),
      carry_(in.max_carry, 0.0f), delta_(size_t(in.state.width), 0.0f), scratch_(size_t(in.state.width), 0.0f),
      carried_before_(in.c.mass_properties.size(), 0.0f) {
    // Mass books (only when properties are accounted): per rule call, the
    // change of the surface column and of the carried attribute.
    st_.mass.assign(M_, MassBooks{});
    w_.record = rays;
    alive_.reserve(kEmitGroup);
}

void ChunkTracer::trace_batched(int64_t begin, int64_t end) {
    a_ = size_t(std::upper_bound(sched_.start.begin(), sched_.start.end(), begin) - sched_.start.begin()) - 1;
    const size_t step_budget = size_t(c_.trace_step_budget > 0 ? c_.trace_step_budget : kStepBudget);
    for (int64_t g0 = begin; g0 < end; g0 += kEmitGroup) {
        const int64_t g1 = std::min(end, g0 + kEmitGroup);
        const size_t n = size_t(g1 - g0);
        emit(g0, g1);
        cast(n);
        find_first_surfels(n);
        start_paths(n);
        while (!alive_.empty() && steps_.size() < step_budget) advance_paths();
        replay_rules(g0, n);
    }
}

void ChunkTracer::trace_one_at_a_time(int64_t begin, int64_t end) {
    a_ = size_t(std::upper_bound(sched_.start.begin(), sched_.start.end(), begin) - sched_.start.begin()) - 1;
    for (int64_t g = begin; g < end; ++g) {
        emit(g, g + 1);
        cast(1);
        find_first_surfels(1);
        start_paths(1);
        replay_rules(g, 1);   // (no round ran: the life is followed and its rules run step by step)
    }
}

// Every emission of the group first, then every cast: independent emissions
// overlap in the core (no opaque call between them), and the casts run back
// to back with Embree's working set warm.
void ChunkTracer::emit(int64_t g0, int64_t g1) {
    const std::vector<int64_t>& start = sched_.start;
    for (int64_t g = g0; g < g1;) {  // runs of one source each
        while (g >= start[a_ + 1]) ++a_;
        const int64_t run_end = std::min(g1, start[a_ + 1]);
        const size_t n_run = size_t(run_end - g);
        emit_run(in_.sources[sched_.active[a_]], c_.seed, uint32_t(in_.iteration), g, n_run, run_rng_.data(),
                 run_org_.data(), run_dir_.data());
        for (size_t i = 0; i < n_run; ++i) {
            Emitted& e = group_[size_t(g - g0) + i];
            e.rng = run_rng_[i];
            e.org = run_org_[i];
            e.d0 = run_dir_[i];
            e.a = a_;
        }
        g = run_end;
    }
}

// The emission rays, counted and recorded as Walker::straight does; where a
// hit needs its surfel, the fetch of its triangle's lookup head starts, and
// a hit's candidates past its head are fetched kRestLag casts later, when
// the head has arrived to say where they are.
void ChunkTracer::cast(size_t n) {
    for (size_t k = 0; k < n; ++k) {
        Emitted& e = group_[k];
        if (w_.record)
            w_.record->push_back(RecordedRay{{e.org.x, e.org.y, e.org.z}, {e.d0.x, e.d0.y, e.d0.z}, 0.0f,
                                             std::numeric_limits<float>::infinity()});
        ++st_.rays;
        index_.cast(w_.rh, e.org, e.d0, 0.0f);
        e.hit = land(w_.rh, e.org, e.d0, e.p, e.n, e.prim);
        e.need_surfel = false;
        if (e.hit) {
            const int type = ton_type_of(e);
            const TonType& tt = c_.ton_types[size_t(type)];
            e.need_surfel = plan(e.rng, tt.ks, tt.kp, tt.kf, type, e.prim, e.event);
            if (e.need_surfel) index_.prefetch_lookup(e.prim);
        }
        if (k >= kRestLag && group_[k - kRestLag].need_surfel) index_.prefetch_lookup_rest(group_[k - kRestLag].prim);
    }
    for (size_t k = n > kRestLag ? n - kRestLag : 0; k < n; ++k)
        if (group_[k].need_surfel) index_.prefetch_lookup_rest(group_[k].prim);
}

// The surfel of each first hit that needs one, its row fetched ahead.
void ChunkTracer::find_first_surfels(size_t n) {
    for (size_t k = 0; k < n; ++k) {
        Emitted& e = group_[k];
        e.s = kNoSurfel;
        if (!e.need_surfel) continue;
        const float pa[3] = {e.p.x, e.p.y, e.p.z};
        e.s = index_.nearest_on_triangle(e.prim, pa);
        const float* row = rows_ + size_t(e.s) * W_;
        __builtin_prefetch(row);
        __builtin_prefetch(row + (W_ - 1));
        __builtin_prefetch(surf_of_ + e.s);
        if (need_uv_) __builtin_prefetch(measures_.uv.data() + 2 * size_t(e.s));
        if (need_normal_) __builtin_prefetch(in_.state.surf.normal.data() + 3 * size_t(e.s));
    }
}

void ChunkTracer::start_paths(size_t n) {
    steps_.clear();
    alive_.clear();
    for (size_t k = 0; k < n; ++k) {
        const Emitted& e = group_[k];
        Path& path = paths_[k];
        const TonType& tt = c_.ton_types[size_t(ton_type_of(e))];
        path.ks = tt.ks;
        path.kp = tt.kp;
        path.kf = tt.kf;
        path.inter = 0;
        path.first_step = path.last_step = kNoStep;
        path.end = e.hit ? LifeEnd::Alive : LifeEnd::Missed;
        if (!e.hit) continue;
        path.p = e.p;
        path.n = e.n;
        path.dir = e.d0;
        path.prim = e.prim;
        path.s = e.s;  // found by find_first_surfels, if needed
        path.event = e.event;
        path.need_surfel = e.need_surfel;
        alive_.push_back(uint32_t(k));
    }
}

// One round: every live path of the group takes one interaction.  A path
// depends only on the gamma-ton's own stream, the scene and the rows (never
// on what the rules do), so the paths advance together: a gamma-ton's next
// lookup and row are fetched while the others move.
void ChunkTracer::advance_paths() {
    for (uint32_t k : alive_)
        if (paths_[k].inter > 0 && paths_[k].need_surfel) find_surfel(paths_[k]);
    size_t still = 0;
    for (uint32_t k : alive_) {
        Path& path = paths_[k];
        Step step;
        const bool goes_on = advance(k, step);
        const uint32_t at = uint32_t(steps_.size());
        steps_.push_back(step);
        if (path.last_step == kNoStep) path.first_step = at;
        else steps_[path.last_step].next = at;
        path.last_step = at;
        if (!goes_on) continue;
        if (path.need_surfel) index_.prefetch_lookup(path.prim);
        alive_[still++] = k;
    }
    alive_.resize(still);
}

// The rules, in gamma-ton order and each gamma-ton's interactions in order,
// as the lives run one by one: the same calls, records and sums.
void ChunkTracer::replay_rules(int64_t g0, size_t n) {
    for (size_t k = 0; k < n; ++k) {
        const Emitted& e = group_[k];
        Path& path = paths_[k];
        const int64_t g = g0 + int64_t(k);
        const int type = ton_type_of(e);
        const TonType& tt = c_.ton_types[size_t(type)];
        ton_weight_ = in_.weight[e.a];
        ++st_.emitted;
        if (path.end == LifeEnd::Missed) {
            missed(type);
            continue;
        }
        std::copy(tt.initial_carry.begin(), tt.initial_carry.end(), carry_.begin());
        for (size_t j = 0; j < M_; ++j) st_.mass[j].emitted += carried(j, type) * ton_weight_;
        for (uint32_t at = path.first_step; at != kNoStep; at = steps_[at].next) run_rules(steps_[at], type, g);
        // A path the rounds left alive (they stopped at the step budget, or
        // none ran) goes on here one interaction at a time, each run at once:
        // its path and draws are those the rounds would have made, its rules
        // run in the same order.
        while (path.end == LifeEnd::Alive) {
            if (path.inter > 0 && path.need_surfel) find_surfel(path);
            Step step;
            advance(uint32_t(k), step);
            run_rules(step, type, g);
        }
        switch (path.end) {
            case LifeEnd::Settled: ++st_.settled; end_life(type, true); break;
            case LifeEnd::Capped: ++st_.capped; end_life(type, false); break;
            default: ++st_.escaped; end_life(type, false); break;
        }
        st_.interactions += path.inter;
    }
}

// Nothing runs on a miss (three gamma-tons in four of an environment source):
// what it carries is emitted and escapes at once, read from its initial
// carry without copying it into carry_ (a mass property's carry index lies
// within its ton type's initial carry: config.cpp).
void ChunkTracer::missed(int type) {
    const TonType& tt = c_.ton_types[size_t(type)];
    ++st_.escaped;
    ++st_.missed;
    for (size_t j = 0; j < M_; ++j) {
        const int ci = MP_[j].carry[size_t(type)];
        const double v = ci >= 0 ? double(tt.initial_carry[size_t(ci)]) : 0.0;
        st_.mass[j].emitted += v * ton_weight_;
        st_.mass[j].escaped += v * ton_weight_;
    }
}

// The event of the interaction where a path has just landed, drawn there: it
// is the gamma-ton's next draw whenever it is drawn (the motion's draws came
// before it, nothing else draws from the stream in between), so drawing it
// at the landing changes no draw.  Returns whether the interaction needs its
// surfel: for the rules of its event or of every hit, or for its
// reflectances where its surface's surfels differ in them.  Otherwise the
// surfel is never looked up (most reflections of most effects).
bool ChunkTracer::plan(PhiloxStream& rng, float ks, float kp, float kf, int type, uint32_t prim, int& event) const {
    const float xi = rng.next();
    const float c1 = std::min(ks, 1.0f);
    const float c2 = std::min(c1 + kp, 1.0f);
    const float c3 = std::min(c2 + kf, 1.0f);
    event = xi < c1 ? GAMMA_EVENT_REFLECT
          : xi < c2 ? GAMMA_EVENT_BOUNCE
          : xi < c3 ? GAMMA_EVENT_FLOW
                    : GAMMA_EVENT_SETTLE;
    if (prim >= tri_surface_.size()) return true;
    const int surface = tri_surface_[prim];
    const Tracer::UniformReflectance& r = in_.reflectance;
    if (surface < 0 || size_t(surface) >= r.uniform.size() || !r.uniform[size_t(surface)]) return true;
    return K_.slot(GAMMA_EVENT_HIT, type, surface).fn != nullptr || K_.slot(event, type, surface).fn != nullptr;
}

// The surfel of a path's hit (after its first), its row fetched ahead.
void ChunkTracer::find_surfel(Path& path) const {
    const float pa[3] = {path.p.x, path.p.y, path.p.z};
    path.s = index_.nearest_on_triangle(path.prim, pa);
    __builtin_prefetch(rows_ + size_t(path.s) * W_);
    __builtin_prefetch(rows_ + size_t(path.s) * W_ + (W_ - 1));
    __builtin_prefetch(surf_of_ + path.s);
}

// One interaction of gamma-ton k's path at its surfel: the event, put in
// `step`, then (unless the life ends there) the motion to the next hit.
// Returns whether the path goes on.
bool ChunkTracer::advance(uint32_t k, Step& step) {
    Path& path = paths_[k];
    const int type = ton_type_of(group_[k]);
    const TonType& tt = c_.ton_types[size_t(type)];
    PhiloxStream& rng = group_[k].rng;
    const int inter = ++path.inter;
    const int event = path.event;
    step = Step{path.p, path.n, path.dir, path.s, inter, event, kNoStep};
    if (event == GAMMA_EVENT_SETTLE) { path.end = LifeEnd::Settled; return false; }
    if (inter >= c_.max_interactions) { path.end = LifeEnd::Capped; return false; }
    // without its surfel, the surface's columns (the same in every surfel of it)
    const float* row = path.s != kNoSurfel ? rows_ + size_t(path.s) * W_
                                           : in_.reflectance.columns[size_t(tri_surface_[path.prim])].data();
    const float ds = row[GAMMA_ROW_REFLECTANCE_STRAIGHT], dp = row[GAMMA_ROW_REFLECTANCE_PARABOLIC],
                df = row[GAMMA_ROW_REFLECTANCE_FLOW];
    const float kp_left = std::max(path.kp - dp, 0.0f);
    path.ks = std::max(path.ks - ds, 0.0f);
    path.kf = std::max(path.kf + kp_left - df, 0.0f);
    path.kp = kp_left;
    w_.p = path.p;
    w_.n = path.n;
    w_.dir = path.dir;
    w_.prim = path.prim;
    const FlightEnd fe = kMotionTable.step[event](w_, rng, tt);
    if (fe == FlightEnd::Escaped) { path.end = LifeEnd::Escaped; return false; }
    if (fe == FlightEnd::Capped) { path.end = LifeEnd::Capped; return false; }
    path.p = w_.p;
    path.n = w_.n;
    path.dir = w_.dir;
    path.prim = w_.prim;
    path.s = kNoSurfel;  // until find_surfel, if the next interaction needs it
    path.need_surfel = plan(rng, path.ks, path.kp, path.kf, type, path.prim, path.event);
    return true;
}

// The rules of one interaction of gamma-ton g (of ton type `type`).
void ChunkTracer::run_rules(const Step& step, int type, int64_t g) {
    if (step.s == kNoSurfel) return;  // no rule runs there (plan)
    const uint32_t s = step.s;
    const int surface = surf_of_[s];
    const TransportSlot& hit = K_.slot(GAMMA_EVENT_HIT, type, surface);
    const TransportSlot& ev = K_.slot(step.event, type, surface);
    // An interaction no rule handles (most reflections) needs no context:
    // none is built, no measure is read.
    if (!hit.fn && !ev.fn) return;
    const V3 p = step.p, n = step.n, dir = step.dir, up = in_.frame.up;
    GammaContext ctx;
    ctx.position[0] = p.x; ctx.position[1] = p.y; ctx.position[2] = p.z;
    ctx.normal[0] = n.x; ctx.normal[1] = n.y; ctx.normal[2] = n.z;
    ctx.direction[0] = dir.x; ctx.direction[1] = dir.y; ctx.direction[2] = dir.z;
    ctx.height = dot(p, up) - in_.frame.min_up;
    ctx.iteration = in_.iteration;
    ctx.interactions = step.inter;
    // the measures of the surfel the rules run on (SPEC §12)
    ctx.uv[0] = need_uv_ ? measures_.uv[2 * size_t(s)] : 0.0f;
    ctx.uv[1] = need_uv_ ? measures_.uv[2 * size_t(s) + 1] : 0.0f;
    ctx.up[0] = up.x; ctx.up[1] = up.y; ctx.up[2] = up.z;
    // on the side the gamma-ton came from (n is turned toward it); the
    // surfel's normal (a cache miss) only when a measure needs it
    ctx.accessibility = 0.0f;
    ctx.curvature = 0.0f;
    if (need_normal_) {
        const float* sn = in_.state.surf.normal.data() + 3 * size_t(s);
        const bool back = n.x * sn[0] + n.y * sn[1] + n.z * sn[2] < 0.0f;
        if (!measures_.accessibility.empty())
            ctx.accessibility = back ? measures_.accessibility_back[s] : measures_.accessibility[s];
        if (!measures_.curvature.empty()) ctx.curvature = back ? -measures_.curvature[s] : measures_.curvature[s];
    }
    // interaction key: mixed from (seed, iteration, gamma-ton, interaction);
    // each event's rule gets its own random() key from it
    const uint64_t key =
        mix64(mix64(mix64(c_.seed ^ uint64_t(uint32_t(in_.iteration))) ^ uint64_t(g)) ^ uint64_t(step.inter));
    if (hit.fn) call(hit, s, ctx, key);
    if (ev.fn) call(ev, s, ctx, key);
}

void ChunkTracer::call(const TransportSlot& sl, uint32_t s, GammaContext& ctx, uint64_t interaction_key) {
    set_random_key(ctx, mix64(interaction_key ^ uint64_t(sl.event)));
    for (size_t j = 0; j < M_; ++j) carried_before_[j] = float(carried(j, sl.ton_type));
    int32_t bad;
    if (!sl.writes) {
        bad = sl.fn(carry_.data(), rows_ + size_t(s) * W_, scratch_.data(), &ctx);
    } else {
        std::fill(delta_.begin() + GAMMA_ROW_HEADER, delta_.end(), 0.0f);
        bad = sl.fn(carry_.data(), rows_ + size_t(s) * W_, delta_.data(), &ctx);
        if (ton_weight_ != 1.0f)
            for (int j = GAMMA_ROW_HEADER; j < W_; ++j) delta_[size_t(j)] *= ton_weight_;
        log_.record(s, delta_.data() + GAMMA_ROW_HEADER, P_);
    }
    for (size_t j = 0; j < M_; ++j) {
        const int col = MP_[j].column[size_t(sl.surface)];
        const double ds = sl.writes && col >= 0 ? double(delta_[size_t(col)]) : 0.0;
        // a gamma-ton stands for ton_weight of its source's strength (SPEC §13.2): so does what it carries
        const double dt = (carried(j, sl.ton_type) - double(carried_before_[j])) * ton_weight_;
        MassBooks& b = st_.mass[j];
        if (ds < 0) b.removed -= ds;
        else b.deposited += ds;
        b.created += ds + dt;
    }
    if (bad) count_nonfinite(st_.nonfinite, sl.event, sl.ton_type, sl.surface, bad);
}

// A gamma-ton's life ends: what it still carries escapes or is dropped.
void ChunkTracer::end_life(int type, bool settled) {
    for (size_t j = 0; j < M_; ++j)
        (settled ? st_.mass[j].dropped : st_.mass[j].escaped) += carried(j, type) * ton_weight_;
}

}  // namespace

void Tracer::run_chunks(int iteration, int64_t first, int64_t last, const SceneIndex& index,
                        const SceneFrame& frame, const SurfelState& state, const UniformReflectance& reflectance,
                        ChunkLog* out, std::vector<RecordedRay>* rays_out, const CancelToken& cancel,
                        bool one_at_a_time) const {
    const Emission plan = emission(iteration, state, frame);
    const PassInputs in{cfg_, kernels_, index, frame, state, reflectance, plan.sched,
                        sources_of_pass(sources_, plan.tables, state, mesh_),
                        source_weights(cfg_, plan.sched, state.size()), max_carry_, iteration};
    auto run_chunk = [&](int64_t ci) {
        cancel.check("the trace");   // (TBB cancels the other chunks and rethrows it to the caller)
        ChunkLog& log = out[size_t(ci - first)];
        log.clear();
        ChunkTracer tracer(in, log, rays_out ? &rays_out[size_t(ci - first)] : nullptr);
        const int64_t begin = ci * kChunkSize, end = std::min(plan.sched.total(), begin + kChunkSize);
        if (one_at_a_time) tracer.trace_one_at_a_time(begin, end);
        else tracer.trace_batched(begin, end);
        log.st = tracer.stats();
    };
    run_with_threads(cfg_.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(first, last, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) run_chunk(ci);
        });
    });
}

std::vector<RecordedRay> Tracer::take_recorded_rays() {
    size_t n = 0;
    for (const auto& l : ray_logs_) n += l.size();
    std::vector<RecordedRay> all;
    all.reserve(n);
    for (const auto& l : ray_logs_) all.insert(all.end(), l.begin(), l.end());
    ray_logs_.clear();
    return all;
}

RaycastStats cast_recorded(const SceneIndex& index, const std::vector<RecordedRay>& rays, int threads) {
    const auto t0 = std::chrono::steady_clock::now();
    const int64_t n_rays = int64_t(rays.size());
    const int64_t nchunks = (n_rays + kChunkSize - 1) / kChunkSize;
    std::vector<int64_t> hits(size_t(nchunks), 0);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, nchunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) {
                int64_t h = 0;
                const int64_t b = ci * kChunkSize, e = std::min(n_rays, b + kChunkSize);
                for (int64_t i = b; i < e; ++i) {
                    const RecordedRay& q = rays[size_t(i)];
                    RTCRayHit rh;
                    index.cast(rh, V3{q.org[0], q.org[1], q.org[2]}, V3{q.dir[0], q.dir[1], q.dir[2]}, q.tnear,
                               q.tfar);
                    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) ++h;
                }
                hits[size_t(ci)] = h;
            }
        });
    });
    RaycastStats st;
    st.rays = n_rays;
    for (int64_t h : hits) st.hits += h;
    st.seconds = seconds_since(t0);
    return st;
}

RaycastStats raw_raycast(const SceneIndex& index, const SceneFrame& frame, int64_t n_rays, int threads,
                         uint64_t seed) {
    const auto t0 = std::chrono::steady_clock::now();
    const int64_t nchunks = (n_rays + kChunkSize - 1) / kChunkSize;
    std::vector<int64_t> hits(size_t(std::max<int64_t>(nchunks, 0)), 0);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int64_t>(0, nchunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
            for (int64_t ci = r.begin(); ci < r.end(); ++ci) {
                int64_t h = 0;
                const int64_t b = ci * kChunkSize, e = std::min(n_rays, b + kChunkSize);
                for (int64_t g = b; g < e; ++g) {
                    PhiloxStream rng(seed, 0, uint64_t(g));
                    V3 org, dir;
                    emit_environment(frame.centre, frame.radius, frame.up, rng, false, org, dir);
                    RTCRayHit rh;
                    index.cast(rh, org, dir, 0.0f);
                    if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) ++h;
                }
                hits[size_t(ci)] = h;
            }
        });
    });
    RaycastStats st;
    st.rays = std::max<int64_t>(n_rays, 0);
    for (int64_t h : hits) st.hits += h;
    st.seconds = seconds_since(t0);
    return st;
}

void parabola_landing(std::array<float, 3> p0a, std::array<float, 3> da, float D, std::array<float, 3> downa,
                      float floor_height, std::array<float, 3>& traced, std::array<float, 3>& analytic) {
    if (!finite3(p0a) || !nonzero3(da) || !nonzero3(downa) || !std::isfinite(floor_height))
        throw Error("parabola_landing: arguments must be finite, d and down non-zero");
    if (!(D > 0) || !std::isfinite(D)) throw Error("parabola_landing: D must be positive");
    const V3 p0{p0a[0], p0a[1], p0a[2]}, d = unit(da), down = unit(downa), up = down * -1.0f;
    const double h0 = double(dot(p0, up)) - floor_height;
    if (h0 < 0) throw Error("parabola_landing: p0 is below the floor");
    const double v = launch_speed(D);
    const V3 vel = d * float(v);
    // Analytic: h(t) = h0 + v*du*t - t^2/2 = 0.
    const double vu = v * double(dot(d, up));
    const double t_star = vu + std::sqrt(vu * vu + 2.0 * h0);
    const V3 a_pt = flight_point(p0, vel, down, t_star);
    analytic = {a_pt.x, a_pt.y, a_pt.z};
    V3 hit{};
    int64_t segments = 0;
    FlightEnd end = fly(
        p0, vel, down, flight_dt(D), segments,
        [&](V3 a, V3 b) {
            const double ha = double(dot(a, up)) - floor_height, hb = double(dot(b, up)) - floor_height;
            if (!(hb <= 0)) return false;
            const double s = ha > hb ? ha / (ha - hb) : 0.0;
            hit = a + (b - a) * float(s);
            return true;
        },
        [](V3, double) { return false; });
    if (end != FlightEnd::Landed) throw Error("parabola_landing: the flight never reaches the floor");
    traced = {hit.x, hit.y, hit.z};
}

}  // namespace gammart
