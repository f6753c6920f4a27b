// Counter-based Philox4x32-10 (Salmon et al. 2011, Random123).
#pragma once
#include <array>
#include <cstdint>

namespace gammart {

using Philox4 = std::array<uint32_t, 4>;

inline Philox4 philox4x32_10(Philox4 ctr, std::array<uint32_t, 2> key) {
    constexpr uint32_t M0 = 0xD2511F53u, M1 = 0xCD9E8D57u;
    constexpr uint32_t W0 = 0x9E3779B9u, W1 = 0xBB67AE85u;
#pragma GCC unroll 10
    for (int round = 0; round < 10; ++round) {
        if (round > 0) { key[0] += W0; key[1] += W1; }
        const uint64_t p0 = uint64_t(M0) * ctr[0];
        const uint64_t p1 = uint64_t(M1) * ctr[2];
        const uint32_t hi0 = uint32_t(p0 >> 32), lo0 = uint32_t(p0);
        const uint32_t hi1 = uint32_t(p1 >> 32), lo1 = uint32_t(p1);
        ctr = {hi1 ^ ctr[1] ^ key[0], lo1, hi0 ^ ctr[3] ^ key[1], lo0};
    }
    return ctr;
}

// u32 -> float in [0,1): top 24 bits times 2^-24 (exact in float).
inline float u01(uint32_t x) { return float(x >> 8) * (1.0f / 16777216.0f); }

// Stream of uniform numbers for one (iteration, index) pair.  Counter =
// (iteration, index_lo, index_hi, draw); every block of 4 outputs consumes one
// `draw` value, outputs are used in order 0..3.
class PhiloxStream {
public:
    PhiloxStream() : PhiloxStream(0, 0, 0) {}  // a placeholder, to be assigned over
    PhiloxStream(uint64_t seed, uint32_t iteration, uint64_t index)
        : key_{uint32_t(seed), uint32_t(seed >> 32)},
          iter_(iteration), lo_(uint32_t(index)), hi_(uint32_t(index >> 32)) {}
    uint32_t next_u32() {
        if (pos_ == 4) {
            block_ = philox4x32_10({iter_, lo_, hi_, draw_++}, key_);
            pos_ = 0;
        }
        return block_[pos_++];
    }
    float next() { return u01(next_u32()); }
    // A fresh stream whose first block (draw 0) its owner computed itself
    // (philox4x32_10 of the same counter, e.g. many streams' at once) and
    // used all four outputs of: the stream continues with draw 1.
    void skip_first_block() {
        draw_ = 1;
        pos_ = 4;
    }
    uint32_t draws() const { return draw_; }

private:
    std::array<uint32_t, 2> key_;
    uint32_t iter_, lo_, hi_;
    uint32_t draw_ = 0;
    Philox4 block_{};
    int pos_ = 4;
};

// Iteration value reserved for the surfel-sampling stream.
constexpr uint32_t kSamplingIteration = 0xFFFFFFFFu;

}  // namespace gammart
