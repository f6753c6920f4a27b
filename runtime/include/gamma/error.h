#pragma once
#include <stdexcept>
#include <string>

namespace gammart {
// Input/config error; mapped to Python ValueError.  Messages are one line.
class Error : public std::runtime_error {
public:
    explicit Error(const std::string& msg) : std::runtime_error(msg) {}
};
}  // namespace gammart
