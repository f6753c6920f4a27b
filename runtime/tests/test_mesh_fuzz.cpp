// A deterministic mutation fuzz of the PLY and OBJ readers (Mesh::parse_ply,
// Mesh::parse_obj), run under AddressSanitizer and UBSan by `make
// runtime-tests`: a fixed seed and a fixed budget of mutants of small valid
// files -- truncated, bytes flipped, spans cut or repeated, tokens inserted,
// declared counts and indices made huge, ASCII and binary formats swapped,
// property types changed.  Every mutant must end in a mesh or a
// gammart::Error whose message is one line of valid UTF-8: any other
// exception, a sanitizer report, a crash or a hang is a failure.

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "helpers.h"

using gammart::Mesh;

namespace {

template <typename T>
void put(std::string& out, T value, bool big_endian) {
    char b[sizeof(T)];
    std::memcpy(b, &value, sizeof(T));
    if (big_endian) std::reverse(b, b + sizeof(T));
    out.append(b, sizeof(T));
}

const char* kAsciiPly =
    "ply\nformat ascii 1.0\ncomment a tetrahedron\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nproperty float u\nproperty float v\nelement face 4\n"
    "property list uchar int vertex_indices\nend_header\n"
    "0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n0 0 1 1 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";

// A tetrahedron (one quad-split face) in binary PLY, with a double z, an
// int list count and a trailing element the reader skips.
std::string binary_ply(bool big_endian) {
    std::string s = std::string("ply\nformat ") + (big_endian ? "binary_big_endian" : "binary_little_endian") +
                    " 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty double z\n"
                    "element face 3\nproperty list int uint vertex_indices\n"
                    "element edge 1\nproperty short vertex1\nproperty ushort vertex2\nend_header\n";
    const float v[5][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0.5f, 0.5f, 1}};
    for (auto& p : v) {
        put(s, p[0], big_endian);
        put(s, p[1], big_endian);
        put(s, double(p[2]), big_endian);
    }
    const std::vector<std::vector<uint32_t>> faces = {{0, 3, 2, 1}, {0, 1, 4}, {1, 2, 4}};
    for (auto& f : faces) {
        put(s, int32_t(f.size()), big_endian);
        for (uint32_t i : f) put(s, i, big_endian);
    }
    put(s, int16_t(0), big_endian);
    put(s, uint16_t(1), big_endian);
    return s;
}

const char* kObj =
    "# a tetrahedron\nmtllib none.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1 1.0\nvt 0 0\nvt 1 0\nvt 0 1\n"
    "vn 0 0 1\ng front\no body\nusemtl paint\nf 1/1/1 3/3/1 2/2/1\nf 1/1 2/2 4/3\ns off\nf -4 -1 -2\n"
    "f 2//1 3//1 4//1\n";

const char* kObjQuads = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\r\nf 1 2 3 4\r\nf 1 2 5\nf 2 3 5\nf 3 4 5\n";

const char* kTokens[] = {"\n", " ", "\r\n", "-1", "0", "4294967295", "2147483648", "99999999999", "nan", "inf",
                         "1e39", "-1e39", "end_header\n", "element face 3\n", "element vertex 2\n",
                         "property list uchar int vertex_indices\n", "property float x\n", "\xff", "\xc3", "\0",
                         "/", "//", "f ", "v ", "vt ", "g \xe9\n", "ply\n"};
const char* kHugeCounts[] = {"0", "1", "2147483647", "2147483648", "4294967295", "4294967296",
                             "100000000000", "18446744073709551615", "99999999999999999999999", "-1", "3e9"};
const char* kFormats[] = {"ascii", "binary_little_endian", "binary_big_endian"};
const char* kTypes[] = {"char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8",
                        "int16", "uint16", "int32", "uint32", "float32", "float64"};

// Replaces the word after the n-th occurrence (of any) of `keys` with `value`.
bool replace_after(std::string& s, const std::vector<std::string>& keys, std::mt19937_64& rng,
                   const std::string& value) {
    std::vector<std::pair<size_t, size_t>> at;  // (start, end) of the word after a key
    for (const auto& key : keys)
        for (size_t p = s.find(key); p != std::string::npos; p = s.find(key, p + 1)) {
            const size_t b = p + key.size();
            size_t e = b;
            while (e < s.size() && s[e] != ' ' && s[e] != '\n' && s[e] != '\r') ++e;
            at.emplace_back(b, e);
        }
    if (at.empty()) return false;
    const auto [b, e] = at[rng() % at.size()];
    s.replace(b, e - b, value);
    return true;
}

