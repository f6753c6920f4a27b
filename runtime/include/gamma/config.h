#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "gamma_abi.h"

namespace gammart {

struct TonType {
    float ks = 0, kp = 0, kf = 0;
    std::vector<float> initial_carry;
};

struct Source {
    std::string kind;  // "point" | "sphere" | "hemisphere"
    int ton_type = 0;
    int64_t count = 0;
    std::array<float, 3> position{0, 0, 0};
};

struct TransportEntry {
    int event = 0, ton_type = 0, surface = 0;
    uint64_t address = 0;
    bool writes_surface = false;
};

struct UpdateEntry {
    int surface = 0;
    uint64_t address = 0;
};

struct Config {
    int64_t surfels = 100000;
    uint64_t seed = 1;
    int threads = 1;             // <= 0: all hardware threads
    int max_interactions = 100;
    int row_width = GAMMA_ROW_HEADER;
    std::vector<std::vector<float>> surface_rows;  // initial row per surface id
    std::vector<int32_t> triangle_surface;         // per triangle; empty -> all 0
    std::vector<TonType> ton_types;
    std::vector<Source> sources;
    std::vector<TransportEntry> transports;
    std::vector<UpdateEntry> updates;

    int add_ton_type(float ks, float kp, float kf, std::vector<float> carry) {
        ton_types.push_back({ks, kp, kf, std::move(carry)});
        return int(ton_types.size()) - 1;
    }
    void add_source(std::string kind, int ton_type, int64_t count, std::array<float, 3> pos = {0, 0, 0}) {
        sources.push_back({std::move(kind), ton_type, count, pos});
    }
    void set_transport(int event, int ton_type, int surface, uint64_t address, bool writes) {
        transports.push_back({event, ton_type, surface, address, writes});
    }
    void set_update(int surface, uint64_t address) { updates.push_back({surface, address}); }
};

}  // namespace gammart
