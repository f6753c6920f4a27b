#pragma once
#include <cstdio>
#include <stdexcept>
#include <string>

namespace gammart {

// A message quotes the user's bytes (a word of a mesh file, a path): bytes
// that are not valid UTF-8, and control characters, are shown as \xNN, so
// the message stays one line that Python can decode (nanobind turns it into
// a str; invalid UTF-8 there became a UnicodeDecodeError instead of the
// message, found by tests/fuzz_meshes.py).
inline std::string printable_message(const std::string& s) {
    std::string out;
    out.reserve(s.size());
    size_t i = 0;
    while (i < s.size()) {
        const unsigned char c = static_cast<unsigned char>(s[i]);
        const size_t len = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
        bool ok = len > 0 && i + len <= s.size();
        for (size_t k = 1; ok && k < len; ++k) ok = (static_cast<unsigned char>(s[i + k]) & 0xC0) == 0x80;
        if (ok) {
            const unsigned char c1 = len > 1 ? static_cast<unsigned char>(s[i + 1]) : 0;
            if (len == 1) ok = c >= 0x20 && c != 0x7F;
            else if (len == 2) ok = c >= 0xC2;                                   // no overlong forms
            else if (len == 3) ok = !(c == 0xE0 && c1 < 0xA0) && !(c == 0xED && c1 >= 0xA0);  // nor surrogates
            else ok = c <= 0xF4 && !(c == 0xF0 && c1 < 0x90) && !(c == 0xF4 && c1 >= 0x90);
        }
        if (ok) {
            out.append(s, i, len);
            i += len;
        } else {
            char hex[5];
            std::snprintf(hex, sizeof hex, "\\x%02X", c);
            out += hex;
            ++i;
        }
    }
    return out;
}

// Input/config error; mapped to Python ValueError.  Messages are one line of
// valid UTF-8 (printable_message).
class Error : public std::runtime_error {
public:
    explicit Error(const std::string& msg) : std::runtime_error(printable_message(msg)) {}
};

}  // namespace gammart
