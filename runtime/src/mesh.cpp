#include "gamma/mesh.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>

#include <cctype>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <filesystem>
#include <mutex>

#include "gamma/error.h"

namespace gammart {

namespace {
using OMesh = OpenMesh::TriMesh_ArrayKernelT<>;

std::string q(const std::string& s) { return "'" + s + "'"; }

void silence_openmesh() {
    static std::once_flag once;
    std::call_once(once, [] {
        omerr().disable();
        omlog().disable();
        omout().disable();
    });
}

Mesh build(std::vector<float> verts, const int32_t* tris, size_t m, const std::string& name) {
    Mesh mesh;
    mesh.name = name;
    const size_t n = verts.size() / 3;
    if (m == 0) throw Error("mesh " + q(name) + " has no triangles");
    for (size_t i = 0; i < verts.size(); ++i)
        if (!std::isfinite(verts[i]))
            throw Error("mesh " + q(name) + ": vertex " + std::to_string(i / 3) +
                        " has a non-finite coordinate");
    for (size_t t = 0; t < m; ++t)
        for (int k = 0; k < 3; ++k) {
            int64_t v = tris[3 * t + k];
            if (v < 0 || size_t(v) >= n)
                throw Error("mesh " + q(name) + ": triangle " + std::to_string(t) +
                            " has vertex index " + std::to_string(v) + " out of range (" +
                            std::to_string(n) + " vertices)");
        }
    // Bounds over vertices used by triangles.
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t t = 0; t < 3 * m; ++t)
        for (int k = 0; k < 3; ++k) {
            double c = verts[3 * size_t(tris[t]) + k];
            lo[k] = std::min(lo[k], c);
            hi[k] = std::max(hi[k], c);
        }
    double diag2 = 0;
    for (int k = 0; k < 3; ++k) diag2 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    const double min_area = 1e-12 * diag2;
    mesh.triangles.reserve(3 * m);
    mesh.original_triangle.reserve(m);
    for (size_t t = 0; t < m; ++t) {
        const float* a = &verts[3 * size_t(tris[3 * t])];
        const float* b = &verts[3 * size_t(tris[3 * t + 1])];
        const float* c = &verts[3 * size_t(tris[3 * t + 2])];
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) { e1[k] = double(b[k]) - a[k]; e2[k] = double(c[k]) - a[k]; }
        double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
               cz = e1[0] * e2[1] - e1[1] * e2[0];
        double area = 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
        if (!(area >= min_area) || area == 0.0) { mesh.degenerate_dropped++; continue; }
        for (int k = 0; k < 3; ++k) mesh.triangles.push_back(tris[3 * t + k]);
        mesh.original_triangle.push_back(int32_t(t));
    }
    mesh.input_triangles = m;
    if (mesh.triangles.empty()) throw Error("mesh " + q(name) + " has only degenerate triangles");
    for (int k = 0; k < 3; ++k) { mesh.lo[k] = float(lo[k]); mesh.hi[k] = float(hi[k]); }
    mesh.vertices = std::move(verts);
    return mesh;
}
// OpenMesh's OBJ reader silently drops vertices it cannot parse as finite
// numbers (nan, inf, 1e999), which would surface as a confusing "no
// triangles" error; scan the 'v' lines ourselves first.
void check_obj_coordinates(const std::string& path) {
    std::string ext = std::filesystem::path(path).extension().string();
    for (auto& ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
    if (ext != ".obj") return;
    std::ifstream in(path);
    std::string line;
    size_t vertex = 0;
    while (std::getline(in, line)) {
        size_t a = line.find_first_not_of(" \t");
        if (a == std::string::npos || line.compare(a, 2, "v ") != 0) {
            if (a == std::string::npos || line.compare(a, 2, "v\t") != 0) continue;
        }
        const char* p = line.c_str() + a + 2;
        for (int k = 0; k < 3; ++k) {
            char* endp = nullptr;
            double c = std::strtod(p, &endp);
            if (endp == p) break;  // malformed: leave it to OpenMesh
            if (!std::isfinite(c) || std::fabs(c) > double(FLT_MAX))
                throw Error("mesh " + q(path) + ": vertex " + std::to_string(vertex) +
                            " has a non-finite coordinate");
            p = endp;
        }
        ++vertex;
    }
}

}  // namespace

float Mesh::diagonal() const {
    float d2 = 0;
    for (int k = 0; k < 3; ++k) d2 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    return std::sqrt(d2);
}

double Mesh::area() const {
    double total = 0;
    for (size_t t = 0; t < num_triangles(); ++t) {
        const float* a = &vertices[3 * size_t(triangles[3 * t])];
        const float* b = &vertices[3 * size_t(triangles[3 * t + 1])];
        const float* c = &vertices[3 * size_t(triangles[3 * t + 2])];
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) { e1[k] = double(b[k]) - a[k]; e2[k] = double(c[k]) - a[k]; }
        double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
               cz = e1[0] * e2[1] - e1[1] * e2[0];
        total += 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
    }
    return total;
}

Mesh Mesh::load(const std::string& path) {
    silence_openmesh();
    std::error_code ec;
    if (!std::filesystem::exists(path, ec))
        throw Error("cannot read mesh " + q(path) + ": file not found");
    if (std::filesystem::is_directory(path, ec))
        throw Error("cannot read mesh " + q(path) + ": is a directory");
    check_obj_coordinates(path);
    OMesh om;
    OpenMesh::IO::Options opt;
    bool ok = false;
    try {
        ok = OpenMesh::IO::read_mesh(om, path, opt);
    } catch (const std::exception&) {
        ok = false;
    }
    if (!ok) throw Error("mesh " + q(path) + " is not a mesh OpenMesh can read");
    std::vector<float> verts(3 * om.n_vertices());
    for (auto vh : om.vertices()) {
        const auto& p = om.point(vh);
        for (int k = 0; k < 3; ++k) verts[3 * size_t(vh.idx()) + k] = p[k];
    }
    std::vector<int32_t> tris;
    tris.reserve(3 * om.n_faces());
    for (auto fh : om.faces()) {
        int cnt = 0;
        int32_t idx[3] = {0, 0, 0};
        for (auto vh : om.fv_range(fh)) {
            if (cnt < 3) idx[cnt] = vh.idx();
            ++cnt;
        }
        if (cnt != 3) continue;
        tris.insert(tris.end(), idx, idx + 3);
    }
    return build(std::move(verts), tris.data(), tris.size() / 3, path);
}

Mesh Mesh::from_arrays(const float* verts, size_t n, const int32_t* tris, size_t m,
                       const std::string& name) {
    return build(std::vector<float>(verts, verts + 3 * n), tris, m, name);
}

}  // namespace gammart
