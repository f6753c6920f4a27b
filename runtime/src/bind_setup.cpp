// gamma._runtime SurfelSample, SetupSnapshot and the setup cache: surfels made ahead or kept.
#include "bind_common.h"

namespace gamma_bind {

void bind_setup(nb::module_& m) {
    nb::class_<gammart::SurfelSample>(m, "SurfelSample",
                                      "Surfels sampled ahead of a Simulation's setup (gamma/surfel_state.h).")
        .def(
            "__init__",
            [](gammart::SurfelSample* self, const gammart::Mesh& mesh, int64_t surfels, uint64_t seed, int threads,
               const gammart::CancelToken* cancel) {
                // pure C++: gammac samples on a thread while it starts up
                nb::gil_scoped_release nogil;
                new (self) gammart::SurfelSample(mesh, surfels > 0 ? size_t(surfels) : 0, seed, threads,
                                                 token_or_never(cancel));
            },
            "mesh"_a, "surfels"_a, "seed"_a, "threads"_a, "cancel"_a.none() = nb::none(), nb::keep_alive<1, 2>(),
            "Samples `surfels` surfels on `mesh` with `seed` in an arena of `threads` threads; never raises for a "
            "bad count or mesh (then `ok` is false and a Simulation samples again, reporting the error), nor once "
            "`cancel` is cancelled (then it stops, and `ok` is false).  A "
            "Simulation that takes the surfels leaves `ok` false.")
        .def_prop_ro("ok", &gammart::SurfelSample::ok)
        .def_prop_ro("seconds", &gammart::SurfelSample::seconds, "Wall time of the sampling.")
        .def(
            "matches",
            [](const gammart::SurfelSample& s, const gammart::Mesh& mesh, int64_t surfels, uint64_t seed) {
                return surfels > 0 && s.matches(mesh, size_t(surfels), seed);
            },
            "mesh"_a, "surfels"_a, "seed"_a, "Whether a Simulation of this mesh, count and seed would use these surfels.");

    nb::class_<gammart::SetupSnapshot>(m, "SetupSnapshot",
                                       "An earlier setup's surfels, lookup and splat kernel "
                                       "(gamma/setup_snapshot.h): Simulation.setup_snapshot's bytes, parsed.")
        .def_prop_ro("surfels", &gammart::SetupSnapshot::surfels)
        .def(
            "matches",
            [](const gammart::SetupSnapshot& s, const gammart::Mesh& mesh, int64_t surfels, uint64_t seed) {
                return surfels > 0 && s.matches_surfels(mesh, size_t(surfels), seed);
            },
            "mesh"_a, "surfels"_a, "seed"_a,
            "Whether a Simulation of this mesh, count and seed would take at least its surfels.")
        .def_prop_ro("taken", &gammart::SetupSnapshot::taken, "Whether a Simulation took it (it is then empty).")
        .def_prop_ro("prepared", &gammart::SetupSnapshot::prepared)
        .def_static(
            "make_ahead",
            [](const gammart::Mesh& mesh, gammart::SurfelSample& sample, int threads) {
                // pure C++: gammac makes it on a thread while it starts up
                nb::gil_scoped_release nogil;
                return gammart::SetupSnapshot::make_ahead(mesh, sample, threads);
            },
            "mesh"_a, "sample"_a, "threads"_a,
            "The setup a Simulation of `mesh` with `sample`'s surfels (moved out) makes when every triangle is "
            "on one surface, made now and prepared (prefetch.py); raises ValueError if the sample holds none.")
        .def_prop_ro("made_ahead", &gammart::SetupSnapshot::made_ahead,
                     "Whether make_ahead made it (not the setup cache).")
        .def_static(
            "load_cached",
            [](const std::string& folder, const gammart::Mesh& mesh, int64_t surfels, uint64_t seed) -> nb::object {
                std::unique_ptr<gammart::SetupSnapshot> snapshot;
                if (surfels > 0) {
                    nb::gil_scoped_release nogil;
                    snapshot = gammart::load_cached_setup(folder, mesh, size_t(surfels), seed);
                }
                return snapshot ? nb::cast(std::move(*snapshot), nb::rv_policy::move) : nb::none();
            },
            "folder"_a, "mesh"_a, "surfels"_a, "seed"_a,
            "The snapshot the setup cache in `folder` keeps for this mesh, count and seed (setup_cache_name), or "
            "None: none kept, a file that cannot be read (left alone), or one damaged, cut short or not a "
            "snapshot of this build (removed).  A file taken is marked recently used.  Never raises.");

    m.attr("RUNTIME_BUILD") = gammart::runtime_build();
    m.def(
        "setup_cache_name",
        [](const gammart::Mesh& mesh, int64_t surfels, uint64_t seed) {
            nb::gil_scoped_release nogil;
            return gammart::setup_cache_name(mesh, surfels > 0 ? size_t(surfels) : 0, seed);
        },
        "mesh"_a, "surfels"_a, "seed"_a,
        "The setup cache's file name for this mesh, count and seed: "
        "setup-{RUNTIME_BUILD}-{mesh.fingerprint()}-{surfels}-{seed}.bin (empty: the build is unknown, no cache).");
    m.def(
        "read_mesh_ahead",
        [](const std::string& path, const std::string& cache_folder, int64_t surfels, uint64_t seed, int threads) {
            gammart::MeshAhead ahead;
            {
                // the whole chain without the GIL: gammac's main thread is importing meanwhile
                nb::gil_scoped_release nogil;
                ahead = gammart::read_mesh_ahead(path, cache_folder, surfels > 0 ? size_t(surfels) : 0, seed,
                                                 threads);
            }
            if (!ahead.mesh) return nb::make_tuple(nb::none(), nb::none(), nb::none());
            const gammart::FileSignature& s = ahead.signature;
            return nb::make_tuple(nb::cast(std::move(*ahead.mesh), nb::rv_policy::move),
                                  nb::make_tuple(s.size, s.mtime_ns, s.inode, s.device),
                                  ahead.setup ? nb::cast(std::move(*ahead.setup), nb::rv_policy::move) : nb::none());
        },
        "path"_a, "cache_folder"_a, "surfels"_a, "seed"_a, "threads"_a,
        "gammac run's read-ahead (gamma/setup_cache.h): (mesh, (size, mtime_ns, inode, device) of the file as "
        "read, the setup cache's SetupSnapshot for it prepared on `threads` threads or None), or (None, None, "
        "None) when the file is not a regular file, cannot be read, or changed meanwhile.  `cache_folder` "
        "empty or `surfels` 0: no setup is looked for.  Never raises.");
}

}  // namespace gamma_bind
