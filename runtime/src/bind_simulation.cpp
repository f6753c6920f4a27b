// gamma._runtime.Simulation: set-up, state, tracing, update and shape change.
#include "bind_common.h"

namespace gamma_bind {

void bind_simulation_state(nb::class_<gammart::Simulation>& simulation) {
    simulation
        .def(
            "__init__",
            [](gammart::Simulation* self, const gammart::Mesh& mesh, const gammart::Config& cfg,
               gammart::SurfelSample* ahead, gammart::SetupSnapshot* snapshot, const gammart::CancelToken* cancel) {
                nb::gil_scoped_release nogil;
                new (self) gammart::Simulation(mesh, cfg, ahead, snapshot, token_or_never(cancel));
            },
            "mesh"_a, "config"_a, "ahead"_a.none() = nb::none(), "snapshot"_a.none() = nb::none(), "cancel"_a.none() = nb::none(),
            "`ahead`: a SurfelSample, whose surfels are taken when they are those this setup would sample "
            "(same mesh, count and seed); `snapshot`: a SetupSnapshot, taken when it is this setup's (same "
            "mesh, count, seed and binding of triangles to surfaces).  The simulation is the same either way.  "
            "`cancel`: a CancelToken; once cancelled, the setup stops between its phases (Cancelled).")
        .def_prop_ro(
            "from_snapshot",
            [](const gammart::Simulation& s) {
                using F = gammart::Simulation::FromSnapshot;
                return s.from_snapshot() == F::Setup ? "setup" : s.from_snapshot() == F::Surfels ? "surfels" : "nothing";
            },
            "What the setup took from its SetupSnapshot: \"setup\", \"surfels\" (another binding) or \"nothing\".")
        .def_prop_ro("setup_made_ahead", &gammart::Simulation::setup_made_ahead,
                     "Whether what the setup took from its SetupSnapshot was made ahead (make_ahead), not read "
                     "from the setup cache.")
        .def(
            "write_setup_snapshot",
            [](const gammart::Simulation& s, int fd) {
                nb::gil_scoped_release nogil;
                return s.write_setup_snapshot(fd);
            },
            "fd"_a,
            "setup_snapshot()'s bytes written to the open file descriptor `fd` as they are made, without the "
            "GIL (no copy of the whole setup in memory); their CRC-32 (zlib's).")
        .def(
            "setup_snapshot",
            [](const gammart::Simulation& s) {
                std::vector<uint8_t> bytes;
                {
                    nb::gil_scoped_release nogil;
                    bytes = s.setup_snapshot();
                }
                const size_t n = bytes.size();
                return to_numpy<uint8_t>(std::move(bytes), {n});
            },
            "The setup (surfels, lookup, splat kernel) as SetupSnapshot bytes (a uint8 array).")
        .def_prop_ro("setup_snapshot_bytes", &gammart::Simulation::setup_snapshot_bytes,
                     "setup_snapshot's size, without making it (an upper bound).")
        .def_prop_ro("num_surfels", &gammart::Simulation::num_surfels)
        .def_prop_ro("row_width", &gammart::Simulation::row_width)
        .def("surfel_positions",
             [](const gammart::Simulation& s) { return to_numpy<float>(s.surfels().position, {s.num_surfels(), 3}); })
        .def("surfel_normals",
             [](const gammart::Simulation& s) { return to_numpy<float>(s.surfels().normal, {s.num_surfels(), 3}); })
        .def("surfel_measures",
             [](const gammart::Simulation& s) {
                 // (accessibility, accessibility on the back, curvature, uv): empty if not computed
                 const gammart::SurfelMeasures& m = s.measures();
                 return nb::make_tuple(to_numpy<float>(m.accessibility, {m.accessibility.size()}),
                                       to_numpy<float>(m.accessibility_back, {m.accessibility_back.size()}),
                                       to_numpy<float>(m.curvature, {m.curvature.size()}),
                                       to_numpy<float>(m.uv, {m.uv.size() / 2, 2}));
             })
        .def("surfel_triangles",
             [](const gammart::Simulation& s) { return to_numpy<int32_t>(s.surfels().triangle, {s.num_surfels()}); })
        .def("surfel_surfaces",
             [](const gammart::Simulation& s) { return to_numpy<int32_t>(s.surfel_surfaces(), {s.num_surfels()}); })
        .def("rows",
             [](const gammart::Simulation& s) {
                 return to_numpy<float>(s.rows(), {s.num_surfels(), size_t(s.row_width())});
             })
        .def("set_rows",
             [](gammart::Simulation& s, nb::handle obj) {
                 F32 a = as_f32(obj);
                 if (a.ndim() != 2 || a.shape(0) != s.num_surfels() || a.shape(1) != size_t(s.row_width()))
                     throw Error("set_rows: expected shape (" + std::to_string(s.num_surfels()) + ", " +
                                 std::to_string(s.row_width()) + ")");
                 s.set_rows(a.data());
             });
}

void bind_simulation_trace(nb::class_<gammart::Simulation>& simulation) {
    simulation
        .def("trace",
             [](gammart::Simulation& s, int iteration, const gammart::CancelToken* cancel) {
                 gammart::TraceStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.trace(iteration, token_or_never(cancel));
                 }
                 return trace_stats_dict(st);
             },
             "iteration"_a, "cancel"_a.none() = nb::none(),
             "Trace one iteration; a dict of counters, timings and `nonfinite`: a list of "
             "(event, ton_type, surface, statement, count).  Once `cancel` (a CancelToken) is cancelled, "
             "the trace stops before its next chunk of gamma-tons, raises Cancelled and leaves the rows "
             "as they were.")
        .def("num_chunks", &gammart::Simulation::num_chunks, "iteration"_a,
             "How many chunks (CHUNK_SIZE gamma-tons each) iteration `iteration` traces.")
        .def(
            "trace_chunks",
            [](const gammart::Simulation& s, int iteration, int64_t first, int64_t last, bool one_at_a_time) {
                std::vector<gammart::ChunkLog> logs;
                {
                    nb::gil_scoped_release nogil;
                    logs = s.trace_chunks(iteration, first, last, one_at_a_time);
                }
                const size_t P = size_t(s.row_width() - GAMMA_ROW_HEADER);
                nb::list out;
                for (gammart::ChunkLog& log : logs) {
                    const size_t n = log.surfel.size();
                    out.append(nb::make_tuple(to_numpy<uint32_t>(std::move(log.surfel), {n}),
                                              to_numpy<float>(std::move(log.delta), {n, P}),
                                              trace_stats_dict(log.st)));
                }
                return out;
            },
            "iteration"_a, "first"_a, "last"_a, "one_at_a_time"_a = false,
            "Trace chunks [first, last) against the current rows, leaving them unchanged; per chunk "
            "(surfel indices uint32[n], property deltas float32[n, P], counters as trace() gives).  "
            "one_at_a_time: with the plain tracer that the batched one is checked against (the same logs).")
        .def(
            "merge_chunks",
            [](gammart::Simulation& s, int iteration, nb::list chunks) {
                std::vector<gammart::ChunkLog> logs = chunk_logs_from(chunks);
                gammart::TraceStats st;
                {
                    nb::gil_scoped_release nogil;
                    st = s.merge_chunks(iteration, logs);
                }
                return trace_stats_dict(st);
            },
            "iteration"_a, "chunks"_a,
            "Add the deltas of all chunks of an iteration (in chunk order) to the rows, as trace() "
            "does; the summed counters (trace_seconds: the merge's).")
        .def("merge_begin", &gammart::Simulation::merge_begin, "iteration"_a,
             "Begin merge_chunks in batches: merge_add(chunks) with the next chunks of the iteration in "
             "chunk order, as many times as needed, then merge_end().  Holds only the n x P sums, never "
             "the chunks; the result is merge_chunks's, bit for bit.")
        .def(
            "merge_add",
            [](gammart::Simulation& s, nb::list chunks) {
                std::vector<gammart::ChunkLog> logs = chunk_logs_from(chunks);
                nb::gil_scoped_release nogil;
                s.merge_add(logs);
            },
            "chunks"_a,
            "Sum the next chunks of the merge begun by merge_begin (each as trace_chunks gives it); the "
            "rows change only at merge_end.  A batch that does not fit raises ValueError and abandons "
            "the merge.")
        .def(
            "merge_end",
            [](gammart::Simulation& s) {
                gammart::TraceStats st;
                {
                    nb::gil_scoped_release nogil;
                    st = s.merge_end();
                }
                return trace_stats_dict(st);
            },
            "Add the sums of every chunk of the iteration to the rows (spread by the splat kernel) and "
            "return the summed counters, as merge_chunks does (log_records_peak: the records of the "
            "largest batch).");
}

