#include "gamma/mesh.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>

#include <algorithm>
#include <array>
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

namespace {

// One OBJ file read line by line: its vertices, texture coordinates, faces
// (fan-triangulated) and object / group / material labels.
class ObjReader {
public:
    ObjReader(const std::string& text, const std::string& name)
        : text_(text), name_(name), where_("mesh " + q(name) + ": ") {}

    Mesh read() {
        reserve();
        for (size_t pos = 0; pos < text_.size();) {
            size_t eol = text_.find('\n', pos);
            if (eol == std::string::npos) eol = text_.size();
            line(std::string_view(text_).substr(pos, eol - pos));
            pos = eol + 1;
        }
        check_vertex_indices();
        const std::vector<float> uvs = corner_uvs();
        return build(std::move(verts_), tris_.data(), tris_.size() / 3, name_, &labels_,
                     uvs.empty() ? nullptr : uvs.data());
    }

private:
    // Positive indices may refer to vertices defined later; they are checked
    // once the file is read.  Only a corner whose index was not yet in range
    // when its face was read (a forward reference, or 0) can be out of range
    // then: the line and the written index of those corners alone are kept,
    // for the message (kept per corner, they were most of a large file's load).
    struct Pending { size_t line; int64_t written; bool forward; };
    struct Forward { size_t corner; size_t line; int64_t written; };

    const std::string& text_;
    const std::string& name_;
    const std::string where_;
    size_t line_no_ = 0;
    std::vector<float> verts_;
    std::vector<int32_t> tris_;
    Labels labels_;
    std::unordered_map<std::string, int32_t> name_id_;
    int32_t object_ = -1, group_ = -1, material_ = -1;
    std::vector<Forward> vertex_forward_, vt_forward_;
    std::vector<int64_t> face_;
    std::vector<Pending> face_src_;
    // Texture coordinates: `vt` values (2 per entry) and, while every corner
    // so far names one, per triangle corner the 0-based vt index (checked at
    // the end like vertex indices).
    std::vector<float> texcoords_;
    std::vector<int64_t> tri_vt_, face_vt_;
    std::vector<Pending> face_vt_src_;
    bool all_corners_have_vt_ = true;
    size_t corners_hint_ = 0;  // 3 per line starting "f ", for tri_vt_'s room

    std::string at_line() const { return where_ + "line " + std::to_string(line_no_) + ": "; }
    std::string at_face() const { return where_ + "face on line " + std::to_string(line_no_); }

    // Room for what lines starting "v " and "f " add (triangles: 3 corners a
    // face), reserved once rather than grown by doubling: each growth copies
    // the array and faults in new pages.  A hint only: other lines still fit.
    void reserve() {
        size_t v = 0, f = 0;
        for (size_t at = 0; at + 1 < text_.size();) {
            if (text_[at + 1] == ' ' || text_[at + 1] == '\t') {
                v += text_[at] == 'v';
                f += text_[at] == 'f';
            }
            const size_t eol = text_.find('\n', at);
            if (eol == std::string::npos) break;
            at = eol + 1;
        }
        verts_.reserve(3 * v);
        tris_.reserve(3 * f);
        corners_hint_ = 3 * f;
        labels_.object.reserve(f);
        labels_.group.reserve(f);
        labels_.material.reserve(f);
    }

    void line(std::string_view line) {
        ++line_no_;
        const size_t hash = line.find('#');
        if (hash != std::string_view::npos) line = line.substr(0, hash);
        size_t a = 0;
        while (a < line.size() && is_space(line[a])) ++a;
        size_t b = a;
        while (b < line.size() && !is_space(line[b])) ++b;
        const std::string_view kw = line.substr(a, b - a);
        const char* const end = line.data() + line.size();
        if (kw == "v") vertex(line.data() + b, end);
        else if (kw == "vt") texcoord(line.data() + b, end);
        else if (kw == "f") face(line, b);
        else if (kw == "o") object_ = intern(trim(line, b), "object");
        else if (kw == "g") group_ = intern(trim(line, b), "group");
        else if (kw == "usemtl") material_ = intern(trim(line, b), "material");
        // Everything else (vn, s, mtllib, l, p, ...) is ignored.
    }

