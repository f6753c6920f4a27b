// Sampling the surfel state (see gamma/surfel_state.h).
#include "gamma/surfel_state.h"

#include <chrono>
#include <cstring>
#include <exception>

#ifdef __GLIBC__
#include <malloc.h>
#endif

#include "gamma/threads.h"

namespace gammart {

SurfelState SurfelState::sample(const Mesh& mesh, const std::vector<int32_t>& tri_surface, size_t n, uint64_t seed,
                                const std::vector<std::vector<float>>& surface_rows, const CancelToken& cancel) {
    return of(sample_surfels(mesh, n, seed, cancel), tri_surface, surface_rows);
}

SurfelState SurfelState::of(SurfelSet surf, const std::vector<int32_t>& tri_surface,
                            const std::vector<std::vector<float>>& surface_rows) {
    SurfelState st;
    st.surf = std::move(surf);
    const size_t count = st.surf.triangle.size();
    const int W = surface_rows.empty() ? 0 : int(surface_rows[0].size());
    st.width = W;
    st.surface.resize(count);
    st.rows.resize(count * size_t(W));
    for (size_t i = 0; i < count; ++i) {
        const int s = tri_surface[size_t(st.surf.triangle[i])];
        st.surface[i] = s;
        std::memcpy(&st.rows[i * size_t(W)], surface_rows[size_t(s)].data(), sizeof(float) * size_t(W));
    }
    return st;
}

SurfelSample::SurfelSample(const Mesh& mesh, size_t n, uint64_t seed, int threads, const CancelToken& cancel)
    : mesh_(&mesh), n_(n), seed_(seed) {
    const auto t0 = std::chrono::steady_clock::now();
    try {
        run_with_threads(threads, [&] { surf_ = sample_surfels(mesh, n, seed, cancel); });
        ok_ = true;
    } catch (const std::exception&) {  // reported by the Simulation's own sampling (or cancelled: not needed)
        surf_ = SurfelSet{};
    }
#ifdef __GLIBC__
    // The sampling's temporaries were freed into this thread's malloc arena,
    // which the setup (on another thread, later) does not allocate from:
    // kept, they raised the peak of a 1.6M-surfel `gammac run` on the bunny
    // from 1,907 MiB (sampled in the setup) to 2,022-2,069 MiB; returned to
    // the system, it is 1,854-1,865 MiB.
    malloc_trim(0);
#endif
    seconds_ = seconds_since(t0);
}

bool SurfelSample::matches(const Mesh& mesh, size_t n, uint64_t seed) const {
    // everything of the mesh sample_surfels reads
    return ok_ && n == n_ && seed == seed_ &&
           (&mesh == mesh_ || (mesh.lo == mesh_->lo && mesh.hi == mesh_->hi && mesh.vertices == mesh_->vertices &&
                               mesh.triangles == mesh_->triangles));
}

SurfelSet SurfelSample::take() {
    ok_ = false;
    return std::move(surf_);
}

}  // namespace gammart
