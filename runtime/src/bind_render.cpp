// gamma._runtime: pictures and bakes of a Simulation, and FalseColourView.
#include "bind_common.h"

namespace gamma_bind {

void bind_false_colour_view(nb::module_& m) {
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
}

void bind_simulation_render(nb::class_<gammart::Simulation>& simulation) {
    simulation
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
                std::array<float, 3> up, float fov_deg, int width, int height, int threads, const gammart::CancelToken* cancel) {
                 F32 v = as_f32(values);
                 if (v.ndim() != 1 || v.shape(0) != s.num_surfels())
                     throw Error("render: values must have shape (" + std::to_string(s.num_surfels()) + ",)");
                 if (width < 1 || height < 1) throw Error("render: width and height must be positive");
                 if (!(fov_deg > 0 && fov_deg < 180)) throw Error("render: fov_deg must be in (0, 180)");
                 const size_t npx = size_t(width) * size_t(height);
                 std::vector<float> val(npx), shade(npx);
                 {
                     nb::gil_scoped_release nogil;
                     s.render(v.data(), eye, target, up, fov_deg, width, height, threads, val.data(), shade.data(),
                              token_or_never(cancel));
                 }
                 return nb::make_tuple(to_numpy<float>(std::move(val), {size_t(height), size_t(width)}),
                                       to_numpy<float>(std::move(shade), {size_t(height), size_t(width)}));
             },
             "values"_a, "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a, "cancel"_a.none() = nb::none())
        .def("false_colour_view",
             [](const gammart::Simulation& s, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads, const gammart::CancelToken* cancel) {
                 if (width < 1 || height < 1) throw Error("false_colour_view: width and height must be positive");
                 if (!(fov_deg > 0 && fov_deg < 180)) throw Error("false_colour_view: fov_deg must be in (0, 180)");
                 nb::gil_scoped_release nogil;
                 return s.false_colour_view(eye, target, up, fov_deg, width, height, threads, token_or_never(cancel));
             },
             "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a,
             "cancel"_a.none() = nb::none(),
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
                 std::vector<float> c = *s.corner_normals();
                 const size_t m = c.size() / 9;
                 return to_numpy<float>(std::move(c), {m, 3, 3});
             },
             "The renders' shading normals: float32[m, 3 corners, 3].")
        .def_prop_ro("num_textures", [](const gammart::Simulation& s) { return s.textures().size(); });
}

namespace {

// Simulation.bake_texels: the arguments checked, the texture channels baked without the GIL.
nb::ndarray<nb::numpy, float> bake_texels(const gammart::Simulation& s, nb::handle positions, nb::handle normals,
                                          nb::handle corners, nb::handle lookup_uvs, nb::handle scene_triangle,
                                          nb::handle tris, nb::handle bary, nb::handle surface_of_triangle,
                                          nb::handle slots, int iteration, int threads,
                                          const gammart::CancelToken* cancel, nb::handle texels, size_t band_width,
                                          size_t band_rows, size_t first_row) {
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
    gammart::TexelGrid grid;
    nb::ndarray<const int64_t, nb::c_contig, nb::device::cpu> where;
    if (!texels.is_none()) {
        where = nb::cast<nb::ndarray<const int64_t, nb::c_contig, nb::device::cpu>>(
            numpy_asarray(texels, "int64"));
        if (where.ndim() != 1 || where.shape(0) != k || band_width == 0)
            throw Error("bake_texels: texels (k,) and a band width expected");
        grid = {where.data(), band_width, band_rows, first_row};
    }
    I32 surface_of = as_i32(surface_of_triangle), slot = as_i32(slots);
    if (slot.ndim() != 2 || surface_of.ndim() != 1)
        throw Error("bake_texels: slots (surfaces, P) and surface_of_triangle (n,) expected");
    const gammart::ChannelSlots channel_slots{surface_of.data(), surface_of.shape(0), slot.data(),
                                              slot.shape(0), slot.shape(1)};
    std::vector<float> channels(k * (gammart::kTextureChannels + slot.shape(1)));
    {
        nb::gil_scoped_release nogil;
        s.bake_texels(layout, k, t.data(), b.data(), texels.is_none() ? nullptr : &grid, channel_slots,
                      iteration, threads, channels.data(), token_or_never(cancel));
    }
    return to_numpy(std::move(channels), {k, gammart::kTextureChannels + slot.shape(1)});
}

}  // namespace

