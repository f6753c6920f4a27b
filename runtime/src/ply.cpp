// PLY reader: ASCII and binary (little and big endian) triangle soups.
//
// Our own reader rather than OpenMesh's, because OpenMesh loops forever on a
// truncated header, allocates whatever count a header declares before reading
// a byte of the body, and drops faces it cannot fit into its half-edge
// structure (repeated vertices, non-manifold edges) without saying which.
// Here every declared size is checked against the bytes actually present
// before anything is allocated, every read is bounds-checked, and a face with
// repeated vertices is simply a degenerate triangle, dropped with a warning
// like any other (SPEC §16.1); a face of fewer than 3 vertices is an error
// naming it, as in an OBJ file.
//
// Read: element `vertex` (x, y, z; optional texture coordinates named
// u/v, s/t or texture_u/texture_v), element `face` (list property
// `vertex_indices` or `vertex_index`; polygons as fans). Other elements and
// properties are skipped.

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/mesh.h"

namespace gammart {

namespace {

enum class Type { i8, u8, i16, u16, i32, u32, f32, f64, none };

Type type_of(const std::string& s) {
    if (s == "char" || s == "int8") return Type::i8;
    if (s == "uchar" || s == "uint8") return Type::u8;
    if (s == "short" || s == "int16") return Type::i16;
    if (s == "ushort" || s == "uint16") return Type::u16;
    if (s == "int" || s == "int32") return Type::i32;
    if (s == "uint" || s == "uint32") return Type::u32;
    if (s == "float" || s == "float32") return Type::f32;
    if (s == "double" || s == "float64") return Type::f64;
    return Type::none;
}

size_t size_of(Type t) {
    switch (t) {
        case Type::i8: case Type::u8: return 1;
        case Type::i16: case Type::u16: return 2;
        case Type::i32: case Type::u32: case Type::f32: return 4;
        case Type::f64: return 8;
        default: return 0;
    }
}

std::string plural(const std::string& element, uint64_t n) {
    if (n == 1) return element;
    return element == "vertex" ? "vertices" : element + "s";
}

bool is_integer(Type t) { return t != Type::f32 && t != Type::f64; }

struct Property {
    std::string name;
    Type type = Type::none;        // scalar type, or the item type of a list
    Type count_type = Type::none;  // != none: a list
    bool is_list() const { return count_type != Type::none; }
};

struct Element {
    std::string name;
    uint64_t count = 0;
    std::vector<Property> props;
};

enum class Format { ascii, binary_le, binary_be };

// Longest header we accept: real headers are a few hundred bytes; a file that
// has no `end_header` within this many bytes is not a PLY we can read.
constexpr size_t kMaxHeader = 1 << 20;

class Reader {
public:
    Reader(const std::string& data, const std::string& name) : data_(data), name_(name) {}

    Mesh read() {
        parse_header();
        check_sizes();
        std::vector<float> verts, texcoords;
        std::vector<int32_t> tris;
        bool have_uv = false;
        for (const Element& e : elements_) {
            if (e.name == "vertex") {
                read_vertices(e, verts, texcoords, have_uv);
            } else if (e.name == "face") {
                read_faces(e, verts.size() / 3, tris);
            } else {
                for (uint64_t i = 0; i < e.count; ++i) skip_element(e, i);
            }
        }
        if (format_ == Format::ascii) skip_space();
        std::vector<float> uvs;
        if (have_uv && !tris.empty()) {
            uvs.resize(2 * tris.size());
            for (size_t i = 0; i < tris.size(); ++i) {
                uvs[2 * i] = texcoords[2 * size_t(tris[i])];
                uvs[2 * i + 1] = texcoords[2 * size_t(tris[i]) + 1];
            }
        }
        if (tris.empty()) fail("has no triangles");
        return Mesh::from_arrays(verts.data(), verts.size() / 3, tris.data(), tris.size() / 3, name_,
                                 uvs.empty() ? nullptr : uvs.data());
    }

private:
    [[noreturn]] void fail(const std::string& what) const {
        throw Error("mesh '" + name_ + "'" + (what[0] == ':' ? "" : " ") + what);
    }
    [[noreturn]] void fail_header(size_t line, const std::string& what) const {
        throw Error("mesh '" + name_ + "': PLY header line " + std::to_string(line) + ": " + what);
    }

