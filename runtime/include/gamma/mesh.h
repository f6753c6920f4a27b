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

    size_t num_vertices() const { return vertices.size() / 3; }
    size_t num_triangles() const { return triangles.size() / 3; }
    float diagonal() const;
    double area() const;  // total area of kept triangles

    // Loads OBJ/PLY (anything OpenMesh reads).  Throws gammart::Error.
    static Mesh load(const std::string& path);
    // Validates and builds from raw arrays.  Throws gammart::Error.
    static Mesh from_arrays(const float* verts, size_t n, const int32_t* tris, size_t m,
                            const std::string& name = "<arrays>");
};

}  // namespace gammart