    int32_t intern(const std::string& s, const char* kind) {
        if (s.empty()) return -1;
        if (!valid_utf8(s))
            throw Error(at_line() + "the " + kind + " name is not UTF-8 text (re-save the file as UTF-8)");
        auto it = name_id_.find(s);
        if (it != name_id_.end()) return it->second;
        const int32_t id = int32_t(labels_.names.size());
        labels_.names.push_back(s);
        name_id_.emplace(s, id);
        return id;
    }

    void vertex(const char* p, const char* end) {
        float xyz[3];
        for (int k = 0; k < 3; ++k) {
            double c = 0;
            if (!read_double(p, end, c)) throw Error(at_line() + "cannot read vertex coordinates");
            if (!std::isfinite(c) || std::fabs(c) > double(FLT_MAX))
                throw Error(non_finite_vertex(name_, verts_.size() / 3));
            xyz[k] = float(c);
        }
        verts_.insert(verts_.end(), xyz, xyz + 3);
    }

    // vt u [v [w]]: v defaults to 0, w is ignored.
    void texcoord(const char* p, const char* end) {
        float uv[2] = {0.0f, 0.0f};
        for (int k = 0; k < 2; ++k) {
            double c = 0;
            if (!read_double(p, end, c)) {
                if (k == 1) break;
                throw Error(at_line() + "cannot read texture coordinates");
            }
            if (!std::isfinite(c) || std::fabs(c) > double(FLT_MAX))
                throw Error(at_line() + "texture coordinate is not finite");
            uv[k] = float(c);
        }
        texcoords_.insert(texcoords_.end(), uv, uv + 2);
    }

    void face(std::string_view line, size_t b) {
        face_.clear();
        face_src_.clear();
        face_vt_.clear();
        face_vt_src_.clear();
        // The whitespace-separated tokens `istringstream >> std::string` would
        // give (lines hold no '\n'), without a stream per face.
        for (size_t q = b;;) {
            while (q < line.size() && is_space(line[q])) ++q;
            if (q >= line.size()) break;
            size_t e = q;
            while (e < line.size() && !is_space(line[e])) ++e;
            corner(line.substr(q, e - q));
            q = e;
        }
        if (face_.size() < 3) throw Error(at_face() + " has fewer than 3 vertices");
        if (!all_corners_have_vt_ && !tri_vt_.empty()) {
            tri_vt_ = {};             // no UVs: their indices are never checked
            vt_forward_ = {};
        }
        for (size_t k = 1; k + 1 < face_.size(); ++k) triangle({0, k, k + 1});
    }

