// What the binding files (bind_*.cpp) share: the headers, numpy conversions
// and TraceStats / chunk logs to and from Python.
#pragma once
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/unique_ptr.h>
#include <nanobind/stl/vector.h>

#include <embree3/rtcore.h>

#include <algorithm>
#include <cstdint>
#include <cstring>

#include "gamma/cancel.h"
#include "gamma/config.h"
#include "gamma/error.h"
#include "gamma/mesh.h"
#include "gamma/png_encode.h"
#include "gamma/sampling.h"
#include "gamma/setup_cache.h"
#include "gamma/remesh.h"
#include "gamma/shape_step.h"
#include "gamma/simulation.h"
#include "gamma/uv_raster.h"
#include "gamma_abi.h"

namespace nb = nanobind;
using namespace nb::literals;
using gammart::Error;

namespace gamma_bind {

// A pass's `cancel` argument: a CancelToken, or None for one never
// cancelled.  (Python's argument tuple holds the token for the whole call.)
inline const gammart::CancelToken& token_or_never(const gammart::CancelToken* cancel) {
    return cancel != nullptr ? *cancel : gammart::CancelToken::never();
}


template <typename T>
nb::ndarray<nb::numpy, T> to_numpy(std::vector<T> data, std::initializer_list<size_t> shape) {
    auto* heap = new std::vector<T>(std::move(data));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(heap->data(), shape.size(), shape.begin(), owner);
}

inline nb::object numpy_asarray(nb::handle obj, const char* dtype) {
    nb::module_ np = nb::module_::import_("numpy");
    return np.attr("ascontiguousarray")(obj, "dtype"_a = dtype);
}

using F32 = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;
using I32 = nb::ndarray<const int32_t, nb::c_contig, nb::device::cpu>;

inline F32 as_f32(nb::handle obj) { return nb::cast<F32>(numpy_asarray(obj, "float32")); }
inline I32 as_i32(nb::handle obj) { return nb::cast<I32>(numpy_asarray(obj, "int32")); }


inline nb::dict geometry_dict(const gammart::MeshMeasures& g) {
    nb::dict d;
    d["volume"] = g.closed ? nb::cast(g.volume) : nb::none();
    d["area"] = g.area;
    d["triangles"] = g.triangles;
    d["min_angle_deg"] = g.min_angle_deg;
    d["min_free_angle_deg"] = g.min_free_angle_deg;
    d["closed"] = g.closed;
    return d;
}

inline nb::list nonfinite_list(const std::vector<gammart::NonFinite>& items) {
    nb::list out;
    for (const auto& nf : items)
        out.append(nb::make_tuple(nf.event, nf.ton_type, nf.surface, nf.statement, nf.count));
    return out;
}

// TraceStats as the dict trace() returns, and back (merge_chunks receives
// the dicts of chunks traced elsewhere).
inline nb::dict trace_stats_dict(const gammart::TraceStats& st) {
    nb::dict d;
#define GAMMA_COUNTER_TO(name) d[#name] = st.name;
    GAMMA_TRACE_COUNTERS(GAMMA_COUNTER_TO)
#undef GAMMA_COUNTER_TO
    d["trace_seconds"] = st.trace_seconds;
    d["log_records_peak"] = st.log_records_peak;
    d["nonfinite"] = nonfinite_list(st.nonfinite);
    nb::list mass;
    for (const gammart::MassBooks& b : st.mass) {
        nb::dict m;
#define GAMMA_BOOK_TO(name) m[#name] = b.name;
        GAMMA_MASS_BOOKS(GAMMA_BOOK_TO)
#undef GAMMA_BOOK_TO
        mass.append(m);
    }
    d["mass"] = mass;
    return d;
}

inline gammart::TraceStats trace_stats_from(nb::handle obj) {
    nb::dict d = nb::cast<nb::dict>(obj);
    gammart::TraceStats st;
#define GAMMA_COUNTER_FROM(name) st.name = nb::cast<int64_t>(d[#name]);
    GAMMA_TRACE_COUNTERS(GAMMA_COUNTER_FROM)
#undef GAMMA_COUNTER_FROM
    for (nb::handle item : nb::cast<nb::list>(d["nonfinite"])) {
        auto t = nb::cast<nb::tuple>(item);
        gammart::count_nonfinite(st.nonfinite, nb::cast<int>(t[0]), nb::cast<int>(t[1]), nb::cast<int>(t[2]),
                                 nb::cast<int>(t[3]), nb::cast<int64_t>(t[4]));
    }
    // Doubles pass through Python floats unchanged, so the merged books are
    // the ones trace() forms.
    for (nb::handle item : nb::cast<nb::list>(d["mass"])) {
        nb::dict m = nb::cast<nb::dict>(item);
        gammart::MassBooks b;
#define GAMMA_BOOK_FROM(name) b.name = nb::cast<double>(m[#name]);
        GAMMA_MASS_BOOKS(GAMMA_BOOK_FROM)
#undef GAMMA_BOOK_FROM
        st.mass.push_back(b);
    }
    return st;
}

// Chunks as trace_chunks gives them to Python, back into logs.
inline std::vector<gammart::ChunkLog> chunk_logs_from(nb::list chunks) {
    using U32 = nb::ndarray<const uint32_t, nb::c_contig, nb::device::cpu>;
    std::vector<gammart::ChunkLog> logs(chunks.size());
    nb::module_ np = nb::module_::import_("numpy");
    for (size_t i = 0; i < logs.size(); ++i) {
        auto t = nb::cast<nb::tuple>(chunks[i]);
        if (t.size() != 3) throw Error("merge_chunks: each chunk is (surfels, deltas, counters)");
        U32 sv = nb::cast<U32>(np.attr("ascontiguousarray")(t[0], "dtype"_a = "uint32"));
        F32 dv = as_f32(t[1]);
        logs[i].surfel.assign(sv.data(), sv.data() + sv.size());
        logs[i].delta.assign(dv.data(), dv.data() + dv.size());
        logs[i].st = trace_stats_from(t[2]);
    }
    return logs;
}

}  // namespace gamma_bind

namespace gamma_bind {
void bind_mesh(nb::module_& m);
void bind_config(nb::module_& m);
void bind_setup(nb::module_& m);
void bind_false_colour_view(nb::module_& m);
void bind_simulation_state(nb::class_<gammart::Simulation>& simulation);
void bind_simulation_trace(nb::class_<gammart::Simulation>& simulation);
void bind_simulation_shape(nb::class_<gammart::Simulation>& simulation);
void bind_simulation_render(nb::class_<gammart::Simulation>& simulation);
void bind_simulation_bake(nb::class_<gammart::Simulation>& simulation);
}  // namespace gamma_bind