void bind_simulation_bake(nb::class_<gammart::Simulation>& simulation) {
    simulation
        .def("bake_points",
             [](const gammart::Simulation& s, nb::handle positions, nb::handle normals, nb::handle triangles,
                nb::handle uvs, int iteration, int threads, const gammart::CancelToken* cancel) {
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
                                   look.data(), token_or_never(cancel));
                 }
                 return nb::make_tuple(to_numpy(std::move(rows), {k, W}),
                                       to_numpy(std::move(look), {k, size_t(GAMMA_LOOK_WIDTH)}));
             },
             "positions"_a, "normals"_a, "triangles"_a, "uvs"_a, "iteration"_a, "threads"_a, "cancel"_a.none() = nb::none(),
             "At surface points: (smoothed rows float32[k, W], looks float32[k, L]: colour, roughness, "
             "metallic, displacement, occlusion as abi.APPEARANCE_OUTPUTS).")
        .def("bake_texels",
             &bake_texels,
             "positions"_a, "normals"_a, "corners"_a, "lookup_uvs"_a.none(), "scene_triangle"_a, "tris"_a, "bary"_a,
             "surface_of_triangle"_a, "slots"_a, "iteration"_a, "threads"_a, "cancel"_a.none() = nb::none(),
             "texels"_a.none() = nb::none(), "band_width"_a = 0, "band_rows"_a = 0, "first_row"_a = 0,
             "The texture channels float32[k, 7 + P] (base colour, occlusion, roughness, metallic, "
             "displacement, P properties) at texels of a texture layout, each given by its layout triangle and "
             "barycentrics, smoothed and looked at as bake_points() does; slots (surfaces x P): a property's row "
             "slot per surface (-1: none), surface_of_triangle: per scene triangle.  With texels (row * "
             "band_width + column in a band of band_rows rows starting at first_row of the texture), texels "
             "near enough to the lattice points around them take their interpolated rows (gamma/baker.h).")
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
             [](const gammart::Simulation& s, int iteration, int threads, const gammart::CancelToken* cancel) {
                 const size_t k = s.num_prepared_points(), W = size_t(s.row_width());
                 std::vector<float> rows(k * W), look(k * GAMMA_LOOK_WIDTH);
                 {
                     nb::gil_scoped_release nogil;
                     s.bake_prepared(iteration, threads, rows.data(), look.data(), token_or_never(cancel));
                 }
                 return nb::make_tuple(to_numpy(std::move(rows), {k, W}),
                                       to_numpy(std::move(look), {k, size_t(GAMMA_LOOK_WIDTH)}));
             },
             "iteration"_a, "threads"_a, "cancel"_a.none() = nb::none(), "bake_points() of the prepared points: (rows float32[k, W], looks float32[k, L]).")
        .def("render_appearance",
             [](gammart::Simulation& s, std::array<float, 3> eye, std::array<float, 3> target,
                std::array<float, 3> up, float fov_deg, int width, int height, int threads, int samples,
                std::array<float, 3> sun_direction, int ao_samples, int iteration, const gammart::CancelToken* cancel) {
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
                     st = s.render_appearance(p, img.data(), token_or_never(cancel));
                 }
                 s.last_render = std::move(st);
                 return to_numpy<float>(std::move(img), {size_t(height), size_t(width), 4});
             },
             "eye"_a, "target"_a, "up"_a, "fov_deg"_a, "width"_a, "height"_a, "threads"_a, "samples"_a = 4,
             "sun_direction"_a = std::array<float, 3>{0, 0, 0}, "ao_samples"_a = 8, "iteration"_a = 0, "cancel"_a.none() = nb::none(),
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

}  // namespace gamma_bind