    void parse_header() {
        if (data_.compare(0, 4, "ply\n") != 0 && data_.compare(0, 5, "ply\r\n") != 0)
            fail("is not a PLY file (it does not start with 'ply')");
        size_t pos = 0, line_no = 0;
        bool have_format = false;
        while (true) {
            if (pos >= data_.size() || pos > kMaxHeader)
                fail(pos > kMaxHeader ? "has no 'end_header' in its first megabyte"
                                      : "has no 'end_header': the header is truncated");
            size_t eol = data_.find('\n', pos);
            if (eol == std::string::npos) fail("has no 'end_header': the header is truncated");
            std::string line = data_.substr(pos, eol - pos);
            pos = eol + 1;
            ++line_no;
            if (!line.empty() && line.back() == '\r') line.pop_back();
            if (line_no == 1) continue;  // "ply"
            std::istringstream ls(line);
            std::string kw;
            ls >> kw;
            if (kw.empty() || kw == "comment" || kw == "obj_info") continue;
            if (kw == "format") {
                std::string f, version;
                ls >> f >> version;
                if (f == "ascii") format_ = Format::ascii;
                else if (f == "binary_little_endian") format_ = Format::binary_le;
                else if (f == "binary_big_endian") format_ = Format::binary_be;
                else fail_header(line_no, "unknown format '" + f + "'");
                have_format = true;
            } else if (kw == "element") {
                Element e;
                std::string count;
                ls >> e.name >> count;
                char* end = nullptr;
                errno = 0;
                unsigned long long n = std::strtoull(count.c_str(), &end, 10);
                if (e.name.empty() || count.empty() || *end != '\0' || count[0] == '-' || errno == ERANGE)
                    fail_header(line_no, "'" + line + "' is not 'element NAME COUNT'");
                e.count = n;
                elements_.push_back(e);
            } else if (kw == "property") {
                if (elements_.empty()) fail_header(line_no, "property before any element");
                Property p;
                std::string type;
                ls >> type;
                if (type == "list") {
                    std::string count_type, item_type;
                    ls >> count_type >> item_type >> p.name;
                    p.count_type = type_of(count_type);
                    p.type = type_of(item_type);
                    if (p.count_type == Type::none || !is_integer(p.count_type) || p.type == Type::none)
                        fail_header(line_no, "'" + line + "' is not 'property list COUNTTYPE TYPE NAME'");
                } else {
                    p.type = type_of(type);
                    ls >> p.name;
                    if (p.type == Type::none) fail_header(line_no, "unknown property type '" + type + "'");
                }
                if (p.name.empty()) fail_header(line_no, "property without a name");
                elements_.back().props.push_back(p);
            } else if (kw == "end_header") {
                if (!have_format) fail_header(line_no, "no 'format' line before 'end_header'");
                body_ = pos;
                return;
            } else {
                fail_header(line_no, "unknown keyword '" + kw + "'");
            }
        }
    }

    // The smallest body the header allows, against the bytes present: a
    // header that declares more than the file can hold is refused before
    // anything is allocated for it.
    void check_sizes() const {
        const double available = double(data_.size() - body_);
        double needed = 0;
        for (const Element& e : elements_) {
            double per = 0;
            for (const Property& p : e.props) {
                if (format_ == Format::ascii) per += 2;  // a digit and a separator
                else per += double(size_of(p.is_list() ? p.count_type : p.type));
            }
            if (format_ == Format::ascii && per == 0) per = 1;  // an empty line
            needed += per * double(e.count);
            if (needed > available)
                fail("declares " + std::to_string(e.count) + " " + plural(e.name, e.count) +
                     ", more than its " + std::to_string(data_.size()) + " bytes can hold");
        }
        for (const Element& e : elements_)
            if (e.name == "vertex" && e.count > uint64_t(INT32_MAX))
                fail("declares " + std::to_string(e.count) + " vertices; at most " +
                     std::to_string(INT32_MAX) + " are supported");
    }

