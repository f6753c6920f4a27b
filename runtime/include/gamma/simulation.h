// The simulation facade: one run's parts wired together and the API the
// Python binding and the tests use.  Each part lives in its own file:
//   config.h        validation of the run-wide settings
//   scene_index.h   Embree BVH + per-surface surfel kd-trees (rebuildable)
//   surfel_state.h  surfel positions, surfaces and rows
//   sources.h       gamma-ton sources and emission
//   kernel_table.h  compiled kernels per (event, ton type, surface)
//   tracer.h        the gamma-ton loop; motion.h its per-mode step table;
//                   surface_log.h the deposit path (chunk logs and merge)
//   update_pass.h   the update rules
//   renderer.h      false-colour and appearance renders
//   baker.h         rows and colours at surface points
//   shape_step.h    displacement, re-tiling (remesh.h), surfel transfer, rebuild
#pragma once
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <vector>

#include "gamma/baker.h"
#include "gamma/cancel.h"
#include "gamma/config.h"
#include "gamma/kernel_table.h"
#include "gamma/mesh.h"
#include "gamma/render.h"
#include "gamma/renderer.h"
#include "gamma/scene_index.h"
#include "gamma/setup_snapshot.h"
#include "gamma/shape_step.h"
#include "gamma/shading.h"
#include "gamma/sources.h"
#include "gamma/stats.h"
#include "gamma/surfel_state.h"
#include "gamma/surfels.h"
#include "gamma/threads.h"
#include "gamma/tracer.h"

namespace gammart {

class Simulation {
public:
    // Validates config (throws gammart::Error), resamples surfels, builds the
    // Embree scene and the surfel kd-trees.  A surface that has triangles but
    // receives no surfel is an error (its hits would otherwise run another
    // surface's rules).  `ahead`: surfels sampled before (surfel_state.h),
    // taken when they are the ones this setup would sample (the result is
    // the same either way).  `snapshot`: an earlier setup (setup_snapshot.h),
    // whose surfels, lookup and splat kernel are taken when it matches this
    // mesh, count, seed and binding, and only its surfels when just the
    // binding differs (the result is again the same); it is preferred to
    // `ahead`.  `cancel` stops the setup between its phases (Cancelled).
    Simulation(const Mesh& mesh, const Config& config, SurfelSample* ahead = nullptr,
               SetupSnapshot* snapshot = nullptr, const CancelToken& cancel = CancelToken::never());
    ~Simulation();
    Simulation(const Simulation&) = delete;
    Simulation& operator=(const Simulation&) = delete;

    // Takes another effect (kernels, sources, initial rows, options) for the
    // next run, keeping the surfels, the scene index and the splat kernel:
    // the state is then what Simulation(mesh, config) would give, without
    // its setup.  Throws gammart::Error (nothing changed) unless the surfel
    // count, the seed and the binding of triangles to surfaces are the same
    // and the shape never changed.
    void reconfigure(const Config& config);

    size_t num_surfels() const { return state_.size(); }
    int row_width() const { return state_.width; }
    const SurfelSet& surfels() const { return state_.surf; }
    const std::vector<int32_t>& surfel_surfaces() const { return state_.surface; }
    const std::vector<float>& rows() const { return state_.rows; }
    // Accessibility, curvature and uv per surfel (those the config requested).
    const SurfelMeasures& measures() const { return state_.measures; }
    void set_rows(const float* data);  // N*W floats