void mutate(std::string& s, bool ply, std::mt19937_64& rng) {
    const int edits = 1 + int(rng() % 3);
    for (int k = 0; k < edits; ++k) {
        const size_t at = rng() % (s.size() + 1);
        switch (rng() % 9) {
            case 0: s.resize(at); break;                                      // truncate
            case 1:                                                           // flip bytes
                for (int f = 0, n = 1 + int(rng() % 4); f < n && !s.empty(); ++f) s[rng() % s.size()] ^= char(1 + rng() % 255);
                break;
            case 2: s.erase(at, 1 + rng() % 24); break;                      // cut a span
            case 3: s.insert(at, kTokens[rng() % (sizeof kTokens / sizeof *kTokens)]); break;
            case 4: {                                                         // repeat a span
                const std::string span = s.substr(at, 1 + rng() % 64);
                for (int r = 0, n = 1 + int(rng() % 8); r < n; ++r) s.insert(at, span);
                break;
            }
            case 5: {                                                         // a huge count or index
                const std::string value = kHugeCounts[rng() % (sizeof kHugeCounts / sizeof *kHugeCounts)];
                if (ply) replace_after(s, {"element vertex ", "element face ", "element edge "}, rng, value);
                else replace_after(s, {"f ", "/", " "}, rng, value);
                break;
            }
            case 6:                                                           // ASCII <-> binary
                if (ply) replace_after(s, {"format "}, rng, kFormats[rng() % 3]);
                else s.insert(at, std::string(1 + rng() % 8, char(rng() % 256)));
                break;
            case 7:                                                           // property types
                if (ply) replace_after(s, {"property ", "list "}, rng, kTypes[rng() % (sizeof kTypes / sizeof *kTypes)]);
                else replace_after(s, {"v ", "vt "}, rng, kHugeCounts[rng() % 4]);
                break;
            default: {                                                        // swap two lines
                const size_t a = s.find('\n', rng() % (s.size() + 1)), b = s.find('\n', rng() % (s.size() + 1));
                if (a == std::string::npos || b == std::string::npos || a == b) break;
                const size_t lo = std::min(a, b) + 1, hi = std::max(a, b) + 1;
                const size_t lo_end = s.find('\n', lo);
                if (lo_end == std::string::npos || lo_end + 1 > hi) break;
                std::string first = s.substr(lo, lo_end + 1 - lo);
                const size_t hi_end = s.find('\n', hi);
                if (hi_end == std::string::npos) break;
                std::string second = s.substr(hi, hi_end + 1 - hi);
                s.replace(hi, second.size(), first);
                s.replace(lo, first.size(), second);
                break;
            }
        }
    }
}

bool valid_one_line(const std::string& msg) {
    return !msg.empty() && gammart::printable_message(msg) == msg;   // no control bytes, valid UTF-8
}

}  // namespace

TEST(MeshFuzz, ErrorMessagesAreOneLineOfValidUtf8) {
    EXPECT_EQ(gammart::printable_message("a\xff" "b\nc\xc3\xa9"), "a\\xFFb\\x0Ac\xc3\xa9");
    EXPECT_EQ(gammart::printable_message("\xed\xa0\x80"), "\\xED\\xA0\\x80");   // a surrogate
    EXPECT_EQ(gammart::printable_message("\xc0\xaf"), "\\xC0\\xAF");            // overlong '/'
    const std::string msg = gamma_test::expect_error(
        [] { Mesh::parse_ply("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 0\nproperty list uchar int vertex_indices\n"
                             "end_header\n0 \xff\xfe 0\n", "m\xe9.ply"); });
    EXPECT_TRUE(valid_one_line(msg)) << msg;
    EXPECT_NE(msg.find("m\\xE9.ply"), std::string::npos) << msg;
}

TEST(MeshFuzz, MutantsEndInAMeshOrAnError) {
    const std::vector<std::pair<std::string, bool>> seeds = {
        {kAsciiPly, true}, {binary_ply(false), true}, {binary_ply(true), true}, {kObj, false}, {kObjQuads, false}};
    for (const auto& [text, ply] : seeds) {   // the seeds themselves are valid
        const Mesh m = ply ? Mesh::parse_ply(text, "seed.ply") : Mesh::parse_obj(text, "seed.obj");
        ASSERT_GT(m.num_triangles(), 0u);
    }
    std::mt19937_64 rng(2026);
    const int kMutants = 6000;
    int meshes = 0, errors = 0, failures = 0;
    for (int n = 0; n < kMutants && failures < 5; ++n) {
        const auto& [text, ply] = seeds[rng() % seeds.size()];
        std::string s = text;
        mutate(s, ply, rng);
        try {
            const Mesh m = ply ? Mesh::parse_ply(s, "f.ply") : Mesh::parse_obj(s, "f.obj");
            EXPECT_GT(m.num_triangles(), 0u);
            EXPECT_EQ(m.triangles.size(), 3 * m.num_triangles());
            for (int32_t i : m.triangles) ASSERT_TRUE(i >= 0 && size_t(i) < m.num_vertices());
            ++meshes;
        } catch (const gammart::Error& err) {
            const std::string msg = err.what();
            if (!valid_one_line(msg) || msg.find(ply ? "f.ply" : "f.obj") == std::string::npos) {
                ADD_FAILURE() << "mutant " << n << ": message '" << gammart::printable_message(msg) << "'";
                ++failures;
            }
            ++errors;
        } catch (const std::exception& err) {
            ADD_FAILURE() << "mutant " << n << " threw " << err.what() << " (not gammart::Error) on '"
                          << gammart::printable_message(s) << "'";
            ++failures;
        }
    }
    EXPECT_EQ(failures, 0);
    EXPECT_GT(meshes, kMutants / 10);   // the mutants reach the bodies, not only the headers
    EXPECT_GT(errors, kMutants / 4);
}
