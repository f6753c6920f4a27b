// nanobind module gamma._runtime
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

#include "gamma/config.h"
#include "gamma/error.h"
#include "gamma/gmath.h"
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

namespace {

template <typename T>
nb::ndarray<nb::numpy, T> to_numpy(std::vector<T> data, std::initializer_list<size_t> shape) {
    auto* heap = new std::vector<T>(std::move(data));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(heap->data(), shape.size(), shape.begin(), owner);
}

nb::object numpy_asarray(nb::handle obj, const char* dtype) {
    nb::module_ np = nb::module_::import_("numpy");
    return np.attr("ascontiguousarray")(obj, "dtype"_a = dtype);
}

using F32 = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;
using I32 = nb::ndarray<const int32_t, nb::c_contig, nb::device::cpu>;

F32 as_f32(nb::handle obj) { return nb::cast<F32>(numpy_asarray(obj, "float32")); }
I32 as_i32(nb::handle obj) { return nb::cast<I32>(numpy_asarray(obj, "int32")); }

}  // namespace

namespace {
nb::dict geometry_dict(const gammart::MeshMeasures& g) {
    nb::dict d;
    d["volume"] = g.closed ? nb::cast(g.volume) : nb::none();
    d["area"] = g.area;
    d["triangles"] = g.triangles;
    d["min_angle_deg"] = g.min_angle_deg;
    d["min_free_angle_deg"] = g.min_free_angle_deg;
    d["closed"] = g.closed;
    return d;
}

nb::list nonfinite_list(const std::vector<gammart::NonFinite>& items) {
    nb::list out;
    for (const auto& nf : items)
        out.append(nb::make_tuple(nf.event, nf.ton_type, nf.surface, nf.statement, nf.count));
    return out;
}

// TraceStats as the dict trace() returns, and back (merge_chunks receives
// the dicts of chunks traced elsewhere).
nb::dict trace_stats_dict(const gammart::TraceStats& st) {
    nb::dict d;
    d["emitted"] = st.emitted;
    d["settled"] = st.settled;
    d["escaped"] = st.escaped;
    d["missed"] = st.missed;
    d["capped"] = st.capped;
    d["interactions"] = st.interactions;
    d["rays"] = st.rays;
    d["flow_steps"] = st.flow_steps;
    d["bounces"] = st.bounces;
    d["drips"] = st.drips;
    d["segments"] = st.segments;
    d["silent"] = st.silent;
    d["trace_seconds"] = st.trace_seconds;
    d["log_records_peak"] = st.log_records_peak;
    d["nonfinite"] = nonfinite_list(st.nonfinite);
    nb::list mass;
    for (const gammart::MassBooks& b : st.mass) {
        nb::dict m;
        m["removed"] = b.removed;
        m["deposited"] = b.deposited;
        m["escaped"] = b.escaped;
        m["in_flight"] = b.in_flight;
        m["emitted"] = b.emitted;
        m["created"] = b.created;
        m["dropped"] = b.dropped;
        mass.append(m);
    }
    d["mass"] = mass;
    return d;
}

gammart::TraceStats trace_stats_from(nb::handle obj) {
    nb::dict d = nb::cast<nb::dict>(obj);
    gammart::TraceStats st;
    st.emitted = nb::cast<int64_t>(d["emitted"]);
    st.settled = nb::cast<int64_t>(d["settled"]);
    st.escaped = nb::cast<int64_t>(d["escaped"]);
    st.missed = nb::cast<int64_t>(d["missed"]);
    st.capped = nb::cast<int64_t>(d["capped"]);
    st.interactions = nb::cast<int64_t>(d["interactions"]);
    st.rays = nb::cast<int64_t>(d["rays"]);
    st.flow_steps = nb::cast<int64_t>(d["flow_steps"]);
    st.bounces = nb::cast<int64_t>(d["bounces"]);
    st.drips = nb::cast<int64_t>(d["drips"]);
    st.segments = nb::cast<int64_t>(d["segments"]);
    st.silent = d.contains("silent") ? nb::cast<int64_t>(d["silent"]) : 0;
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
        b.removed = nb::cast<double>(m["removed"]);
        b.deposited = nb::cast<double>(m["deposited"]);
        b.escaped = nb::cast<double>(m["escaped"]);
        b.in_flight = nb::cast<double>(m["in_flight"]);
        b.emitted = nb::cast<double>(m["emitted"]);
        b.created = nb::cast<double>(m["created"]);
        b.dropped = nb::cast<double>(m["dropped"]);
        st.mass.push_back(b);
    }
    return st;
}

// Chunks as trace_chunks gives them to Python, back into logs.
std::vector<gammart::ChunkLog> chunk_logs_from(nb::list chunks) {
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
}  // namespace