    // One `v`, `v/vt`, `v//vn` or `v/vt/vn` token of a face.
    void corner(std::string_view tok) {
        auto unreadable = [&] { return Error(at_face() + ": cannot read '" + std::string(tok) + "'"); };
        const size_t s1 = tok.find('/');
        std::string_view tpart;  // the texture index: between the first and the second '/'
        if (s1 != std::string_view::npos) {
            const size_t s2 = tok.find('/', s1 + 1);
            tpart = tok.substr(s1 + 1, s2 == std::string_view::npos ? std::string_view::npos : s2 - s1 - 1);
        }
        if (tpart.empty()) {
            all_corners_have_vt_ = false;
            face_vt_.push_back(0);
            face_vt_src_.push_back({line_no_, 0, false});
        } else {
            long long tidx = 0;
            if (!read_whole_integer(tpart, tidx)) throw unreadable();
            const int64_t nt = int64_t(texcoords_.size() / 2);
            const int64_t tz = tidx < 0 ? nt + tidx : tidx - 1;
            if (tidx < 0 && tz < 0)
                throw Error(at_face() + " has texture index " + std::to_string(tidx) + " out of range (" +
                            std::to_string(nt) + " texture coordinates)");
            face_vt_.push_back(tz);
            face_vt_src_.push_back({line_no_, tidx, tz < 0 || tz >= nt});
        }
        const std::string_view first = tok.substr(0, tok.find('/'));
        long long idx = 0;
        if (first.empty() || !read_whole_integer(first, idx)) throw unreadable();
        const int64_t nv = int64_t(verts_.size() / 3);
        const int64_t zero_based = idx < 0 ? nv + idx : idx - 1;  // 0 -> -1, reported at the end
        if (idx < 0 && zero_based < 0)
            throw Error(at_face() + " has vertex index " + std::to_string(idx) + " out of range (" +
                        std::to_string(nv) + " vertices)");
        face_.push_back(zero_based);
        face_src_.push_back({line_no_, idx, zero_based < 0 || zero_based >= nv});
    }

    void triangle(const std::array<size_t, 3>& corners) {
        for (size_t c : corners) {
            if (face_src_[c].forward)
                vertex_forward_.push_back({tris_.size(), face_src_[c].line, face_src_[c].written});
            if (all_corners_have_vt_) {
                if (tri_vt_.empty()) tri_vt_.reserve(corners_hint_);
                if (face_vt_src_[c].forward)
                    vt_forward_.push_back({tri_vt_.size(), face_vt_src_[c].line, face_vt_src_[c].written});
                tri_vt_.push_back(face_vt_[c]);
            }
            tris_.push_back(int32_t(std::min<int64_t>(face_[c], INT32_MAX)));
        }
        labels_.object.push_back(object_);
        labels_.group.push_back(group_);
        labels_.material.push_back(material_);
    }

    // The record of corner i among the forward ones (every corner out of range has one).
    static const Forward& forward_of(const std::vector<Forward>& forward, size_t i) {
        const auto it = std::lower_bound(forward.begin(), forward.end(), i,
                                         [](const Forward& f, size_t corner) { return f.corner < corner; });
        if (it == forward.end() || it->corner != i) throw std::logic_error("parse_obj: no record of a corner");
        return *it;
    }

    void check_vertex_indices() const {
        const int64_t nv = int64_t(verts_.size() / 3);
        for (size_t i = 0; i < tris_.size(); ++i)
            if (tris_[i] < 0 || tris_[i] >= nv) {
                const Forward& f = forward_of(vertex_forward_, i);
                throw Error(where_ + "face on line " + std::to_string(f.line) + " has vertex index " +
                            std::to_string(f.written) + " out of range (" + std::to_string(nv) + " vertices)");
            }
    }

    // UVs per corner, only if every corner of every face names a texture coordinate.
    std::vector<float> corner_uvs() const {
        std::vector<float> uvs;
        if (!all_corners_have_vt_ || tris_.empty()) return uvs;
        const int64_t nt = int64_t(texcoords_.size() / 2);
        uvs.resize(2 * tri_vt_.size());
        for (size_t i = 0; i < tri_vt_.size(); ++i) {
            if (tri_vt_[i] < 0 || tri_vt_[i] >= nt) {
                const Forward& f = forward_of(vt_forward_, i);
                throw Error(where_ + "face on line " + std::to_string(f.line) + " has texture index " +
                            std::to_string(f.written) + " out of range (" + std::to_string(nt) +
                            " texture coordinates)");
            }
            uvs[2 * i] = texcoords_[2 * size_t(tri_vt_[i])];
            uvs[2 * i + 1] = texcoords_[2 * size_t(tri_vt_[i]) + 1];
        }
        return uvs;
    }
};

}  // namespace

Mesh Mesh::parse_obj(const std::string& text, const std::string& name) { return ObjReader(text, name).read(); }

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
