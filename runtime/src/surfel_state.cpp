// Sampling the surfel state (see gamma/surfel_state.h).
#include "gamma/surfel_state.h"

#include <cstring>

namespace gammart {

SurfelState SurfelState::sample(const Mesh& mesh, const std::vector<int32_t>& tri_surface, size_t n, uint64_t seed,
                                const std::vector<std::vector<float>>& surface_rows) {
    SurfelState st;
    st.surf = sample_surfels(mesh, n, seed);
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

}  // namespace gammart