NB_MODULE(_runtime, m) {
    m.doc() = "gamma weathering runtime (gamma-ton tracing)";
    m.attr("ABI_VERSION") = GAMMA_ABI_VERSION;
    m.attr("CHUNK_SIZE") = gammart::kChunkSize;
    m.attr("RUNTIME_VERSION") = GAMMA_RUNTIME_VERSION;
    m.attr("EMBREE_VERSION") = RTC_VERSION_STRING;
    m.attr("PARABOLA_EPSILON_FRACTION") = gammart::kParabolaEpsilonFraction;
    m.attr("MAX_FLIGHT_SEGMENTS") = gammart::kMaxFlightSegments;
    // The project's own math (gmath.h), by C symbol: the addresses the JIT
    // binds the kernels' calls to and the reference interpreter calls.
    nb::dict math;
    math["gamma_sinf"] = uintptr_t(&gamma_sinf);
    math["gamma_cosf"] = uintptr_t(&gamma_cosf);
    math["gamma_tanf"] = uintptr_t(&gamma_tanf);
    math["gamma_atan2f"] = uintptr_t(&gamma_atan2f);
    math["gamma_expf"] = uintptr_t(&gamma_expf);
    math["gamma_logf"] = uintptr_t(&gamma_logf);
    math["gamma_powf"] = uintptr_t(&gamma_powf);
    m.attr("MATH_FUNCTIONS") = math;

    // gammart::Error (bad input or config) -> ValueError with its one-line
    // message.  Anything else is internal; std::runtime_error reaches Python
    // as RuntimeError through nanobind's default translation ("internal
    // error: ..." messages, one line).
    nb::register_exception_translator([](const std::exception_ptr& p, void*) {
        try {
            std::rethrow_exception(p);
        } catch (const Error& e) {
            PyErr_SetString(PyExc_ValueError, e.what());
        }
    });

    m.def(
        "parabola_landing",
        [](std::array<float, 3> p0, std::array<float, 3> d, float D, std::array<float, 3> down, float floor_height) {
            std::array<float, 3> traced{}, analytic{};
            gammart::parabola_landing(p0, d, D, down, floor_height, traced, analytic);
            return nb::make_tuple(nb::make_tuple(traced[0], traced[1], traced[2]),
                                 nb::make_tuple(analytic[0], analytic[1], analytic[2]));
        },
        "p0"_a, "d"_a, "D"_a, "down"_a, "floor_height"_a,
        "Landing on the plane dot(x, up) = floor_height: (piecewise-linear as traced, analytic).");

    m.def(
        "rasterise_uv",
        [](nb::handle corner_uvs, int size, int row0, int row1, int tile) {
            using F64 = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
            F64 uv = nb::cast<F64>(numpy_asarray(corner_uvs, "float64"));
            if (uv.ndim() != 3 || uv.shape(1) != 3 || uv.shape(2) != 2)
                throw Error("rasterise_uv: corner uvs (m, 3, 2) expected");
            gammart::UvRaster r;
            {
                nb::gil_scoped_release nogil;
                r = gammart::rasterise_uv(uv.data(), uv.shape(0), size, row0, row1, tile);
            }
            const size_t k = r.tris.size();
            return nb::make_tuple(to_numpy(std::move(r.texels), {k}), to_numpy(std::move(r.tris), {k}),
                                  to_numpy(std::move(r.bary), {k, 3}));
        },
        "corner_uvs"_a, "size"_a, "row0"_a, "row1"_a, "tile"_a = 1,
        "The texels of rows [row0, row1) covered by triangles in UV space: (texel int64[k], triangle "
        "int32[k], barycentrics float64[k, 3]), tile by tile; see gamma/uv_raster.h.");

    m.def(
        "dilate_charts",
        [](nb::ndarray<float, nb::ndim<3>, nb::c_contig, nb::device::cpu> image, nb::handle charts, int passes,
           int threads) {
            I32 c = as_i32(charts);
            const size_t rows = image.shape(0), cols = image.shape(1);
            if (c.ndim() != 2 || c.shape(0) != rows || c.shape(1) != cols)
                throw Error("dilate_charts: charts (rows, columns) of the image's size expected");
            std::vector<int32_t> label(c.data(), c.data() + rows * cols);
            {
                nb::gil_scoped_release nogil;
                gammart::dilate_charts(image.data(), label.data(), rows, cols, image.shape(2), passes, threads);
            }
        },
        "image"_a, "charts"_a, "passes"_a, "threads"_a,
        "Fills the gutters of a float32[rows, columns, C] image in place, `passes` rings deep, each texel "
        "from the neighbours of one chart (charts: int32[rows, columns], -1 empty); atlas.py's dilate, "
        "see gamma/uv_raster.h.");

    m.def(
        "fill_charts",
        [](nb::handle values, nb::handle texels, size_t rows, size_t cols, nb::handle texel_chart, int passes,
           int threads) {
            using I64 = nb::ndarray<const int64_t, nb::c_contig, nb::device::cpu>;
            F32 v = as_f32(values);
            I64 t = nb::cast<I64>(numpy_asarray(texels, "int64"));
            I32 c = as_i32(texel_chart);
            const size_t k = t.ndim() == 1 ? t.shape(0) : 0, n = rows * cols;
            const size_t C = v.ndim() == 2 ? v.shape(1) : 1;
            if (t.ndim() != 1 || (v.ndim() != 1 && v.ndim() != 2) || v.shape(0) != k || c.ndim() != 1 ||
                c.shape(0) != k)
                throw Error("fill_charts: values (k,) or (k, C), texels (k,) and their charts (k,) expected");
            std::vector<float> image(n * C, 0.0f);
            std::vector<int32_t> label(n, -1);
            for (size_t i = 0; i < k; ++i) {
                const int64_t at = t.data()[i];
                if (at < 0 || size_t(at) >= n) throw Error("fill_charts: a texel outside the image");
                std::copy(v.data() + i * C, v.data() + (i + 1) * C, image.begin() + long(size_t(at) * C));
                label[size_t(at)] = c.data()[i];
            }
            {
                nb::gil_scoped_release nogil;
                gammart::dilate_charts(image.data(), label.data(), rows, cols, C, passes, threads);
            }
            return to_numpy(std::move(image), {rows, cols, C});
        },
        "values"_a, "texels"_a, "rows"_a, "columns"_a, "texel_chart"_a, "passes"_a, "threads"_a,
        "A float32[rows, columns, C] image with `values` at the flat `texels` (0 elsewhere), its gutters "
        "filled by dilate_charts from each texel's chart (texel_chart, >= 0).");

    m.def(
        "encode_pngs",
        [](nb::handle pictures, int level, int threads) {
            using U8 = nb::ndarray<const uint8_t, nb::ndim<3>, nb::c_contig, nb::device::cpu>;
            std::vector<U8> arrays;       // held while the GIL is released
            std::vector<gammart::RgbPicture> rgb;
            for (nb::handle item : pictures) {
                U8 a;
                if (!nb::try_cast(item, a) || a.shape(2) != 3)
                    throw Error("encode_pngs: each picture must be a C-contiguous uint8[height, width, 3] array");
                rgb.push_back({a.data(), int(std::min<size_t>(a.shape(1), INT32_MAX)),
                               int(std::min<size_t>(a.shape(0), INT32_MAX))});
                arrays.push_back(std::move(a));
            }
            std::vector<std::vector<uint8_t>> encoded;
            {
                nb::gil_scoped_release nogil;
                encoded = gammart::encode_pngs_rgb(rgb, level, threads);
            }
            nb::list out;
            for (const auto& png : encoded) out.append(nb::bytes(reinterpret_cast<const char*>(png.data()), png.size()));
            return out;
        },
        "pictures"_a, "level"_a, "threads"_a,
        "The PNG files (bytes) of uint8[height, width, 3] pictures, as Pillow's save(format='PNG', "
        "compress_level=level) writes them (gamma/png_encode.h), encoded `threads` at a time without the GIL.");

    nb::class_<gammart::Mesh>(m, "Mesh")
        .def_static(
            "load",
            [](const std::string& path) {
                // pure C++ (no Python object): gammac reads the mesh on a thread while it starts up
                nb::gil_scoped_release nogil;
                return gammart::Mesh::load(path);
            },
            "path"_a)
        .def_static(
            "from_arrays",
            [](nb::handle verts, nb::handle tris, nb::handle uvs) {
                F32 v = as_f32(verts);
                I32 t = as_i32(tris);
                if (v.ndim() != 2 || v.shape(1) != 3) throw Error("from_arrays: vertices must have shape (n, 3)");
                if (t.ndim() != 2 || t.shape(1) != 3) throw Error("from_arrays: triangles must have shape (m, 3)");
                if (uvs.is_none()) return gammart::Mesh::from_arrays(v.data(), v.shape(0), t.data(), t.shape(0));
                F32 uv = as_f32(uvs);
                if (uv.ndim() != 3 || uv.shape(0) != t.shape(0) || uv.shape(1) != 3 || uv.shape(2) != 2)
                    throw Error("from_arrays: uvs must have shape (" + std::to_string(t.shape(0)) + ", 3, 2)");
                return gammart::Mesh::from_arrays(v.data(), v.shape(0), t.data(), t.shape(0), "<arrays>",
                                                  uv.data());
            },
            "vertices"_a, "triangles"_a, "uvs"_a.none() = nb::none())
        .def_prop_ro("num_vertices", &gammart::Mesh::num_vertices)
        .def_prop_ro("num_triangles", &gammart::Mesh::num_triangles)
        .def_prop_ro("degenerate_dropped", [](const gammart::Mesh& me) { return me.degenerate_dropped; })
        .def_prop_ro("name", [](const gammart::Mesh& me) { return me.name; })
        .def_prop_ro("bounds",
                     [](const gammart::Mesh& me) {
                         return nb::make_tuple(nb::make_tuple(me.lo[0], me.lo[1], me.lo[2]),
                                               nb::make_tuple(me.hi[0], me.hi[1], me.hi[2]));
                     })
        .def("vertices", [](const gammart::Mesh& me) { return to_numpy<float>(me.vertices, {me.num_vertices(), 3}); })
        .def(
            "fingerprint",
            [](const gammart::Mesh& me) {
                nb::gil_scoped_release nogil;
                return gammart::mesh_fingerprint(me);
            },
            "CRC-32s of the vertices, triangles and bounds with their counts: the setup cache's name for the "
            "mesh (no numpy needed).")
        .def_prop_ro("has_uvs", &gammart::Mesh::has_uvs)
        .def("triangle_uvs",
             [](const gammart::Mesh& me) {
                 const size_t m = me.num_triangles();
                 return to_numpy<float>(me.has_uvs() ? me.uvs : std::vector<float>(6 * m, 0.0f), {m, 3, 2});
             },
             "Texture coordinates per kept triangle corner, float32[m, 3, 2] (zeros without UVs).")
        .def("part_names", [](const gammart::Mesh& me) { return me.part_names; })
        .def("triangle_labels",
             [](const gammart::Mesh& me) {
                 const size_t m = me.num_triangles();
                 auto col = [&](const std::vector<int32_t>& v) {
                     return to_numpy<int32_t>(v.size() == m ? v : std::vector<int32_t>(m, -1), {m});
                 };
                 return nb::make_tuple(col(me.object_id), col(me.group_id), col(me.material_id));
             })
        .def("triangles",
             [](const gammart::Mesh& me) { return to_numpy<int32_t>(me.triangles, {me.num_triangles(), 3}); });

    nb::class_<gammart::Config>(m, "Config")
        .def(nb::init<>())
        .def_rw("surfels", &gammart::Config::surfels)
        .def_rw("seed", &gammart::Config::seed)
        .def_rw("threads", &gammart::Config::threads)
        .def_rw("max_interactions", &gammart::Config::max_interactions)
        .def_rw("trace_batch_chunks", &gammart::Config::trace_batch_chunks)
        .def_rw("row_width", &gammart::Config::row_width)
        .def_rw("surface_rows", &gammart::Config::surface_rows)
        .def_prop_rw(
            "code_owner",
            [](const gammart::Config& c) -> nb::object {
                return c.code_owner ? *static_cast<const nb::object*>(c.code_owner.get()) : nb::none();
            },
            [](gammart::Config& c, nb::object owner) {
                // The last reference may go from a thread without the GIL (a
                // reconfigure or destructor under gil_scoped_release): take it.
                c.code_owner = std::shared_ptr<const void>(new nb::object(std::move(owner)), [](const void* p) {
                    nb::gil_scoped_acquire gil;
                    delete static_cast<const nb::object*>(p);
                });
            },
            "The object that owns the kernels' machine code (e.g. the JIT); kept alive with the config.")
        .def_prop_rw(
            "triangle_surface",
            [](const gammart::Config& c) -> nb::object {
                return nb::cast(to_numpy<int32_t>(c.triangle_surface, {c.triangle_surface.size()}),
                                nb::rv_policy::move);
            },
            [](gammart::Config& c, nb::handle obj) {
                if (obj.is_none()) { c.triangle_surface.clear(); return; }
                I32 a = as_i32(obj);
                if (a.ndim() != 1) throw Error("config: triangle_surface must be one-dimensional");
                c.triangle_surface.assign(a.data(), a.data() + a.shape(0));
            },
            nb::for_setter(nb::arg("value").none()))
        .def_prop_rw(
            "down", [](const gammart::Config& c) { return c.down; },
            [](gammart::Config& c, std::array<float, 3> d) { c.down = d; })
        .def("add_ton_type", &gammart::Config::add_ton_type, "ks"_a, "kp"_a, "kf"_a, "initial_carry"_a,
             "bounce_distance"_a, "flow_step"_a, "drip_angle_deg"_a = 10.0f)
        .def(
            "add_source",
            [](gammart::Config& c, std::string kind, int ton_type, int64_t count, std::array<float, 3> position,
               std::array<float, 3> direction, float angle_deg, float falloff, std::array<float, 2> size,
               float radius, std::string emission, int first_iteration, int last_iteration, float strength,
               int surface, bool along_normal, uint64_t weight_kernel) {
                gammart::Source s;
                s.kind = std::move(kind);
                s.ton_type = ton_type;
                s.count = count;
                s.position = position;
                s.direction = direction;
                s.angle_deg = angle_deg;
                s.falloff = falloff;
                s.size = size;
                s.radius = radius;
                s.emission = std::move(emission);
                s.first_iteration = first_iteration;
                s.last_iteration = last_iteration;
                s.strength = strength;
                s.surface = surface;
                s.along_normal = along_normal;
                s.weight_kernel = weight_kernel;
                return c.add_source(std::move(s));
            },
            "kind"_a, "ton_type"_a, "count"_a, "position"_a = std::array<float, 3>{0, 0, 0},
            "direction"_a = std::array<float, 3>{0, -1, 0}, "angle_deg"_a = 0.0f, "falloff"_a = 0.0f,
            "size"_a = std::array<float, 2>{0, 0}, "radius"_a = 0.0f, "emission"_a = "parallel",
            "first_iteration"_a = 1, "last_iteration"_a = 0, "strength"_a = 0.0f, "surface"_a = -1,
            "along_normal"_a = false, "weight_kernel"_a = uint64_t(0))
        .def("set_transport", &gammart::Config::set_transport, "event"_a, "ton_type"_a, "surface"_a, "address"_a,
             "writes_surface"_a)
        .def("set_update", &gammart::Config::set_update, "surface"_a, "address"_a)
        .def("set_appearance", &gammart::Config::set_appearance, "surface"_a, "address"_a, "displaces"_a = false)
        .def("add_shape_rate", &gammart::Config::add_shape_rate, "surface"_a, "column"_a, "metres_per_unit"_a,
             "The surface's shape follows row column `column` (SPEC §19).")
        .def("add_mass_property", &gammart::Config::add_mass_property, "columns"_a, "carry"_a,
             "Account pick-up of a property: its row column per surface and carry index per ton type (-1: none).")
        .def_rw("measure_accessibility", &gammart::Config::measure_accessibility)
        .def_rw("measure_curvature", &gammart::Config::measure_curvature)
        .def_rw("measure_uv", &gammart::Config::measure_uv)
        .def_rw("retile_edge_factor", &gammart::Config::retile_edge_factor)
        .def_rw("retile_iterations", &gammart::Config::retile_iterations)
        .def_rw("max_step_factor", &gammart::Config::max_step_factor)
        .def_rw("displacement_rings", &gammart::Config::displacement_rings)
        .def_prop_ro("num_ton_types", [](const gammart::Config& c) { return c.ton_types.size(); })
        .def_prop_ro("num_sources", [](const gammart::Config& c) { return c.sources.size(); });

    nb::class_<gammart::FalseColourView>(m, "FalseColourView",
                                         "Simulation.false_colour_view's rays, cast once for many pictures.")
        .def_prop_ro("width", [](const gammart::FalseColourView& v) { return v.width; })
        .def_prop_ro("surfels", [](const gammart::FalseColourView& v) { return v.surfels; },
                     "The surfels of the simulation it was cast on (values have one each).")
        .def_prop_ro("height", [](const gammart::FalseColourView& v) { return v.height; })
        .def("shade",
             [](const gammart::FalseColourView& v) {
                 return to_numpy<float>(v.shade, {size_t(v.height), size_t(v.width)});
             },
             "float32[height, width]: Simulation.render's shade (a copy).")
        .def("values",
             [](const gammart::FalseColourView& v, nb::handle values) {
                 F32 a = as_f32(values);
                 if (a.ndim() != 1 || a.shape(0) != v.surfels)
                     throw Error("values: values must have shape (" + std::to_string(v.surfels) + ",)");
                 const size_t npx = size_t(v.width) * size_t(v.height);
                 std::vector<float> out(npx);
                 {
                     nb::gil_scoped_release nogil;
                     for (size_t px = 0; px < npx; ++px) out[px] = v.value(px, a.data());
                 }
                 return to_numpy<float>(std::move(out), {size_t(v.height), size_t(v.width)});
             },
             "values"_a, "float32[height, width]: Simulation.render's value image of `values` (one per surfel "
             "of the simulation the view was made from).")
        .def("picture",
             [](const gammart::FalseColourView& v, nb::handle values, double vmin, double vmax, nb::handle background,
                int threads) {
                 F32 a = as_f32(values);
                 if (a.ndim() != 1 || a.shape(0) != v.surfels)
                     throw Error("picture: values must have shape (" + std::to_string(v.surfels) + ",)");
                 using U8 = nb::ndarray<const uint8_t, nb::c_contig, nb::device::cpu>;
                 U8 bg = nb::cast<U8>(numpy_asarray(background, "uint8"));
                 const size_t npx = size_t(v.width) * size_t(v.height);
                 if (bg.size() != 3 * npx) throw Error("picture: background must have shape (height, width, 3)");
                 if (!(vmax > vmin)) throw Error("picture: vmax must be greater than vmin");
                 std::vector<uint8_t> out(3 * npx);
                 {
                     nb::gil_scoped_release nogil;
                     v.picture(a.data(), vmin, vmax, bg.data(), threads, out.data());
                 }
                 return to_numpy<uint8_t>(std::move(out), {size_t(v.height), size_t(v.width), 3});
             },
             "values"_a, "vmin"_a, "vmax"_a, "background"_a, "threads"_a,
             "uint8[height, width, 3]: the false-colour picture of `values` on the scale vmin..vmax, as "
             "gamma.driver.outputs.FalseColourCanvas.picture makes it from Simulation.render's images.")
        .def(
            "to_bytes",
            [](const gammart::FalseColourView& v) {
                std::vector<uint8_t> out;
                {
                    nb::gil_scoped_release nogil;
                    out = v.to_bytes();
                }
                const size_t n = out.size();
                return to_numpy<uint8_t>(std::move(out), {n});
            },
            "uint8[n]: the view as bytes (gamma/renderer.h), for the cache of views.")
        .def_static(
            "from_bytes",
            [](nb::bytes data) {
                const auto* p = reinterpret_cast<const uint8_t*>(data.c_str());
                const size_t n = data.size();
                nb::gil_scoped_release nogil;
                return gammart::FalseColourView::from_bytes(p, n);
            },
            "data"_a, "The view to_bytes gave (ValueError for bytes that are not a whole view).");

    nb::class_<gammart::SurfelSample>(m, "SurfelSample",
                                      "Surfels sampled ahead of a Simulation's setup (gamma/surfel_state.h).")
        .def(
            "__init__",
            [](gammart::SurfelSample* self, const gammart::Mesh& mesh, int64_t surfels, uint64_t seed, int threads) {
                // pure C++: gammac samples on a thread while it starts up
                nb::gil_scoped_release nogil;
                new (self) gammart::SurfelSample(mesh, surfels > 0 ? size_t(surfels) : 0, seed, threads);
            },
            "mesh"_a, "surfels"_a, "seed"_a, "threads"_a, nb::keep_alive<1, 2>(),
            "Samples `surfels` surfels on `mesh` with `seed` in an arena of `threads` threads; never raises for a "
            "bad count or mesh (then `ok` is false and a Simulation samples again, reporting the error).  A "
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

    nb::class_<gammart::Simulation>(m, "Simulation")
        .def(
            "__init__",
            [](gammart::Simulation* self, const gammart::Mesh& mesh, const gammart::Config& cfg,
               gammart::SurfelSample* ahead, gammart::SetupSnapshot* snapshot) {
                nb::gil_scoped_release nogil;
                new (self) gammart::Simulation(mesh, cfg, ahead, snapshot);
            },
            "mesh"_a, "config"_a, "ahead"_a.none() = nb::none(), "snapshot"_a.none() = nb::none(),
            "`ahead`: a SurfelSample, whose surfels are taken when they are those this setup would sample "
            "(same mesh, count and seed); `snapshot`: a SetupSnapshot, taken when it is this setup's (same "
            "mesh, count, seed and binding of triangles to surfaces).  The simulation is the same either way.")
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
             })
        .def("trace",
             [](gammart::Simulation& s, int iteration) {
                 gammart::TraceStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.trace(iteration);
                 }
                 return trace_stats_dict(st);
             },
             "iteration"_a,
             "Trace one iteration; a dict of counters, timings and `nonfinite`: a list of "
             "(event, ton_type, surface, statement, count).")
        .def("num_chunks", &gammart::Simulation::num_chunks, "iteration"_a,
             "How many chunks (CHUNK_SIZE gamma-tons each) iteration `iteration` traces.")
        .def(
            "trace_chunks",
            [](const gammart::Simulation& s, int iteration, int64_t first, int64_t last) {
                std::vector<gammart::ChunkLog> logs;
                {
                    nb::gil_scoped_release nogil;
                    logs = s.trace_chunks(iteration, first, last);
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
            "iteration"_a, "first"_a, "last"_a,
            "Trace chunks [first, last) against the current rows, leaving them unchanged; per chunk "
            "(surfel indices uint32[n], property deltas float32[n, P], counters as trace() gives).")
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
            "largest batch).")
        .def("update",
             [](gammart::Simulation& s, int iteration) {
                 gammart::UpdateStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.update(iteration);
                 }
                 nb::dict d;
                 d["seconds"] = st.seconds;
                 d["nonfinite"] = nonfinite_list(st.nonfinite);
                 return d;
             },
             "iteration"_a,
             "Run the update rules; a dict {seconds, nonfinite} (event -1 in nonfinite).")
        .def("cancel", &gammart::Simulation::cancel,
             "Stop the trace running now (or the next) before its next chunk: it raises ValueError "
             "('cancelled: ...') and leaves the rows as they were.  Callable from any thread.")
        .def("clear_cancel", &gammart::Simulation::clear_cancel,
             "Withdraw a cancel() no trace took (it came after the trace's last chunk), so that the next "
             "trace runs.")
        .def("reconfigure", &gammart::Simulation::reconfigure, "config"_a,
             "Take another effect's config for the next run, keeping surfels, scene index and splat kernel "
             "(same surfel count, seed and surface binding, shape never changed; else an error, nothing "
             "changed).")
        .def("shape",
             [](gammart::Simulation& s, int iteration) {
                 gammart::ShapeStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.shape(iteration);
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
             "iteration"_a, "The shape step after the update pass (SPEC §19): a dict of counters, timings and geometry.")
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
                     "The triangle lookup: candidate entries, triangles on the kd-tree, bytes.")
        .def("record_rays",
             [](gammart::Simulation& s, int iteration) {
                 std::vector<gammart::RecordedRay> rays;
                 {
                     nb::gil_scoped_release nogil;
                     rays = s.record_rays(iteration);
                 }
                 static_assert(sizeof(gammart::RecordedRay) == 8 * sizeof(float));
                 std::vector<float> flat(rays.size() * 8);
                 if (!rays.empty()) std::memcpy(flat.data(), rays.data(), flat.size() * sizeof(float));
                 return to_numpy<float>(std::move(flat), {rays.size(), 8});
             },
             "iteration"_a,
             "The rays trace(iteration) casts, in order: an (n, 8) float32 array of origin, direction, "
             "tnear, tfar.  The rows are left unchanged.")
        .def("cast_rays",
             [](const gammart::Simulation& s, nb::handle rays_obj, int threads) {
                 F32 a = as_f32(rays_obj);
                 if (a.ndim() != 2 || a.shape(1) != 8) throw Error("cast_rays: expected an (n, 8) array");
                 std::vector<gammart::RecordedRay> rays(a.shape(0));
                 if (!rays.empty()) std::memcpy(rays.data(), a.data(), rays.size() * sizeof(gammart::RecordedRay));
                 gammart::RaycastStats st;
                 {
                     nb::gil_scoped_release nogil;
                     st = s.cast_rays(rays, threads);
                 }
                 nb::dict d;
                 d["rays"] = st.rays;
                 d["hits"] = st.hits;
                 d["seconds"] = st.seconds;
                 return d;
             },
             "rays"_a, "threads"_a,
             "Embree alone on rays from record_rays (converted before the clock starts): {rays, hits, seconds}.")
        .def("render",
             [](const gammart::Simulation& s, nb::handle values, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads) {
                 F32 v = as_f32(values);
                 if (v.ndim() != 1 || v.shape(0) != s.num_surfels())
                     throw Error("render: values must have shape (" + std::to_string(s.num_surfels()) + ",)");
                 if (width < 1 || height < 1) throw Error("render: width and height must be positive");
                 if (!(fov_deg > 0 && fov_deg < 180)) throw Error("render: fov_deg must be in (0, 180)");
                 const size_t npx = size_t(width) * size_t(height);
                 std::vector<float> val(npx), shade(npx);
                 {
                     nb::gil_scoped_release nogil;
                     s.render(v.data(), eye, target, up, fov_deg, width, height, threads, val.data(), shade.data());
                 }
                 return nb::make_tuple(to_numpy<float>(std::move(val), {size_t(height), size_t(width)}),
                                       to_numpy<float>(std::move(shade), {size_t(height), size_t(width)}));
             },
             "values"_a, "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a)
        .def("false_colour_view",
             [](const gammart::Simulation& s, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads) {
                 if (width < 1 || height < 1) throw Error("false_colour_view: width and height must be positive");
                 if (!(fov_deg > 0 && fov_deg < 180)) throw Error("false_colour_view: fov_deg must be in (0, 180)");
                 nb::gil_scoped_release nogil;
                 return s.false_colour_view(eye, target, up, fov_deg, width, height, threads);
             },
             "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a,
             "The rays of render() cast once (a FalseColourView): the pictures of many values without "
             "casting again (the geometry must not change in between).")
        .def("set_textures",
             [](gammart::Simulation& s, nb::handle list) {
                 std::vector<gammart::Texture> tex;
                 size_t i = 0;
                 for (nb::handle item : list) {
                     F32 a = as_f32(item);
                     if (a.ndim() != 3 || a.shape(2) != 3)
                         throw Error("set_textures: texture " + std::to_string(i) + " must have shape (H, W, 3)");
                     gammart::Texture t;
                     t.height = int(a.shape(0));
                     t.width = int(a.shape(1));
                     t.rgb.assign(a.data(), a.data() + a.shape(0) * a.shape(1) * 3);
                     tex.push_back(std::move(t));
                     ++i;
                 }
                 s.set_textures(std::move(tex));
             },
             "textures"_a, "Textures (float32[H, W, 3], row 0 = top) for the appearance kernels, in order.")
        .def("set_shading",
             [](gammart::Simulation& s, nb::handle flat, float crease_deg) {
                 std::vector<uint8_t> flags;
                 if (!flat.is_none()) {
                     I32 f = as_i32(flat);
                     if (f.ndim() != 1) throw Error("set_shading: flat must be one flag per triangle");
                     flags.reserve(f.shape(0));
                     for (size_t t = 0; t < f.shape(0); ++t) flags.push_back(f.data()[t] != 0 ? 1 : 0);
                 }
                 s.set_shading(std::move(flags), crease_deg);
             },
             "flat"_a.none(), "crease_deg"_a,
             "Render shading: flat (int32[m] flags, or None) triangles and every triangle when crease_deg <= 0 "
             "render flat; the others smooth, with edges sharper than crease_deg kept sharp.")
        .def("set_base_colours",
             [](gammart::Simulation& s, nb::handle triangle_material, nb::handle factors, nb::handle textures,
                nb::handle images) {
                 gammart::BaseColours b;
                 I32 tm = as_i32(triangle_material), tx = as_i32(textures);
                 F32 f = as_f32(factors);
                 // factors: r, g, b[, roughness, metallic]; textures: base colour[, metallic-roughness]
                 const size_t fw = f.ndim() == 2 ? f.shape(1) : 0, tw = tx.ndim() == 2 ? tx.shape(1) : 1;
                 if (tm.ndim() != 1 || tx.ndim() < 1 || tx.ndim() > 2 || (fw != 3 && fw != 5) ||
                     f.shape(0) != tx.shape(0) || (tw != 1 && tw != 2))
                     throw Error("set_base_colours: triangle_material int32[m], factors float32[k, 3 or 5], "
                                 "textures int32[k] or int32[k, 2] are needed");
                 b.triangle_material.assign(tm.data(), tm.data() + tm.shape(0));
                 for (size_t k = 0; k < f.shape(0); ++k) {
                     const float* row = f.data() + fw * k;
                     b.factor.push_back({row[0], row[1], row[2]});
                     if (fw == 5) b.rough_metal.push_back({row[3], row[4]});
                     b.texture.push_back(tx.data()[tw * k]);
                     if (tw == 2) b.rough_metal_texture.push_back(tx.data()[tw * k + 1]);
                 }
                 size_t i = 0;
                 for (nb::handle item : images) {
                     F32 a = as_f32(item);
                     if (a.ndim() != 3 || a.shape(2) != 3)
                         throw Error("set_base_colours: image " + std::to_string(i) + " must have shape (H, W, 3)");
                     gammart::Texture t;
                     t.height = int(a.shape(0));
                     t.width = int(a.shape(1));
                     t.rgb.assign(a.data(), a.data() + a.shape(0) * a.shape(1) * 3);
                     b.images.push_back(std::move(t));
                     ++i;
                 }
                 s.set_base_colours(std::move(b));
             },
             "triangle_material"_a, "factors"_a, "textures"_a, "images"_a,
             "The scene's own materials: a material per triangle (-1: none); per material an RGB factor "
             "(then roughness and metallic factors) and an image index (-1: none) of the base colour (then "
             "of the metallic-roughness texture); images float32[H, W, 3] (row 0 = top).")
        .def("corner_normals",
             [](const gammart::Simulation& s) {
                 std::vector<float> c = s.corner_normals();
                 const size_t m = c.size() / 9;
                 return to_numpy<float>(std::move(c), {m, 3, 3});
             },
             "The renders' shading normals: float32[m, 3 corners, 3].")
        .def_prop_ro("num_textures", [](const gammart::Simulation& s) { return s.textures().size(); })
        .def("bake_points",
             [](const gammart::Simulation& s, nb::handle positions, nb::handle normals, nb::handle triangles,
                nb::handle uvs, int iteration, int threads) {
                 F32 p = as_f32(positions), n = as_f32(normals), uv = as_f32(uvs);
                 I32 t = as_i32(triangles);
                 const size_t k = t.ndim() == 1 ? t.shape(0) : 0;
                 if (t.ndim() != 1 || p.ndim() != 2 || p.shape(0) != k || p.shape(1) != 3 || n.ndim() != 2 ||
                     n.shape(0) != k || n.shape(1) != 3 || uv.ndim() != 2 || uv.shape(0) != k || uv.shape(1) != 2)
                     throw Error("bake_points: positions (k,3), normals (k,3), triangles (k,) and uvs (k,2) expected");
                 const size_t W = size_t(s.row_width());
                 std::vector<float> rows(k * W), look(k * GAMMA_LOOK_WIDTH);
                 {
                     nb::gil_scoped_release nogil;
                     s.bake_points(k, p.data(), n.data(), t.data(), uv.data(), iteration, threads, rows.data(),
                                   look.data());
                 }
                 return nb::make_tuple(to_numpy(std::move(rows), {k, W}),
                                       to_numpy(std::move(look), {k, size_t(GAMMA_LOOK_WIDTH)}));
             },
             "positions"_a, "normals"_a, "triangles"_a, "uvs"_a, "iteration"_a, "threads"_a,
             "At surface points: (smoothed rows float32[k, W], looks float32[k, L]: colour, roughness, "
             "metallic, displacement, occlusion as abi.APPEARANCE_OUTPUTS).")
        .def("bake_texels",
             [](const gammart::Simulation& s, nb::handle positions, nb::handle normals, nb::handle corners,
                nb::handle lookup_uvs, nb::handle scene_triangle, nb::handle tris, nb::handle bary, int iteration,
                int threads) {
                 using F64 = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
                 F32 p = as_f32(positions), n = as_f32(normals);
                 I32 c = as_i32(corners), st = as_i32(scene_triangle), t = as_i32(tris);
                 F64 b = nb::cast<F64>(numpy_asarray(bary, "float64"));
                 const size_t nv = p.ndim() == 2 ? p.shape(0) : 0, m = st.ndim() == 1 ? st.shape(0) : 0;
                 const size_t k = t.ndim() == 1 ? t.shape(0) : 0;
                 if (p.ndim() != 2 || p.shape(1) != 3 || n.ndim() != 2 || n.shape(0) != nv || n.shape(1) != 3 ||
                     c.ndim() != 2 || c.shape(0) != m || c.shape(1) != 3 || t.ndim() != 1 || b.ndim() != 2 ||
                     b.shape(0) != k || b.shape(1) != 3)
                     throw Error("bake_texels: positions (n,3), normals (n,3), corners (m,3), scene_triangle (m,), "
                                 "tris (k,) and bary (k,3) expected");
                 for (size_t i = 0; i < 3 * m; ++i)
                     if (c.data()[i] < 0 || size_t(c.data()[i]) >= nv)
                         throw Error("bake_texels: a corner names no vertex");
                 F32 uv;
                 gammart::TexelLayout layout;
                 if (!lookup_uvs.is_none()) {
                     uv = as_f32(lookup_uvs);
                     if (uv.ndim() != 3 || uv.shape(0) != m || uv.shape(1) != 3 || uv.shape(2) != 2)
                         throw Error("bake_texels: lookup uvs (m,3,2) expected");
                     layout.lookup_uvs = uv.data();
                 }
                 layout.positions = p.data();
                 layout.normals = n.data();
                 layout.corners = c.data();
                 layout.scene_triangle = st.data();
                 layout.faces = m;
                 const size_t W = size_t(s.row_width());
                 std::vector<float> rows(k * W), look(k * GAMMA_LOOK_WIDTH);
                 {
                     nb::gil_scoped_release nogil;
                     s.bake_texels(layout, k, t.data(), b.data(), iteration, threads, rows.data(), look.data());
                 }
                 return nb::make_tuple(to_numpy(std::move(rows), {k, W}),
                                       to_numpy(std::move(look), {k, size_t(GAMMA_LOOK_WIDTH)}));
             },
             "positions"_a, "normals"_a, "corners"_a, "lookup_uvs"_a.none(), "scene_triangle"_a, "tris"_a, "bary"_a,
             "iteration"_a, "threads"_a,
             "bake_points() at texels of a texture layout, each given by its layout triangle and barycentrics.")
        .def("prepare_points",
             [](gammart::Simulation& s, nb::handle positions, nb::handle normals, nb::handle triangles,
                nb::handle uvs, int threads) {
                 F32 p = as_f32(positions), n = as_f32(normals), uv = as_f32(uvs);
                 I32 t = as_i32(triangles);
                 const size_t k = t.ndim() == 1 ? t.shape(0) : 0;
                 if (t.ndim() != 1 || p.ndim() != 2 || p.shape(0) != k || p.shape(1) != 3 || n.ndim() != 2 ||
                     n.shape(0) != k || n.shape(1) != 3 || uv.ndim() != 2 || uv.shape(0) != k || uv.shape(1) != 2)
                     throw Error("prepare_points: positions (k,3), normals (k,3), triangles (k), uvs (k,2)");
                 nb::gil_scoped_release nogil;
                 s.prepare_points(k, p.data(), n.data(), t.data(), uv.data(), threads);
             },
             "positions"_a, "normals"_a, "triangles"_a, "uvs"_a, "threads"_a,
             "Points bake_prepared() bakes again and again (their smoothing neighbours found once).")
        .def_prop_ro("num_prepared_points", &gammart::Simulation::num_prepared_points)
        .def("bake_prepared",
             [](const gammart::Simulation& s, int iteration, int threads) {
                 const size_t k = s.num_prepared_points(), W = size_t(s.row_width());
                 std::vector<float> rows(k * W), look(k * GAMMA_LOOK_WIDTH);
                 {
                     nb::gil_scoped_release nogil;
                     s.bake_prepared(iteration, threads, rows.data(), look.data());
                 }
                 return nb::make_tuple(to_numpy(std::move(rows), {k, W}),
                                       to_numpy(std::move(look), {k, size_t(GAMMA_LOOK_WIDTH)}));
             },
             "iteration"_a, "threads"_a, "bake_points() of the prepared points: (rows float32[k, W], looks float32[k, L]).")
        .def("render_appearance",
             [](gammart::Simulation& s, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads, int samples,
                std::array<float, 3> sun_direction, int ao_samples, int iteration) {
                 gammart::AppearanceParams p;
                 p.eye = eye;
                 p.target = target;
                 p.up = up;
                 p.fov_deg = fov_deg;
                 p.width = width;
                 p.height = height;
                 p.threads = threads;
                 p.samples = samples;
                 p.sun = sun_direction;
                 p.ao_samples = ao_samples;
                 p.iteration = iteration;
                 if (width < 1 || height < 1) throw Error("render_appearance: width and height must be positive");
                 std::vector<float> img;
                 gammart::RenderStats st;
                 {
                     nb::gil_scoped_release nogil;
                     img.resize(size_t(width) * size_t(height) * 4);
                     st = s.render_appearance(p, img.data());
                 }
                 s.last_render = std::move(st);
                 return to_numpy<float>(std::move(img), {size_t(height), size_t(width), 4});
             },
             "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a, "samples"_a = 4,
             "sun_direction"_a = std::array<float, 3>{0, 0, 0}, "ao_samples"_a = 8, "iteration"_a = 0,
             "Appearance preview: float32[H, W, 4] (display RGB in [0, 1], alpha = geometry coverage).")
        .def("last_render_stats",
             [](const gammart::Simulation& s) {
                 nb::dict d;
                 d["seconds"] = s.last_render.seconds;
                 d["rays"] = s.last_render.rays;
                 d["kernel_calls"] = s.last_render.kernel_calls;
                 nb::list nf;
                 for (const auto& x : s.last_render.nonfinite) nf.append(nb::make_tuple(x.surface, x.statement, x.count));
                 d["nonfinite"] = nf;
                 return d;
             },
             "Counters of the last render_appearance: {seconds, rays, kernel_calls, nonfinite: "
             "[(surface, statement, count)]}.");
}