    // ---- the body ----

    void skip_space() {
        while (pos() < data_.size() && std::isspace(static_cast<unsigned char>(data_[pos()]))) ++cursor_;
    }
    size_t pos() const { return body_ + cursor_; }

    [[noreturn]] void truncated(const Element& e, uint64_t i) const {
        fail("ends early: " + e.name + " " + std::to_string(i) + " of " + std::to_string(e.count) +
             " is missing or incomplete");
    }

    // One number as double; integers are exact up to 2^53.
    double number(Type t, const Element& e, uint64_t i) {
        if (format_ == Format::ascii) {
            skip_space();
            if (pos() >= data_.size()) truncated(e, i);
            const char* start = data_.c_str() + pos();
            char* end = nullptr;
            double v = std::strtod(start, &end);
            if (end == start) {
                std::string word(start, std::min<size_t>(20, std::strcspn(start, " \t\r\n")));
                fail("line " + std::to_string(line_of(pos())) + ": cannot read '" + word + "' as a number");
            }
            if (is_integer(t) && v != std::floor(v))
                fail("line " + std::to_string(line_of(pos())) + ": '" + std::string(start, size_t(end - start)) +
                     "' is not a whole number");
            cursor_ += size_t(end - start);
            return v;
        }
        const size_t n = size_of(t);
        if (pos() + n > data_.size()) truncated(e, i);
        unsigned char b[8];
        std::memcpy(b, data_.data() + pos(), n);
        cursor_ += n;
        const bool little = format_ == Format::binary_le;
        if (little != host_little()) std::reverse(b, b + n);
        switch (t) {
            case Type::i8: { int8_t v; std::memcpy(&v, b, 1); return v; }
            case Type::u8: return b[0];
            case Type::i16: { int16_t v; std::memcpy(&v, b, 2); return v; }
            case Type::u16: { uint16_t v; std::memcpy(&v, b, 2); return v; }
            case Type::i32: { int32_t v; std::memcpy(&v, b, 4); return v; }
            case Type::u32: { uint32_t v; std::memcpy(&v, b, 4); return v; }
            case Type::f32: { float v; std::memcpy(&v, b, 4); return v; }
            case Type::f64: { double v; std::memcpy(&v, b, 8); return v; }
            default: return 0;
        }
    }

    static bool host_little() {
        const uint16_t one = 1;
        unsigned char c;
        std::memcpy(&c, &one, 1);
        return c == 1;
    }

    size_t line_of(size_t offset) const {
        return size_t(std::count(data_.begin(), data_.begin() + ptrdiff_t(offset), '\n')) + 1;
    }

    uint64_t list_count(const Property& p, const Element& e, uint64_t i) {
        double c = number(p.count_type, e, i);
        if (!(c >= 0) || c > 1e6)
            fail(e.name + " " + std::to_string(i) + " has a list of " + std::to_string(int64_t(c)) +
                 " entries");
        return uint64_t(c);
    }

    void skip_element(const Element& e, uint64_t i) {
        for (const Property& p : e.props) {
            uint64_t n = p.is_list() ? list_count(p, e, i) : 1;
            for (uint64_t k = 0; k < n; ++k) number(p.type, e, i);
        }
    }

