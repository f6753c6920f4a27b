// Eight sines and cosines at once, bit for bit what the C library's sinf /
// cosf give on x86-64 with glibc's FMA variant (__sincosf_fma: glibc picks it
// where the processor has AVX2 and FMA).  The environment emission needs two
// angles per gamma-ton and sincosf was its largest cost; its outputs must not
// change, so this repeats glibc's own algorithm (the reduction by pi/2 in
// double precision, its polynomials and constants, the same fused
// multiply-adds in the same order) rather than using a vector math library
// whose last bits differ.  Used only where a check at first use finds it
// equal to std::sin / std::cos (another C library falls back to those).
#pragma once

namespace gammart {

// True when sincosf8 may be used: the processor has AVX2 and FMA, and at
// first use sincosf8 gave std::sin's and std::cos's bits for 4,097 angles
// 2 pi k / 4096 as the emission forms them and the smallest ones.
bool sincosf8_matches_libm();

// sin_out[j], cos_out[j] = std::sin(x[j]), std::cos(x[j]) for j < 8, bit for
// bit.  Only where sincosf8_matches_libm() is true.  Lanes with |x| >= 120 or
// not finite take the scalar calls.
void sincosf8(const float x[8], float sin_out[8], float cos_out[8]);

}  // namespace gammart
