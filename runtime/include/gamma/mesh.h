#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace gammart {

// Triangle mesh after validation and removal of degenerate triangles.
struct Mesh {
    std::string name;                          // path (or "<arrays>") used in messages
    std::vector<float> vertices;               // n*3
    std::vector<int32_t> triangles;            // m*3 (degenerates removed)
    std::vector<int32_t> original_triangle;    // m: index in the input before removal
    size_t input_triangles = 0;                // m + degenerate_dropped
    size_t degenerate_dropped = 0;
    std::array<float, 3> lo{}, hi{};
    double diag = 0;                           // bbox diagonal, computed in double

    // OBJ part labels per kept triangle: indices into part_names, -1 = none.
    // Empty vectors when the mesh has no labels (PLY, from_arrays).
    std::vector<std::string> part_names;       // distinct non-empty names, first-seen order
    std::vector<int32_t> object_id, group_id, material_id;

    // Texture coordinates per kept triangle corner: m*6 floats (u0 v0 u1 v1
    // u2 v2, corners in triangles() order).  Empty when the mesh has no UVs
    // (an OBJ face corner without a `vt` index anywhere, PLY, or from_arrays
    // without uvs).
    std::vector<float> uvs;
    bool has_uvs() const { return !uvs.empty(); }

    size_t num_vertices() const { return vertices.size() / 3; }
    size_t num_triangles() const { return triangles.size() / 3; }
    float diagonal() const { return float(diag); }
    // The diagonal from_arrays would give these vertices and triangles
    // (bounds over the vertices triangles use), for a copy whose vertices
    // moved (its `diag` is the original's).
    double used_diagonal() const;
    double area() const;  // total area of kept triangles

    // OBJ and PLY: own readers (OBJ objects, groups, materials kept; every
    // declared size checked against the file before anything is allocated);
    // other formats (OFF, STL, ...): OpenMesh.  Only regular files are read
    // (not FIFOs or devices).  Throws gammart::Error.
    static Mesh load(const std::string& path);
    // Parses OBJ text; `name` is used in messages (exposed for tests).
    static Mesh parse_obj(const std::string& text, const std::string& name);
    // Parses the bytes of a PLY file (ASCII or binary; runtime/src/ply.cpp).
    static Mesh parse_ply(const std::string& data, const std::string& name);
    // Validates and builds from raw arrays; `uvs` (optional) holds m*6 floats,
    // the texture coordinates of each input triangle's 3 corners.  Throws
    // gammart::Error.
    static Mesh from_arrays(const float* verts, size_t n, const int32_t* tris, size_t m,
                            const std::string& name = "<arrays>", const float* uvs = nullptr);
};

}  // namespace gammart