    // `cancel` stops the trace before its next chunk of gamma-tons: it throws
    // Cancelled and leaves the rows as they were.
    TraceStats trace(int iteration, const CancelToken& cancel = CancelToken::never());
    // trace() in pieces (see Tracer::trace_chunks): the driver of a
    // distributed run merges the chunks its workers traced.
    int64_t num_chunks(int iteration) const { return tracer_->num_chunks(iteration, state_, frame_); }
    std::vector<ChunkLog> trace_chunks(int iteration, int64_t first, int64_t last, bool one_at_a_time = false) const {
        return tracer_->trace_chunks(iteration, first, last, *index_, frame_, state_, one_at_a_time);
    }
    TraceStats merge_chunks(int iteration, const std::vector<ChunkLog>& logs) {
        shape_.begin_iteration(state_);  // as trace(): the rows before this iteration's deposits
        return tracer_->merge_chunks(iteration, logs, state_, frame_);
    }
    // merge_chunks in batches (see Tracer::merge_begin): a driver merges
    // chunks as they arrive, holding one batch of logs at a time.
    void merge_begin(int iteration) {
        shape_.begin_iteration(state_);  // the rows stay those before this iteration's deposits until merge_end
        tracer_->merge_begin(iteration, state_, frame_);
    }
    void merge_add(const std::vector<ChunkLog>& logs) { tracer_->merge_add(logs, state_); }
    TraceStats merge_end() { return tracer_->merge_end(state_); }
    // The update and the shape step take `cancel` before they start (they
    // change the rows and the mesh in place; an update takes milliseconds).
    UpdateStats update(int iteration, const CancelToken& cancel = CancelToken::never());
    // The shape step (after update): nothing happens unless some surface's
    // shape follows a property (Config::shape_rates).
    ShapeStats shape(int iteration, const CancelToken& cancel = CancelToken::never());
    int shape_rebuilds() const { return shape_.rebuilds(); }
    // The current mesh (deformed and re-tiled once the shape changed).
    const Mesh& mesh() const { return mesh_; }
    RaycastStats raw_raycast(int64_t n_rays, int threads, uint64_t seed);
    // The rays trace(iteration) casts from the current state, in the order
    // the tracer casts them within a group of gamma-tons (a group's paths
    // advance together), groups and chunks in gamma-ton order: the same at
    // any thread count. The rows are left as they were (the trace runs on a
    // copy).
    std::vector<RecordedRay> record_rays(int iteration);
    // Embree alone on those rays (the tracer-efficiency baseline).
    RaycastStats cast_rays(const std::vector<RecordedRay>& rays, int threads) const;
    // Out arrays are height*width.  The renders and bakes below check
    // `cancel` row by row (block by block): Cancelled.
    void render(const float* values, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads,
                float* out_value, float* out_shade, const CancelToken& cancel = CancelToken::never()) const;
    // The false-colour render's rays cast once, for the pictures of many values (renderer.h).
    FalseColourView false_colour_view(std::array<float, 3> eye, std::array<float, 3> target,
                                      std::array<float, 3> up, float fov_deg, int width, int height,
                                      int threads, const CancelToken& cancel = CancelToken::never()) const;

    // Shading of the renders (shading.h): flat[t] != 0 renders triangle t
    // flat (empty: none), crease_deg <= 0 renders every triangle flat.  After
    // a re-tiling, a triangle is flat when every triangle of its surface was.
    // Throws gammart::Error if flat has the wrong size or crease_deg is not
    // finite.
    void set_shading(std::vector<uint8_t> flat, float crease_deg);
    // (Computed on first use after a shape step changed the mesh.)  Shared, not
    // referenced: a later set_shading or shape step makes a new vector and
    // leaves this one to whoever still holds it.
    std::shared_ptr<const std::vector<float>> corner_normals() const;

    // Textures for the appearance kernels (kernel argument `textures`, 3
    // floats per texture in this order).  Throws gammart::Error.
    void set_textures(std::vector<Texture> textures);
    const std::vector<Texture>& textures() const { return textures_; }
    // The scene's own base colours (glTF materials): what surfaces without an
    // appearance render with and what `base_color()` reads.  After a
    // re-tiling a triangle keeps a material when its surface had only that
    // one.  Throws gammart::Error on sizes or indices out of range and on
    // non-finite factors or texels.
    void set_base_colours(BaseColours base);
    // Physically plausible preview: appearance kernels per camera sample,
    // sky ambient x AO + sun with shadows.  out_rgba: height*width*4.
    // Throws gammart::Error on bad parameters.
    RenderStats render_appearance(const AppearanceParams& params, float* out_rgba,
                                  const CancelToken& cancel = CancelToken::never()) const;

    // The property smoothing shared by both renders: the k = 8 nearest
    // surfels of `surface` to p (all surfels if the surface has none; the
    // nearest k of all if surface is out of range), Gaussian weights
    // exp(-d^2 / (2 sigma^2)), sigma = sqrt(A/N), normalised to sum 1; if
    // every weight underflows, the nearest surfel alone (weight 1).  Returns
    // the number of neighbours written to idx / w (nearest first).
    size_t smoothing_weights(int surface, const float p[3], uint32_t idx[kSmoothingNeighbours],
                             double w[kSmoothingNeighbours]) const;
    // The smoothed row (W floats): out[c] = float(sum_j w_j * row_j[c]).
    void interpolate_row(int surface, const float p[3], float* out) const;
    // gammart::look_at (renderer.h) on this simulation's scene.
    int32_t look_at(uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                    const float uv[2], int iteration, uint64_t random_key, float* row, float* tex,
                    float out_look[GAMMA_LOOK_WIDTH]) const;
    // For baking and export: at each of k surface points (position, normal,
    // triangle, uv), the smoothed row (k x W) and the look (k x GAMMA_LOOK_WIDTH: abi.py's APPEARANCE_OUTPUTS).
    void bake_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                     const float* uvs, int iteration, int threads, float* rows_out, float* look_out,
                     const CancelToken& cancel = CancelToken::never()) const;
    // bake_points at texels of a texture layout (gammart::bake_texels).
    void bake_texels(const TexelLayout& layout, size_t k, const int32_t* tris, const double* bary,
                     const TexelGrid* grid, const ChannelSlots& slots, int iteration, int threads,
                     float* channels_out, const CancelToken& cancel = CancelToken::never()) const;
    float smoothing_sigma() const;
    // bake_points for points baked again and again (the live viewer's
    // vertices): prepare_points finds their neighbours once; bake_prepared
    // then gives bake_points' results.  A shape change forgets the points
    // (num_prepared_points() == 0; bake_prepared throws gammart::Error).
    void prepare_points(size_t k, const float* positions, const float* normals, const int32_t* triangles,
                        const float* uvs, int threads, const CancelToken& cancel = CancelToken::never());
    size_t num_prepared_points() const { return prepared_.size(); }
    void bake_prepared(int iteration, int threads, float* rows_out, float* look_out,
                       const CancelToken& cancel = CancelToken::never()) const;

