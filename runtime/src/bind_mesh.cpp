// gamma._runtime.Mesh: meshes read from files or arrays.
#include "bind_common.h"

namespace gamma_bind {

void bind_mesh(nb::module_& m) {
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
}

}  // namespace gamma_bind
