// gamma._runtime.Config: what a simulation is set up with (kernels, sources, surfaces).
#include "bind_common.h"

namespace gamma_bind {

void bind_config(nb::module_& m) {
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
}

}  // namespace gamma_bind
