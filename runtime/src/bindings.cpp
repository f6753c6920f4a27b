// nanobind module gamma._runtime: its constants, error translation and free
// functions; the classes are bound part by part in bind_*.cpp.
#include "bind_common.h"
#include "gamma/baker.h"
#include "gamma/gmath.h"

using namespace gamma_bind;

namespace {

// The module's constants, the project's math by address, error translation
// and cancellation.
void bind_constants_and_errors(nb::module_& m) {
    m.attr("ABI_VERSION") = GAMMA_ABI_VERSION;
    m.attr("CHUNK_SIZE") = gammart::kChunkSize;
    m.attr("RUNTIME_VERSION") = GAMMA_RUNTIME_VERSION;
    m.attr("EMBREE_VERSION") = RTC_VERSION_STRING;
    m.attr("PARABOLA_EPSILON_FRACTION") = gammart::kParabolaEpsilonFraction;
    m.attr("MAX_FLIGHT_SEGMENTS") = gammart::kMaxFlightSegments;
    m.attr("LATTICE_STRIDE") = gammart::kLatticeStride;
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
    // A pass whose CancelToken was cancelled (gamma/cancel.h).
    nb::exception<gammart::Cancelled>(m, "Cancelled");
    nb::class_<gammart::CancelToken>(m, "CancelToken",
                                     "Asks the long passes it is handed to (`cancel=`) to stop between chunks of "
                                     "their work: they raise Cancelled.  Never reset: one per run.")
        .def(nb::init<>())
        .def("cancel", &gammart::CancelToken::cancel, "Callable from any thread, the GIL released or not.")
        .def_prop_ro("cancelled", &gammart::CancelToken::cancelled);
}

// Helpers of the texture export (atlas.py, images.py): UV rasterisation,
// gutter dilation and PNG encoding.
void bind_image_helpers(nb::module_& m) {
    m.def(
        "rasterise_uv",
        [](nb::handle corner_uvs, int size, int row0, int row1, int tile, int threads) {
            using F64 = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
            F64 uv = nb::cast<F64>(numpy_asarray(corner_uvs, "float64"));
            if (uv.ndim() != 3 || uv.shape(1) != 3 || uv.shape(2) != 2)
                throw Error("rasterise_uv: corner uvs (m, 3, 2) expected");
            gammart::UvRaster r;
            {
                nb::gil_scoped_release nogil;
                r = gammart::rasterise_uv(uv.data(), uv.shape(0), size, row0, row1, tile, threads);
            }
            const size_t k = r.tris.size();
            return nb::make_tuple(to_numpy(std::move(r.texels), {k}), to_numpy(std::move(r.tris), {k}),
                                  to_numpy(std::move(r.bary), {k, 3}));
        },
        "corner_uvs"_a, "size"_a, "row0"_a, "row1"_a, "tile"_a = 1, "threads"_a = 0,
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
           int threads, bool with_charts) -> nb::object {
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
            if (with_charts)
                return nb::make_tuple(to_numpy(std::move(image), {rows, cols, C}), to_numpy(std::move(label), {rows, cols}));
            return nb::cast(to_numpy(std::move(image), {rows, cols, C}));
        },
        "values"_a, "texels"_a, "rows"_a, "columns"_a, "texel_chart"_a, "passes"_a, "threads"_a,
        "with_charts"_a = false,
        "A float32[rows, columns, C] image with `values` at the flat `texels` (0 elsewhere), its gutters "
        "filled by dilate_charts from each texel's chart (texel_chart, >= 0); with_charts: (the image, "
        "int32[rows, columns]: the chart each texel holds after the filling, -1: none).");

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
}

}  // namespace

NB_MODULE(_runtime, m) {
    m.doc() = "gamma weathering runtime (gamma-ton tracing)";
    bind_constants_and_errors(m);
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
    bind_image_helpers(m);
    bind_mesh(m);
    bind_config(m);
    bind_false_colour_view(m);
    bind_setup(m);
    nb::class_<gammart::Simulation> simulation(m, "Simulation");
    bind_simulation_state(simulation);
    bind_simulation_trace(simulation);
    bind_simulation_shape(simulation);
    bind_simulation_render(simulation);
    bind_simulation_bake(simulation);
}