void bind_simulation_shape(nb::class_<gammart::Simulation>& simulation) {
    simulation
        .def("update",
             [](gammart::Simulation& s, int iteration, const gammart::CancelToken* cancel) {
                 gammart::UpdateStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.update(iteration, token_or_never(cancel));
                 }
                 nb::dict d;
                 d["seconds"] = st.seconds;
                 d["nonfinite"] = nonfinite_list(st.nonfinite);
                 return d;
             },
             "iteration"_a, "cancel"_a.none() = nb::none(),
             "Run the update rules; a dict {seconds, nonfinite} (event -1 in nonfinite).  Raises Cancelled "
             "without starting once `cancel` is cancelled.")
        .def("reconfigure", &gammart::Simulation::reconfigure, "config"_a,
             "Take another effect's config for the next run, keeping surfels, scene index and splat kernel "
             "(same surfel count, seed and surface binding, shape never changed; else an error, nothing "
             "changed).")
        .def("shape",
             [](gammart::Simulation& s, int iteration, const gammart::CancelToken* cancel) {
                 gammart::ShapeStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.shape(iteration, token_or_never(cancel));
                 }
                 nb::dict d;
                 d["changed"] = st.changed;
                 d["retiled"] = st.retiled;
                 d["retiled_triangles"] = st.retiled_triangles;
                 d["slivers_left"] = st.slivers_left;
                 d["moved_vertices"] = st.moved_vertices;
                 d["clamped_vertices"] = st.clamped_vertices;
                 d["inversion_limited"] = st.inversion_limited;
                 d["clearance_limited"] = st.clearance_limited;
                 d["nonfinite_surfels"] = st.nonfinite_surfels;
                 d["max_displacement"] = st.max_displacement;
                 d["displace_seconds"] = st.displace_seconds;
                 d["retile_seconds"] = st.retile_seconds;
                 d["resample_seconds"] = st.resample_seconds;
                 d["rebuild_seconds"] = st.rebuild_seconds;
                 d["geometry"] = geometry_dict(st.geometry);
                 return d;
             },
             "iteration"_a, "cancel"_a.none() = nb::none(),
             "The shape step after the update pass (SPEC §19): a dict of counters, timings and geometry.  "
             "Raises Cancelled without starting once `cancel` is cancelled.")
        .def("geometry",
             [](const gammart::Simulation& s) {
                 return geometry_dict(gammart::measure(s.mesh(), s.scene_index().tri_surface()));
             },
             "{volume (None if open), area, triangles, min_angle_deg, min_free_angle_deg, closed} of the current "
             "mesh (min_free_angle_deg: at corners not between two boundary or seam edges).")
        .def("mesh_arrays",
             [](const gammart::Simulation& s) {
                 const gammart::Mesh& m = s.mesh();
                 return nb::make_tuple(to_numpy<float>(m.vertices, {m.num_vertices(), 3}),
                                       to_numpy<int32_t>(m.triangles, {m.num_triangles(), 3}));
             },
             "The current (possibly deformed and re-tiled) mesh: (vertices float32[n,3], triangles int32[m,3]).")
        .def("triangle_surfaces",
             [](const gammart::Simulation& s) {
                 const std::vector<int32_t>& t = s.scene_index().tri_surface();
                 return to_numpy<int32_t>(t, {t.size()});
             })
        .def_prop_ro("shape_rebuilds", &gammart::Simulation::shape_rebuilds)
        .def("raw_raycast",
             [](gammart::Simulation& s, int64_t n_rays, int threads, uint64_t seed) {
                 gammart::RaycastStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.raw_raycast(n_rays, threads, seed);
                 }
                 nb::dict d;
                 d["rays"] = st.rays;
                 d["hits"] = st.hits;
                 d["seconds"] = st.seconds;
                 return d;
             },
             "n_rays"_a, "threads"_a, "seed"_a)
        .def_prop_ro("setup_seconds",
                     [](const gammart::Simulation& s) {
                         nb::dict d;
                         d["sample"] = s.setup_seconds().sample;
                         d["geometry"] = s.setup_seconds().geometry;
                         d["surfels"] = s.setup_seconds().surfels;
                         d["splat"] = s.setup_seconds().splat;
                         d["measures"] = s.setup_seconds().measures;
                         d["normals"] = s.setup_seconds().normals;
                         if (s.setup_seconds().sample_ahead > 0) d["sample_ahead"] = s.setup_seconds().sample_ahead;
                         if (s.setup_seconds().ahead > 0) d["ahead"] = s.setup_seconds().ahead;
                         return d;
                     },
                     "Wall time of setup's phases: surfel sampling, BVH, kd-trees + triangle lookup, "
                     "splat kernel, per-surfel measures, the renders' corner normals; sample_ahead: the "
                     "SurfelSample's sampling, when the setup used it; ahead: the rest of a setup made ahead "
                     "(SetupSnapshot.make_ahead), when it was taken whole.")
        .def_prop_ro("lookup_stats",
                     [](const gammart::Simulation& s) {
                         const gammart::SceneIndex& ix = s.scene_index();
                         nb::dict d;
                         d["candidates"] = ix.lookup_candidates();
                         d["fallback_triangles"] = ix.lookup_fallback_triangles();
                         d["grid_triangles"] = ix.lookup_grid_triangles();
                         d["bytes"] = ix.lookup_bytes();
                         return d;
                     },
                     "The triangle lookup: candidate entries, triangles on the kd-tree, bytes.");
}

}  // namespace gamma_bind