    void read_vertices(const Element& e, std::vector<float>& verts, std::vector<float>& texcoords,
                       bool& have_uv) {
        int xyz[3] = {-1, -1, -1}, uv[2] = {-1, -1};
        for (size_t k = 0; k < e.props.size(); ++k) {
            const Property& p = e.props[k];
            if (p.is_list()) continue;
            const std::string& n = p.name;
            if (n == "x") xyz[0] = int(k);
            if (n == "y") xyz[1] = int(k);
            if (n == "z") xyz[2] = int(k);
            if (n == "u" || n == "s" || n == "texture_u" || n == "texture_s") uv[0] = int(k);
            if (n == "v" || n == "t" || n == "texture_v" || n == "texture_t") uv[1] = int(k);
        }
        if (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0) fail("has vertices without x, y and z");
        have_uv = uv[0] >= 0 && uv[1] >= 0;
        verts.resize(3 * e.count);
        if (have_uv) texcoords.resize(2 * e.count);
        for (uint64_t i = 0; i < e.count; ++i) {
            for (size_t k = 0; k < e.props.size(); ++k) {
                const Property& p = e.props[k];
                if (p.is_list()) {
                    uint64_t n = list_count(p, e, i);
                    for (uint64_t j = 0; j < n; ++j) number(p.type, e, i);
                    continue;
                }
                double v = number(p.type, e, i);
                for (int c = 0; c < 3; ++c)
                    if (int(k) == xyz[c]) {
                        if (!std::isfinite(v) || std::fabs(v) > double(FLT_MAX))
                            fail(": vertex " + std::to_string(i) + " has a non-finite coordinate");
                        verts[3 * i + size_t(c)] = float(v);
                    }
                for (int c = 0; c < 2; ++c)
                    if (have_uv && int(k) == uv[c]) {
                        if (!std::isfinite(v) || std::fabs(v) > double(FLT_MAX))
                            fail(": vertex " + std::to_string(i) + " has a non-finite texture coordinate");
                        texcoords[2 * i + size_t(c)] = float(v);
                    }
            }
        }
    }

    void read_faces(const Element& e, size_t num_vertices, std::vector<int32_t>& tris) {
        int indices = -1;
        for (size_t k = 0; k < e.props.size(); ++k)
            if (e.props[k].is_list() && (e.props[k].name == "vertex_indices" || e.props[k].name == "vertex_index"))
                indices = int(k);
        if (indices < 0) fail("has faces without a 'vertex_indices' list");
        if (!is_integer(e.props[size_t(indices)].type)) fail("has face indices that are not integers");
        std::vector<int64_t> poly;
        for (uint64_t i = 0; i < e.count; ++i) {
            for (size_t k = 0; k < e.props.size(); ++k) {
                const Property& p = e.props[k];
                uint64_t n = p.is_list() ? list_count(p, e, i) : 1;
                if (int(k) != indices) {
                    for (uint64_t j = 0; j < n; ++j) number(p.type, e, i);
                    continue;
                }
                poly.clear();
                for (uint64_t j = 0; j < n; ++j) {
                    double v = number(p.type, e, i);
                    if (v < 0 || v >= double(num_vertices))
                        fail(": face " + std::to_string(i) + " has vertex index " +
                             std::to_string(int64_t(v)) + " out of range (" + std::to_string(num_vertices) +
                             " vertices)");
                    poly.push_back(int64_t(v));
                }
                if (poly.size() < 3)   // as an OBJ face is: the file is broken, not a triangle degenerate
                    fail(": face " + std::to_string(i) + " has fewer than 3 vertices (" + std::to_string(poly.size()) +
                         ")");
                for (size_t j = 1; j + 1 < poly.size(); ++j) {
                    tris.push_back(int32_t(poly[0]));
                    tris.push_back(int32_t(poly[j]));
                    tris.push_back(int32_t(poly[j + 1]));
                }
            }
        }
    }

    const std::string& data_;
    const std::string& name_;
    Format format_ = Format::ascii;
    std::vector<Element> elements_;
    size_t body_ = 0, cursor_ = 0;
};

}  // namespace

Mesh Mesh::parse_ply(const std::string& data, const std::string& name) {
    return Reader(data, name).read();
}

}  // namespace gammart
