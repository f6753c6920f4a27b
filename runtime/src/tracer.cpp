// The gamma-ton loop of one iteration (see gamma/tracer.h).
#include "gamma/tracer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
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
                       record_rays_ ? ray_logs_.data() + first : nullptr, cancel);
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
                                           const SceneFrame& frame, const SurfelState& state) const {
    const int64_t nchunks = num_chunks(iteration, state, frame);
    if (first < 0 || last > nchunks || first > last)
        throw Error("trace_chunks: chunks [" + std::to_string(first) + ", " + std::to_string(last) +
                    ") are not within the " + std::to_string(nchunks) + " chunks of iteration " +
                    std::to_string(iteration));
    std::vector<ChunkLog> logs(size_t(last - first));
    run_chunks(iteration, first, last, index, frame, state, uniform_reflectance(index, state), logs.data(), nullptr,
               CancelToken::never());
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

void Tracer::run_chunks(int iteration, int64_t first, int64_t last, const SceneIndex& index,
                        const SceneFrame& frame, const SurfelState& state, const UniformReflectance& reflectance,
                        ChunkLog* out, std::vector<RecordedRay>* rays_out, const CancelToken& cancel) const {
    const Config& c = cfg_;
    const KernelTable& K = kernels_;
    const int W = state.width;
    const int P = W - GAMMA_ROW_HEADER;  // property columns
    const Emission plan = emission(iteration, state, frame);
    const EmissionSchedule& sched = plan.sched;
    // surface sources emit from this iteration's table of their surfels
    std::vector<SourceRt> sources = sources_;
    float spread = 0.0f;
    if (mesh_ != nullptr && state.size() > 0) {   // half the mean surfel spacing sqrt(A / n)
        double area = 0.0;
        const std::vector<float>& v = mesh_->vertices;
        const std::vector<int32_t>& t = mesh_->triangles;
        for (size_t k = 0; k + 2 < t.size(); k += 3) {
            const V3 a{v[3 * size_t(t[k])], v[3 * size_t(t[k]) + 1], v[3 * size_t(t[k]) + 2]};
            const V3 b{v[3 * size_t(t[k + 1])], v[3 * size_t(t[k + 1]) + 1], v[3 * size_t(t[k + 1]) + 2]};
            const V3 c{v[3 * size_t(t[k + 2])], v[3 * size_t(t[k + 2]) + 1], v[3 * size_t(t[k + 2]) + 2]};
            area += 0.5 * double(length(cross(b - a, c - a)));
        }
        spread = float(0.5 * std::sqrt(area / double(state.size())));
    }
    for (size_t i = 0; i < sources.size(); ++i)
        if (sources[i].kind == SourceKind::Surface) {
            if (mesh_ == nullptr) throw Error("a surface source needs the scene's mesh (Tracer::set_mesh)");
            sources[i].table = &plan.tables[i];
            sources[i].positions = state.surf.position.data();
            sources[i].normals = state.surf.normal.data();
            sources[i].surfel_triangle = state.surf.triangle.data();
            sources[i].mesh_vertices = mesh_->vertices.data();
            sources[i].mesh_triangles = mesh_->triangles.data();
            sources[i].spread = spread;
        }
    const std::vector<int64_t>& start = sched.start;
    const int64_t total = sched.total();
    const float* rows = state.rows.data();
    const int32_t* surf_of = state.surface.data();
    const SurfelMeasures& measures = state.measures;
    const int max_inter = c.max_interactions;
    const size_t step_budget = size_t(c.trace_step_budget > 0 ? c.trace_step_budget : kStepBudget);
    const uint64_t seed = c.seed;
    const uint32_t iter_u = uint32_t(iteration);
    const V3 up = frame.up;
    // Weight of each active source's gamma-tons (SPEC §13.2): strength * n / N.
    std::vector<float> weight;
    for (size_t k = 0; k < sched.active.size(); ++k) {
        const Source& so = c.sources[sched.active[k]];
        weight.push_back(so.strength > 0 && so.count > 0
                             ? float(double(so.strength) * double(state.size()) / double(so.count))
                             : 1.0f);
    }

    auto run_chunk = [&](int64_t ci) {
        cancel.check("the trace");   // (TBB cancels the other chunks and rethrows it to the caller)
        ChunkLog& log = out[size_t(ci - first)];
        log.clear();
        TraceStats st;
        std::vector<float> carry(max_carry_, 0.0f);
        std::vector<float> delta(size_t(W), 0.0f), scratch(size_t(W), 0.0f);
        const int64_t begin = ci * kChunkSize, end = std::min(total, begin + kChunkSize);
        size_t a = size_t(std::upper_bound(start.begin(), start.end(), begin) - start.begin()) - 1;
        // interaction_key: mixed from (seed, iteration, gamma-ton, interaction);
        // each event's kernel gets its own random() key from it.
        // Mass books (only when properties are accounted): per kernel call,
        // the change of the surface column and of the carried attribute.
        const std::vector<MassProperty>& MP = c.mass_properties;
        const size_t M = MP.size();
        st.mass.assign(M, MassBooks{});
        std::vector<float> carried_before(M, 0.0f);
        auto carried = [&](size_t j, int type) -> double {
            const int ci = MP[j].carry[size_t(type)];
            return ci >= 0 ? double(carry[size_t(ci)]) : 0.0;
        };
        float ton_weight = 1.0f;
        auto call = [&](const TransportSlot& sl, uint32_t s, GammaContext& ctx, uint64_t interaction_key) {
            set_random_key(ctx, mix64(interaction_key ^ uint64_t(sl.event)));
            for (size_t j = 0; j < M; ++j) carried_before[j] = float(carried(j, sl.ton_type));
            int32_t bad;
            if (!sl.writes) {
                bad = sl.fn(carry.data(), rows + size_t(s) * W, scratch.data(), &ctx);
            } else {
                std::fill(delta.begin() + GAMMA_ROW_HEADER, delta.end(), 0.0f);
                bad = sl.fn(carry.data(), rows + size_t(s) * W, delta.data(), &ctx);
                if (ton_weight != 1.0f)
                    for (int j = GAMMA_ROW_HEADER; j < W; ++j) delta[size_t(j)] *= ton_weight;
                log.record(s, delta.data() + GAMMA_ROW_HEADER, P);
            }
            for (size_t j = 0; j < M; ++j) {
                const int col = MP[j].column[size_t(sl.surface)];
                const double ds = sl.writes && col >= 0 ? double(delta[size_t(col)]) : 0.0;
                // a gamma-ton stands for ton_weight of its source's strength (SPEC §13.2): so does what it carries
                const double dt = (carried(j, sl.ton_type) - double(carried_before[j])) * ton_weight;
                MassBooks& b = st.mass[j];
                if (ds < 0) b.removed -= ds;
                else b.deposited += ds;
                b.created += ds + dt;
            }
            if (bad) count_nonfinite(st.nonfinite, sl.event, sl.ton_type, sl.surface, bad);
        };
        // A gamma-ton's life ends: what it still carries escapes or is dropped.
        auto end_life = [&](int type, bool settled) {
            for (size_t j = 0; j < M; ++j) (settled ? st.mass[j].dropped : st.mass[j].escaped) += carried(j, type) * ton_weight;
        };
        Walker w(index, frame, st);
        if (rays_out) w.record = &rays_out[size_t(ci - first)];

        // The gamma-tons go in groups of kEmitGroup: emit every gamma-ton,
        // then cast every emission ray (starting the fetch of each hit
        // triangle's lookup head), then find each hit's surfel (starting the
        // fetch of its row), then trace the group's paths together, then run
        // the kernels of each gamma-ton's interactions in gamma-ton order.
        // The dependent cache misses of an interaction (head, then row)
        // overlap with the other gamma-tons' work instead of following one
        // another.  Emission, casts and paths depend only on the gamma-ton's
        // own stream, the scene and the rows, and the kernels run in the
        // order the lives ran one by one: the same draws, rays, records and
        // sums, the same bytes.
        const bool need_normal = !measures.accessibility.empty() || !measures.curvature.empty();
        const bool need_uv = !measures.uv.empty();
        struct Emitted {
            PhiloxStream rng;
            V3 org, d0, p, n;
            uint32_t prim, s;
            size_t a;  // active source
            int event;  // of the first interaction (plan)
            bool hit, need_surfel;
        };
        std::array<Emitted, kEmitGroup> group_slots;
        // A gamma-ton's path while the group's paths advance, and one
        // interaction of it (steps of one gamma-ton linked in order).
        enum class LifeEnd : uint8_t { Missed, Escaped, Settled, Capped, Alive };
        constexpr uint32_t kNoStep = UINT32_MAX;
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
        struct Step {
            V3 p, n, dir;
            uint32_t s;
            int inter, event;
            uint32_t next;
        };
        std::array<Path, kEmitGroup> paths;
        constexpr uint32_t kNoSurfel = UINT32_MAX;
        const std::vector<int32_t>& tri_surface = index.tri_surface();
        // The event of the interaction where a path has just landed, drawn
        // there: it is the gamma-ton's next draw whenever it is drawn (the
        // motion's draws came before it, nothing else draws from the stream
        // in between), so drawing it at the landing changes no draw.  Returns
        // whether the interaction needs its surfel: for the rules of its
        // event or of every hit, or for its reflectances where its
        // surface's surfels differ in them.  Otherwise the surfel is never
        // looked up (most reflections of most effects).
        auto plan = [&](PhiloxStream& rng, float ks, float kp, float kf, int type, uint32_t prim,
                        int& event) -> bool {
            const float xi = rng.next();
            const float c1 = std::min(ks, 1.0f);
            const float c2 = std::min(c1 + kp, 1.0f);
            const float c3 = std::min(c2 + kf, 1.0f);
            event = xi < c1 ? GAMMA_EVENT_REFLECT
                  : xi < c2 ? GAMMA_EVENT_BOUNCE
                  : xi < c3 ? GAMMA_EVENT_FLOW
                            : GAMMA_EVENT_SETTLE;
            if (prim >= tri_surface.size()) return true;
            const int surface = tri_surface[prim];
            if (surface < 0 || size_t(surface) >= reflectance.uniform.size() || !reflectance.uniform[size_t(surface)])
                return true;
            return K.slot(GAMMA_EVENT_HIT, type, surface).fn != nullptr || K.slot(event, type, surface).fn != nullptr;
        };
        std::vector<Step> steps;
        std::vector<uint32_t> alive;
        alive.reserve(kEmitGroup);
        // The surfel of a path's hit (after its first), its row fetched ahead.
        auto find_surfel = [&](Path& path) {
            const float pa[3] = {path.p.x, path.p.y, path.p.z};
            path.s = index.nearest_on_triangle(path.prim, pa);
            __builtin_prefetch(rows + size_t(path.s) * W);
            __builtin_prefetch(rows + size_t(path.s) * W + (W - 1));
            __builtin_prefetch(surf_of + path.s);
        };
        // One interaction of gamma-ton k's path at its surfel: the event, put
        // in `step`, then (unless the life ends there) the motion to the next
        // hit.  Returns whether the path goes on.  The group's rounds and the
        // continuation of the paths a round left alive both advance by it.
        auto advance = [&](uint32_t k, Step& step) -> bool {
            Path& path = paths[k];
            const int type = c.sources[sched.active[group_slots[k].a]].ton_type;
            const TonType& tt = c.ton_types[size_t(type)];
            PhiloxStream& rng = group_slots[k].rng;
            const int inter = ++path.inter;
            const int event = path.event;
            step = Step{path.p, path.n, path.dir, path.s, inter, event, kNoStep};
            if (event == GAMMA_EVENT_SETTLE) { path.end = LifeEnd::Settled; return false; }
            if (inter >= max_inter) { path.end = LifeEnd::Capped; return false; }
            // without its surfel, the surface's columns (the same in every surfel of it)
            const float* row = path.s != kNoSurfel ? rows + size_t(path.s) * W
                                                   : reflectance.columns[size_t(tri_surface[path.prim])].data();
            const float ds = row[GAMMA_ROW_REFLECTANCE_STRAIGHT], dp = row[GAMMA_ROW_REFLECTANCE_PARABOLIC],
                        df = row[GAMMA_ROW_REFLECTANCE_FLOW];
            const float kp_left = std::max(path.kp - dp, 0.0f);
            path.ks = std::max(path.ks - ds, 0.0f);
            path.kf = std::max(path.kf + kp_left - df, 0.0f);
            path.kp = kp_left;
            w.p = path.p;
            w.n = path.n;
            w.dir = path.dir;
            w.prim = path.prim;
            const FlightEnd fe = kMotionTable.step[event](w, rng, tt);
            if (fe == FlightEnd::Escaped) { path.end = LifeEnd::Escaped; return false; }
            if (fe == FlightEnd::Capped) { path.end = LifeEnd::Capped; return false; }
            path.p = w.p;
            path.n = w.n;
            path.dir = w.dir;
            path.prim = w.prim;
            path.s = kNoSurfel;  // until find_surfel, if the next interaction needs it
            path.need_surfel = plan(rng, path.ks, path.kp, path.kf, type, path.prim, path.event);
            return true;
        };
        // The kernels of one interaction of gamma-ton g (of ton type `type`).
        auto run_kernels = [&](const Step& step, int type, int64_t g) {
            if (step.s == kNoSurfel) return;  // no rule runs there (plan)
            const uint32_t s = step.s;
            const int surface = surf_of[s];
            const TransportSlot& hit = K.slot(GAMMA_EVENT_HIT, type, surface);
            const TransportSlot& ev = K.slot(step.event, type, surface);
            // An interaction no rule handles (most reflections) needs no
            // context: none is built, no measure is read.
            if (!hit.fn && !ev.fn) return;
            const V3 p = step.p, n = step.n, dir = step.dir;
            GammaContext ctx;
            ctx.position[0] = p.x; ctx.position[1] = p.y; ctx.position[2] = p.z;
            ctx.normal[0] = n.x; ctx.normal[1] = n.y; ctx.normal[2] = n.z;
            ctx.direction[0] = dir.x; ctx.direction[1] = dir.y; ctx.direction[2] = dir.z;
            ctx.height = dot(p, up) - frame.min_up;
            ctx.iteration = iteration;
            ctx.interactions = step.inter;
            // the measures of the surfel the rules run on (SPEC §12)
            ctx.uv[0] = need_uv ? measures.uv[2 * size_t(s)] : 0.0f;
            ctx.uv[1] = need_uv ? measures.uv[2 * size_t(s) + 1] : 0.0f;
            ctx.up[0] = up.x; ctx.up[1] = up.y; ctx.up[2] = up.z;
            // on the side the gamma-ton came from (n is turned toward it);
            // the surfel's normal (a cache miss) only when a measure needs it
            ctx.accessibility = 0.0f;
            ctx.curvature = 0.0f;
            if (need_normal) {
                const float* sn = state.surf.normal.data() + 3 * size_t(s);
                const bool back = n.x * sn[0] + n.y * sn[1] + n.z * sn[2] < 0.0f;
                if (!measures.accessibility.empty())
                    ctx.accessibility = back ? measures.accessibility_back[s] : measures.accessibility[s];
                if (!measures.curvature.empty()) ctx.curvature = back ? -measures.curvature[s] : measures.curvature[s];
            }
            const uint64_t key = mix64(mix64(mix64(seed ^ uint64_t(iter_u)) ^ uint64_t(g)) ^ uint64_t(step.inter));
            if (hit.fn) call(hit, s, ctx, key);
            if (ev.fn) call(ev, s, ctx, key);
        };
        std::array<PhiloxStream, kEmitGroup> run_rng;
        std::array<V3, kEmitGroup> run_org, run_dir;
        for (int64_t g0 = begin; g0 < end; g0 += kEmitGroup) {
            const int64_t g1 = std::min(end, g0 + kEmitGroup);
            Emitted* const group = group_slots.data();
            const size_t n_group = size_t(g1 - g0);
            // Every emission first, then every cast: independent emissions
            // overlap in the core (no opaque call between them), and the
            // casts run back to back with Embree's working set warm.
            for (int64_t g = g0; g < g1;) {  // runs of one source each
                while (g >= start[a + 1]) ++a;
                const int64_t run_end = std::min(g1, start[a + 1]);
                const size_t n_run = size_t(run_end - g);
                emit_run(sources[sched.active[a]], seed, iter_u, g, n_run, run_rng.data(), run_org.data(),
                         run_dir.data());
                for (size_t i = 0; i < n_run; ++i) {
                    Emitted& e = group[g - g0 + int64_t(i)];
                    e.rng = run_rng[i];
                    e.org = run_org[i];
                    e.d0 = run_dir[i];
                    e.a = a;
                }
                g = run_end;
            }
            // A hit's candidates past its head are fetched kRestLag casts
            // after its head, when the head has arrived to say where they are.
            for (size_t k = 0; k < n_group; ++k) {
                Emitted& e = group[k];
                // the emission ray, counted and recorded as Walker::straight does
                if (w.record) w.record->push_back(RecordedRay{{e.org.x, e.org.y, e.org.z}, {e.d0.x, e.d0.y, e.d0.z},
                                                              0.0f, std::numeric_limits<float>::infinity()});
                ++st.rays;
                index.cast(w.rh, e.org, e.d0, 0.0f);
                e.hit = land(w.rh, e.org, e.d0, e.p, e.n, e.prim);
                e.need_surfel = false;
                if (e.hit) {
                    const int type = c.sources[sched.active[e.a]].ton_type;
                    const TonType& tt = c.ton_types[size_t(type)];
                    e.need_surfel = plan(e.rng, tt.ks, tt.kp, tt.kf, type, e.prim, e.event);
                    if (e.need_surfel) index.prefetch_lookup(e.prim);
                }
                if (k >= kRestLag && group[k - kRestLag].need_surfel)
                    index.prefetch_lookup_rest(group[k - kRestLag].prim);
            }
            for (size_t k = n_group > kRestLag ? n_group - kRestLag : 0; k < n_group; ++k)
                if (group[k].need_surfel) index.prefetch_lookup_rest(group[k].prim);
            for (size_t k = 0; k < n_group; ++k) {
                Emitted& e = group[k];
                e.s = kNoSurfel;
                if (!e.need_surfel) continue;
                const float pa[3] = {e.p.x, e.p.y, e.p.z};
                e.s = index.nearest_on_triangle(e.prim, pa);
                const float* row = rows + size_t(e.s) * W;
                __builtin_prefetch(row);
                __builtin_prefetch(row + (W - 1));
                __builtin_prefetch(surf_of + e.s);
                if (need_uv) __builtin_prefetch(measures.uv.data() + 2 * size_t(e.s));
                if (need_normal) __builtin_prefetch(state.surf.normal.data() + 3 * size_t(e.s));
            }
            // The paths: which surfels each gamma-ton meets, with which event,
            // and how its life ends.  A path depends only on the gamma-ton's
            // own stream, the scene and the rows (never on what the kernels
            // do), so the group's paths advance together, one interaction
            // each per round: a gamma-ton's next lookup and row are fetched
            // while the others move.
            steps.clear();
            alive.clear();
            for (size_t k = 0; k < n_group; ++k) {
                const Emitted& e = group[k];
                Path& path = paths[k];
                const TonType& tt = c.ton_types[size_t(c.sources[sched.active[e.a]].ton_type)];
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
                path.s = e.s;  // found in the group's second pass, if needed
                path.event = e.event;
                path.need_surfel = e.need_surfel;
                alive.push_back(uint32_t(k));
            }
            while (!alive.empty() && steps.size() < step_budget) {
                for (uint32_t k : alive)
                    if (paths[k].inter > 0 && paths[k].need_surfel) find_surfel(paths[k]);
                size_t still = 0;
                for (uint32_t k : alive) {
                    Path& path = paths[k];
                    Step step;
                    const bool goes_on = advance(k, step);
                    const uint32_t at = uint32_t(steps.size());
                    steps.push_back(step);
                    if (path.last_step == kNoStep) path.first_step = at;
                    else steps[path.last_step].next = at;
                    path.last_step = at;
                    if (!goes_on) continue;
                    if (path.need_surfel) index.prefetch_lookup(path.prim);
                    alive[still++] = k;
                }
                alive.resize(still);
            }
            // The kernels, in gamma-ton order and each gamma-ton's interactions
            // in order, as the lives ran before their paths were split off:
            // the same calls, records and sums.
            for (size_t k = 0; k < n_group; ++k) {
                const Emitted& e = group[k];
                Path& path = paths[k];
                const int64_t g = g0 + int64_t(k);
                const int type = c.sources[sched.active[e.a]].ton_type;
                const TonType& tt = c.ton_types[size_t(type)];
                ton_weight = weight[e.a];
                ++st.emitted;
                if (path.end == LifeEnd::Missed) {
                    // Nothing runs on a miss (three gamma-tons in four of an
                    // environment source): what it carries is emitted and
                    // escapes at once, read from its initial carry without
                    // copying it into `carry` (a mass property's carry index
                    // lies within its ton type's initial carry: config.cpp).
                    ++st.escaped;
                    ++st.missed;
                    for (size_t j = 0; j < M; ++j) {
                        const int ci = MP[j].carry[size_t(type)];
                        const double v = ci >= 0 ? double(tt.initial_carry[size_t(ci)]) : 0.0;
                        st.mass[j].emitted += v * ton_weight;
                        st.mass[j].escaped += v * ton_weight;
                    }
                    continue;
                }
                std::copy(tt.initial_carry.begin(), tt.initial_carry.end(), carry.begin());
                for (size_t j = 0; j < M; ++j) st.mass[j].emitted += carried(j, type) * ton_weight;
                for (uint32_t at = path.first_step; at != kNoStep; at = steps[at].next)
                    run_kernels(steps[at], type, g);
                // A path the rounds left alive (they stopped at the step
                // budget) goes on here one interaction at a time, each run
                // at once: its path and draws are those the rounds would have
                // made, its kernels run in the same order.
                while (path.end == LifeEnd::Alive) {
                    if (path.inter > 0 && path.need_surfel) find_surfel(path);
                    Step step;
                    advance(uint32_t(k), step);
                    run_kernels(step, type, g);
                }
                switch (path.end) {
                    case LifeEnd::Settled: ++st.settled; end_life(type, true); break;
                    case LifeEnd::Capped: ++st.capped; end_life(type, false); break;
                    default: ++st.escaped; end_life(type, false); break;
                }
                st.interactions += path.inter;
            }
        }
        log.st = st;
    };

    run_with_threads(c.threads, [&] {
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
