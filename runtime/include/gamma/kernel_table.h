// The compiled kernels of a run, indexed for the passes that call them:
// transport kernels per (event, ton type, surface), update and appearance
// kernels per surface.  Also the random-key mixing the kernels' random()
// relies on (constants from the generated ABI header).
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/config.h"
#include "gamma_abi.h"

namespace gammart {

struct TransportSlot {
    GammaTransportKernel fn = nullptr;
    bool writes = false;  // logs a delta of the property columns
    int event = 0, ton_type = 0, surface = 0;
};

struct KernelTable {
    int n_types = 1, n_surfaces = 0;
    std::vector<TransportSlot> transport;           // [event][type][surface]
    std::vector<GammaUpdateKernel> update;          // [surface]
    std::vector<GammaAppearanceKernel> appearance;  // [surface]
    std::vector<uint8_t> displaces;                 // [surface]: its appearance assigns `displacement`

    // Validates the entries of `c` against its ton types and surfaces (throws
    // gammart::Error); later entries for the same slot win.
    static KernelTable from_config(const Config& c);

    const TransportSlot& slot(int event, int type, int surface) const {
        return transport[(size_t(event) * size_t(n_types) + size_t(type)) * size_t(n_surfaces) + size_t(surface)];
    }
    bool any_update() const {
        for (auto fn : update)
            if (fn) return true;
        return false;
    }
};

// splitmix64's finaliser, with the constants of the generated header (the
// compiled random() uses the same function).
inline uint64_t mix64(uint64_t z) {
    z += GAMMA_RANDOM_GOLDEN;
    z = (z ^ (z >> 30)) * GAMMA_RANDOM_MIX0;
    z = (z ^ (z >> 27)) * GAMMA_RANDOM_MIX1;
    return z ^ (z >> 31);
}

inline void set_random_key(GammaContext& ctx, uint64_t key) {
    ctx.random_key[0] = uint32_t(key);
    ctx.random_key[1] = uint32_t(key >> 32);
}

}  // namespace gammart