    // Filled by the Python binding after render_appearance (GIL held).
    RenderStats last_render;
    // Wall time of setup's phases: surfel sampling, BVH, kd-trees + triangle
    // lookup, splat kernel, per-surfel measures, the renders' corner normals;
    // sample_ahead: the wall time of the surfels sampled ahead, when they
    // were used (then `sample` is only the time taken to adopt them); ahead:
    // the wall time of the rest of a setup made ahead (SetupSnapshot::
    // make_ahead), when it was taken whole.
    struct SetupSeconds {
        double sample = 0, geometry = 0, surfels = 0, splat = 0, measures = 0, normals = 0, sample_ahead = 0,
               ahead = 0;
    };
    const SetupSeconds& setup_seconds() const { return setup_seconds_; }
    // What the setup took from a SetupSnapshot: nothing, the surfels only
    // (another binding), or the surfels, the lookup and the splat kernel.
    enum class FromSnapshot { Nothing, Surfels, Setup };
    FromSnapshot from_snapshot() const { return from_snapshot_; }
    // Whether what it took from its SetupSnapshot was made ahead (make_ahead:
    // made in this process, not read from the setup cache).
    bool setup_made_ahead() const { return setup_made_ahead_; }
    // The setup as SetupSnapshot bytes (throws Error once the shape changed:
    // the snapshot is of the setup, before any shape step).  It may be taken
    // on another thread while the simulation traces and updates (gammac
    // keeps it for the setup cache behind the loop): what it reads only
    // reconfigure and shape change, and those wait for it (setup_lock_).
    std::vector<uint8_t> setup_snapshot() const;
    // setup_snapshot's bytes written to the file descriptor `fd` as they are
    // made (SetupSnapshot::write_fd); their CRC-32.
    uint32_t write_setup_snapshot(int fd) const;
    // setup_snapshot's size, without making it (an upper bound).
    size_t setup_snapshot_bytes() const;

    // Index of the surfel nearest to p (any surface).
    uint32_t nearest_surfel(const float p[3]) const;
    // Index of the surfel of `surface` nearest to p (any surfel if the
    // surface has no triangles, hence no surfels, or is out of range).
    uint32_t nearest_surfel_of(int surface, const float p[3]) const;

    // The parts (read-only views for tests).
    const SceneIndex& scene_index() const { return *index_; }
    const SceneFrame& frame() const { return frame_; }
    const SurfelState& state() const { return state_; }

private:
    RenderScene render_scene(const CancelToken& cancel = CancelToken::never()) const {
        return RenderScene{*index_, frame_, state_, kernels_, textures_, mesh_, corner_normals(), base_, cancel};
    }

    Mesh mesh_;
    Config cfg_;
    SceneFrame frame_;
    KernelTable kernels_;
    std::vector<SourceRt> sources_;
    SurfelState state_;
    std::unique_ptr<SceneIndex> index_;
    std::unique_ptr<Tracer> tracer_;
    ShapeStep shape_{cfg_};
    std::vector<Texture> textures_;
    std::vector<uint8_t> shading_flat_;   // per triangle of mesh_, or empty
    std::vector<uint8_t> flat_surface_;   // per surface: all its triangles flat
    BaseColours base_;
    BakePoints prepared_;
    std::vector<int32_t> surface_material_;  // per surface: its one material, else -1
    float crease_deg_ = kDefaultCreaseDeg;
    // The renders' normals: a shape step only marks them stale (most
    // iterations render nothing), the first render or bake recomputes them.
    mutable std::shared_ptr<const std::vector<float>> corner_normals_ =
        std::make_shared<const std::vector<float>>();
    mutable bool corner_normals_stale_ = false;
    mutable std::mutex corner_normals_mutex_;
    // Held shared by setup_snapshot, exclusively by reconfigure and shape.
    mutable std::shared_mutex setup_lock_;
    void update_corner_normals();
    void refresh_corner_normals() const;  // with corner_normals_mutex_ held
    SetupSeconds setup_seconds_;
    FromSnapshot from_snapshot_ = FromSnapshot::Nothing;
    bool setup_made_ahead_ = false;
};

}  // namespace gammart
