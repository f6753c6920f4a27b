#include "gamma/mesh.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string_view>
#include <unordered_map>

#include "gamma/error.h"

namespace gammart {

namespace {
using OMesh = OpenMesh::PolyMesh_ArrayKernelT<>;

std::string q(const std::string& s) { return "'" + s + "'"; }

void silence_openmesh() {
    static std::once_flag once;
    std::call_once(once, [] {
        omerr().disable();
        omlog().disable();
        omout().disable();
    });
}

std::string non_finite_vertex(const std::string& name, size_t v) {
    return "mesh " + q(name) + ": vertex " + std::to_string(v) + " has a non-finite coordinate";
}

// Per input triangle labels (indices into names); empty = no labels.
struct Labels {
    std::vector<std::string> names;
    std::vector<int32_t> object, group, material;
};

// Bounds over the vertices the m triangles use and their squared diagonal,
// in double (a float sum of squares overflows for coordinates beyond ~1e19).
double used_bounds(const float* verts, const int32_t* tris, size_t m, double lo[3], double hi[3]) {
    for (int k = 0; k < 3; ++k) lo[k] = INFINITY, hi[k] = -INFINITY;
    for (size_t t = 0; t < 3 * m; ++t)
        for (int k = 0; k < 3; ++k) {
            double c = verts[3 * size_t(tris[t]) + k];
            lo[k] = std::min(lo[k], c);
            hi[k] = std::max(hi[k], c);
        }
    double diag2 = 0;
    for (int k = 0; k < 3; ++k) diag2 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    return diag2;
}

// `uvs`: m*6 floats (per input triangle corner) or nullptr.
Mesh build(std::vector<float> verts, const int32_t* tris, size_t m, const std::string& name,
           const Labels* labels = nullptr, const float* uvs = nullptr) {
    Mesh mesh;
    mesh.name = name;
    const size_t n = verts.size() / 3;
    if (m == 0) throw Error("mesh " + q(name) + " has no triangles");
    for (size_t i = 0; i < verts.size(); ++i)
        if (!std::isfinite(verts[i])) throw Error(non_finite_vertex(name, i / 3));
    for (size_t t = 0; t < m; ++t)
        for (int k = 0; k < 3; ++k) {
            int64_t v = tris[3 * t + k];
            if (v < 0 || size_t(v) >= n)
                throw Error("mesh " + q(name) + ": triangle " + std::to_string(t) +
                            " has vertex index " + std::to_string(v) + " out of range (" +
                            std::to_string(n) + " vertices)");
        }
    if (uvs)
        for (size_t i = 0; i < 6 * m; ++i)
            if (!std::isfinite(uvs[i]))
                throw Error("mesh " + q(name) + ": triangle " + std::to_string(i / 6) +
                            " has a non-finite texture coordinate");
    double lo[3], hi[3];
    const double diag2 = used_bounds(verts.data(), tris, m, lo, hi);
    const double diag = std::sqrt(diag2);
    // The tracer works in float with points up to 4 diagonals from the centre.
    if (!std::isfinite(diag) || !(diag > 0) || 4.0 * diag > double(FLT_MAX))
        throw Error("mesh " + q(name) + " has a non-finite or zero extent");
    const double min_area = 1e-12 * diag2;
    mesh.triangles.reserve(3 * m);
    mesh.original_triangle.reserve(m);
    if (uvs) mesh.uvs.reserve(6 * m);
    if (labels) {
        mesh.object_id.reserve(m);
        mesh.group_id.reserve(m);
        mesh.material_id.reserve(m);
    }
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
        if (uvs) mesh.uvs.insert(mesh.uvs.end(), uvs + 6 * t, uvs + 6 * t + 6);
        if (labels) {
            mesh.object_id.push_back(labels->object[t]);
            mesh.group_id.push_back(labels->group[t]);
            mesh.material_id.push_back(labels->material[t]);
        }
    }
    mesh.input_triangles = m;
    if (mesh.triangles.empty()) throw Error("mesh " + q(name) + " has only degenerate triangles");
    for (int k = 0; k < 3; ++k) { mesh.lo[k] = float(lo[k]); mesh.hi[k] = float(hi[k]); }
    mesh.diag = diag;
    if (labels) mesh.part_names = labels->names;
    mesh.vertices = std::move(verts);
    return mesh;
}

std::string lower_ext(const std::string& path) {
    std::string ext = std::filesystem::path(path).extension().string();
    for (auto& ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
    return ext;
}

// ---- OBJ -------------------------------------------------------------------

inline bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// Names reach Python (and summary.json) as str: they must be UTF-8.
bool valid_utf8(const std::string& s) {
    const size_t n = s.size();
    for (size_t i = 0; i < n;) {
        const unsigned char c = static_cast<unsigned char>(s[i]);
        size_t len;
        unsigned char lo = 0x80, hi = 0xBF;  // range of the second byte
        if (c < 0x80) len = 1;
        else if (c >= 0xC2 && c <= 0xDF) len = 2;
        else if (c >= 0xE0 && c <= 0xEF) { len = 3; if (c == 0xE0) lo = 0xA0; if (c == 0xED) hi = 0x9F; }
        else if (c >= 0xF0 && c <= 0xF4) { len = 4; if (c == 0xF0) lo = 0x90; if (c == 0xF4) hi = 0x8F; }
        else return false;
        if (i + len > n) return false;
        for (size_t k = 1; k < len; ++k) {
            const unsigned char d = static_cast<unsigned char>(s[i + k]);
            if (k == 1 ? (d < lo || d > hi) : (d & 0xC0) != 0x80) return false;
        }
        i += len;
    }
    return true;
}

std::string trim(std::string_view s, size_t a = 0) {
    while (a < s.size() && is_space(s[a])) ++a;
    size_t b = s.size();
    while (b > a && is_space(s[b - 1])) --b;
    return std::string(s.substr(a, b - a));
}

// The numbers of an OBJ line, read as strtod and strtoll read them (the
// reader's results and errors are those it always gave), without the
// copies: the lines are views of the file's text, not NUL-terminated, and
// std::from_chars reads a plain decimal number the same (both round
// correctly).  Anything else -- a leading '+', hex, out of range, text
// right after the number -- is read by strtod / strtoll on a copy, as before.

// strtod(p) on the line that ends at `end`: false if it reads nothing, else
// the value, and p moved past what it read.
bool read_double(const char*& p, const char* end, double& value) {
    const char* q = p;
    while (q < end && is_space(*q)) ++q;
    const auto fast = std::from_chars(q, end, value);
    if (fast.ec == std::errc() && (fast.ptr == end || is_space(*fast.ptr))) {
        p = fast.ptr;
        return true;
    }
    const std::string rest(p, end);
    char* stop = nullptr;
    value = std::strtod(rest.c_str(), &stop);
    if (stop == rest.c_str()) return false;
    p += stop - rest.c_str();
    return true;
}

// strtoll(s, &stop, 10) with *stop == '\0' afterwards (all of s read, as far
// as C sees it).
bool read_whole_integer(std::string_view s, long long& value) {
    const auto fast = std::from_chars(s.data(), s.data() + s.size(), value);
    if (fast.ec == std::errc() && fast.ptr == s.data() + s.size()) return true;
    const std::string copy(s);
    char* stop = nullptr;
    value = std::strtoll(copy.c_str(), &stop, 10);
    return *stop == '\0';
}

}  // namespace

double Mesh::used_diagonal() const {
    double lo[3], hi[3];
    return std::sqrt(used_bounds(vertices.data(), triangles.data(), num_triangles(), lo, hi));
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

Mesh Mesh::parse_obj(const std::string& text, const std::string& name) {
    std::vector<float> verts;
    std::vector<int32_t> tris;
    Labels labels;
    std::unordered_map<std::string, int32_t> name_id;
    size_t line_no = 0, pos = 0;
    const std::string where = "mesh " + q(name) + ": ";
    auto intern = [&](const std::string& s, const char* kind) -> int32_t {
        if (s.empty()) return -1;
        if (!valid_utf8(s))
            throw Error(where + "line " + std::to_string(line_no) + ": the " + kind +
                        " name is not UTF-8 text (re-save the file as UTF-8)");
        auto it = name_id.find(s);
        if (it != name_id.end()) return it->second;
        int32_t id = int32_t(labels.names.size());
        labels.names.push_back(s);
        name_id.emplace(s, id);
        return id;
    };
    int32_t cur_object = -1, cur_group = -1, cur_material = -1;
    // Positive indices may refer to vertices defined later; they are checked
    // once the file is read.  Only a corner whose index was not yet in range
    // when its face was read (a forward reference, or 0) can be out of range
    // then: the line and the written index of those corners alone are kept,
    // for the message (per corner, they were 8 MB of the bunny's load).
    struct Pending { size_t line; int64_t written; bool forward; };
    struct Forward { size_t corner; size_t line; int64_t written; };
    std::vector<Forward> vertex_forward, vt_forward;
    std::vector<int64_t> face;
    std::vector<Pending> face_src;
    // Texture coordinates: `vt` values (2 per entry) and, while every corner
    // so far names one, per triangle corner the 0-based vt index (checked at
    // the end like vertex indices).
    std::vector<float> texcoords;
    std::vector<int64_t> tri_vt, face_vt;
    std::vector<Pending> face_vt_src;
    bool all_corners_have_vt = true;
    const std::string_view all(text);
    size_t corners_hint = 0;   // 3 per line starting "f ", for tri_vt's room
    {
        // Room for what lines starting "v " and "f " add (triangles: 3
        // corners a face), reserved once rather than grown by doubling: each
        // growth copies the array and faults in new pages (a third of the
        // bunny's load was page faults).  A hint only: other lines still fit.
        size_t v = 0, f = 0;
        for (size_t at = 0; at + 1 < text.size();) {
            if (text[at + 1] == ' ' || text[at + 1] == '\t') {
                v += text[at] == 'v';
                f += text[at] == 'f';
            }
            const size_t eol = text.find('\n', at);
            if (eol == std::string::npos) break;
            at = eol + 1;
        }
        verts.reserve(3 * v);
        tris.reserve(3 * f);
        corners_hint = 3 * f;
        labels.object.reserve(f);
        labels.group.reserve(f);
        labels.material.reserve(f);
    }
    while (pos < text.size()) {
        size_t eol = text.find('\n', pos);
        if (eol == std::string::npos) eol = text.size();
        std::string_view line = all.substr(pos, eol - pos);
        pos = eol + 1;
        ++line_no;
        size_t hash = line.find('#');
        if (hash != std::string_view::npos) line = line.substr(0, hash);
        size_t a = 0;
        while (a < line.size() && is_space(line[a])) ++a;
        size_t b = a;
        while (b < line.size() && !is_space(line[b])) ++b;
        const std::string_view kw = line.substr(a, b - a);
        const char* const line_end = line.data() + line.size();
        if (kw == "v") {
            const char* p = line.data() + b;
            float xyz[3];
            for (int k = 0; k < 3; ++k) {
                double c = 0;
                if (!read_double(p, line_end, c))
                    throw Error(where + "line " + std::to_string(line_no) + ": cannot read vertex coordinates");
                if (!std::isfinite(c) || std::fabs(c) > double(FLT_MAX))
                    throw Error(non_finite_vertex(name, verts.size() / 3));
                xyz[k] = float(c);
            }
            verts.insert(verts.end(), xyz, xyz + 3);
        } else if (kw == "vt") {
            // vt u [v [w]]: v defaults to 0, w is ignored.
            const char* p = line.data() + b;
            float uv[2] = {0.0f, 0.0f};
            for (int k = 0; k < 2; ++k) {
                double c = 0;
                if (!read_double(p, line_end, c)) {
                    if (k == 1) break;
                    throw Error(where + "line " + std::to_string(line_no) + ": cannot read texture coordinates");
                }
                if (!std::isfinite(c) || std::fabs(c) > double(FLT_MAX))
                    throw Error(where + "line " + std::to_string(line_no) + ": texture coordinate is not finite");
                uv[k] = float(c);
            }
            texcoords.insert(texcoords.end(), uv, uv + 2);
        } else if (kw == "f") {
            face.clear();
            face_src.clear();
            face_vt.clear();
            face_vt_src.clear();
            // The whitespace-separated tokens `istringstream >> std::string` would give
            // (lines hold no '\n'), without a stream per face: ~70 ms on the bunny.
            for (size_t q = b;;) {
                while (q < line.size() && is_space(line[q])) ++q;
                if (q >= line.size()) break;
                size_t e = q;
                while (e < line.size() && !is_space(line[e])) ++e;
                const std::string_view tok = line.substr(q, e - q);
                q = e;
                auto unreadable = [&] {
                    return Error(where + "face on line " + std::to_string(line_no) + ": cannot read '" +
                                 std::string(tok) + "'");
                };
                // Texture index: between the first and the second '/'.
                const size_t s1 = tok.find('/');
                std::string_view tpart;
                if (s1 != std::string_view::npos) {
                    const size_t s2 = tok.find('/', s1 + 1);
                    tpart = tok.substr(s1 + 1, s2 == std::string_view::npos ? std::string_view::npos : s2 - s1 - 1);
                }
                if (tpart.empty()) {
                    all_corners_have_vt = false;
                    face_vt.push_back(0);
                    face_vt_src.push_back({line_no, 0, false});
                } else {
                    long long tidx = 0;
                    if (!read_whole_integer(tpart, tidx)) throw unreadable();
                    const int64_t nt = int64_t(texcoords.size() / 2);
                    int64_t tz = tidx < 0 ? nt + tidx : tidx - 1;
                    if (tidx < 0 && tz < 0)
                        throw Error(where + "face on line " + std::to_string(line_no) + " has texture index " +
                                    std::to_string(tidx) + " out of range (" + std::to_string(nt) +
                                    " texture coordinates)");
                    face_vt.push_back(tz);
                    face_vt_src.push_back({line_no, tidx, tz < 0 || tz >= nt});
                }
                const std::string_view first = tok.substr(0, tok.find('/'));
                long long idx = 0;
                if (first.empty() || !read_whole_integer(first, idx)) throw unreadable();
                const int64_t nv = int64_t(verts.size() / 3);
                int64_t zero_based;
                if (idx < 0) {
                    zero_based = nv + idx;
                    if (zero_based < 0)
                        throw Error(where + "face on line " + std::to_string(line_no) + " has vertex index " +
                                    std::to_string(idx) + " out of range (" + std::to_string(nv) + " vertices)");
                } else {
                    zero_based = idx - 1;  // 0 -> -1, reported below
                }
                face.push_back(zero_based);
                face_src.push_back({line_no, idx, zero_based < 0 || zero_based >= nv});
            }
            if (face.size() < 3)
                throw Error(where + "face on line " + std::to_string(line_no) + " has fewer than 3 vertices");
            if (!all_corners_have_vt && !tri_vt.empty()) {
                tri_vt = {};             // no UVs: their indices are never checked
                vt_forward = {};
            }
            for (size_t k = 1; k + 1 < face.size(); ++k) {
                const size_t corner[3] = {0, k, k + 1};
                for (size_t c : corner) {
                    if (face_src[c].forward)
                        vertex_forward.push_back({tris.size(), face_src[c].line, face_src[c].written});
                    if (all_corners_have_vt) {
                        if (tri_vt.empty()) tri_vt.reserve(corners_hint);
                        if (face_vt_src[c].forward)
                            vt_forward.push_back({tri_vt.size(), face_vt_src[c].line, face_vt_src[c].written});
                        tri_vt.push_back(face_vt[c]);
                    }
                    tris.push_back(int32_t(std::min<int64_t>(face[c], INT32_MAX)));
                }
                labels.object.push_back(cur_object);
                labels.group.push_back(cur_group);
                labels.material.push_back(cur_material);
            }
        } else if (kw == "o") {
            cur_object = intern(trim(line, b), "object");
        } else if (kw == "g") {
            cur_group = intern(trim(line, b), "group");
        } else if (kw == "usemtl") {
            cur_material = intern(trim(line, b), "material");
        }
        // Everything else (vn, s, mtllib, l, p, ...) is ignored.
    }
    // The record of corner i among the forward ones (every corner out of range has one).
    auto forward_of = [](const std::vector<Forward>& forward, size_t i) -> const Forward& {
        const auto it = std::lower_bound(forward.begin(), forward.end(), i,
                                         [](const Forward& f, size_t corner) { return f.corner < corner; });
        if (it == forward.end() || it->corner != i) throw std::logic_error("parse_obj: no record of a corner");
        return *it;
    };
    const int64_t nv = int64_t(verts.size() / 3);
    for (size_t i = 0; i < tris.size(); ++i)
        if (tris[i] < 0 || tris[i] >= nv) {
            const Forward& f = forward_of(vertex_forward, i);
            throw Error(where + "face on line " + std::to_string(f.line) + " has vertex index " +
                        std::to_string(f.written) + " out of range (" + std::to_string(nv) + " vertices)");
        }
    // UVs only if every corner of every face names a texture coordinate.
    std::vector<float> uvs;
    if (all_corners_have_vt && !tris.empty()) {
        const int64_t nt = int64_t(texcoords.size() / 2);
        uvs.resize(2 * tri_vt.size());
        for (size_t i = 0; i < tri_vt.size(); ++i) {
            if (tri_vt[i] < 0 || tri_vt[i] >= nt) {
                const Forward& f = forward_of(vt_forward, i);
                throw Error(where + "face on line " + std::to_string(f.line) + " has texture index " +
                            std::to_string(f.written) + " out of range (" + std::to_string(nt) +
                            " texture coordinates)");
            }
            uvs[2 * i] = texcoords[2 * size_t(tri_vt[i])];
            uvs[2 * i + 1] = texcoords[2 * size_t(tri_vt[i]) + 1];
        }
    }
    return build(std::move(verts), tris.data(), tris.size() / 3, name, &labels, uvs.empty() ? nullptr : uvs.data());
}

namespace {

// The whole file, if it is a regular file we can read.
std::string read_file(const std::string& path) {
    std::error_code ec;
    const auto status = std::filesystem::status(path, ec);
    if (ec || !std::filesystem::exists(status))
        throw Error("cannot read mesh " + q(path) + ": file not found");
    if (std::filesystem::is_directory(status))
        throw Error("cannot read mesh " + q(path) + ": is a directory");
    if (!std::filesystem::is_regular_file(status))
        throw Error("cannot read mesh " + q(path) + ": not a regular file (a pipe or a device)");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error("cannot read mesh " + q(path) + ": cannot open file");
    // Read into a string of the file's size (one allocation, no stream
    // growing by copies and no copy out of it); a file that grew meanwhile
    // is read to its end all the same.
    std::string text;
    const auto size = std::filesystem::file_size(path, ec);
    if (!ec) {
        text.resize(size_t(size));
        in.read(text.data(), std::streamsize(text.size()));
        text.resize(size_t(in.gcount()));
        if (in.bad()) throw Error("cannot read mesh " + q(path) + ": read error");
        if (!in.eof() && in.peek() == std::char_traits<char>::eof()) return text;
        in.clear();
    }
    std::ostringstream ss;
    ss << in.rdbuf();
    if (in.bad()) throw Error("cannot read mesh " + q(path) + ": read error");
    return text + ss.str();
}

}  // namespace

Mesh Mesh::load(const std::string& path) {
    const std::string ext = lower_ext(path);
    if (ext == ".obj") return parse_obj(read_file(path), path);
    if (ext == ".ply") return parse_ply(read_file(path), path);
    read_file(path).size();  // the same checks before OpenMesh sees the file
    silence_openmesh();
    OMesh om;
    // Ask for texture coordinates (PLY vertex u/v); opt says afterwards whether the file had them.
    om.request_vertex_texcoords2D();
    OpenMesh::IO::Options opt = OpenMesh::IO::Options::VertexTexCoord;
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
        for (int k = 0; k < 3; ++k) {
            if (!std::isfinite(p[k])) throw Error(non_finite_vertex(path, size_t(vh.idx())));
            verts[3 * size_t(vh.idx()) + k] = p[k];
        }
    }
    std::vector<int32_t> tris;
    tris.reserve(3 * om.n_faces());
    std::vector<int32_t> poly;
    for (auto fh : om.faces()) {
        poly.clear();
        for (auto vh : om.fv_range(fh)) poly.push_back(vh.idx());
        for (size_t k = 1; k + 1 < poly.size(); ++k) {
            tris.push_back(poly[0]);
            tris.push_back(poly[k]);
            tris.push_back(poly[k + 1]);
        }
    }
    // Per-vertex texture coordinates become per-corner ones (build checks they are finite).
    std::vector<float> uvs;
    if (opt.check(OpenMesh::IO::Options::VertexTexCoord)) {
        uvs.reserve(2 * tris.size());
        for (int32_t v : tris) {
            const auto& t = om.texcoord2D(OMesh::VertexHandle(v));
            uvs.push_back(t[0]);
            uvs.push_back(t[1]);
        }
    }
    return build(std::move(verts), tris.data(), tris.size() / 3, path, nullptr, uvs.empty() ? nullptr : uvs.data());
}

Mesh Mesh::from_arrays(const float* verts, size_t n, const int32_t* tris, size_t m,
                       const std::string& name, const float* uvs) {
    return build(std::vector<float>(verts, verts + 3 * n), tris, m, name, nullptr, uvs);
}

}  // namespace gammart
