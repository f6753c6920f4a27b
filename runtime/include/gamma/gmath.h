// The project's own float transcendental functions: sin, cos, tan, atan2,
// exp, log, pow.  The runtime and the compiled kernels (through the C
// exports gamma_expf, ... of gmath.cpp) use these and never the C library's,
// so results are the same bits on every machine and C library.
//
// Each function is written once, as a template over its lane type: the
// scalar form (float) and the vector form (f8, eight floats in a GCC/Clang
// portable vector) are the same IEEE operations in the same order, so they
// give the same bits lane for lane.  The build compiles with
// -ffp-contract=off and never with fast-math (a fused or reassociated
// operation would break that).
//
// Method: the float argument is widened to double (exactly; float denormals
// become normal doubles) and the function is evaluated in double with an
// error far below a float ulp, then rounded once to float.  Error bounds,
// measured against a 64-bit-mantissa (long double) reference by
// runtime/tests/test_gmath.cpp over every float of a dense sweep: at most
// 0.5 ulp + 2^-20 ulp (that is, the result is the correctly rounded value
// except where the exact value lies within ~1e-6 ulp of a rounding
// boundary).  Special values follow C99 Annex F (sin/cos/tan of inf or NaN
// is NaN; sin(-0) = -0; log(0) = -inf; log(x < 0) = NaN; pow per F.10.4.4;
// atan2 per F.10.1.4).
//
// Argument reduction for sin/cos/tan: |x| < 2^20 by Cody-Waite (pi/2 in
// three 33-bit parts and a fourth, exact products); larger |x| by
// Payne-Hanek (96 bits of 2/pi from the right place, scalar; vector lanes
// with large arguments take the scalar function).
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace gammart::gm {

typedef float f8 __attribute__((vector_size(32)));
typedef double d8 __attribute__((vector_size(64)));
typedef int64_t l8 __attribute__((vector_size(64)));

float sin(float x);
float cos(float x);
float tan(float x);
void sincos(float x, float& s, float& c);
float atan2(float y, float x);
float exp(float x);
float log(float x);
float pow(float x, float y);

f8 sin(f8 x);
f8 cos(f8 x);
f8 tan(f8 x);
void sincos(f8 x, f8& s, f8& c);
f8 atan2(f8 y, f8 x);
f8 exp(f8 x);
f8 log(f8 x);
f8 pow(f8 x, f8 y);

// sincos of x[0, n) into s and c: eight at a time where the CPU has AVX2
// (the eight-lane form compiled for it), else one at a time; the same bits
// either way.
void sincos_n(const float* x, float* s, float* c, size_t n);

}  // namespace gammart::gm

// C linkage for the compiled kernels (bound into the JIT and the cached
// shared objects) and the reference interpreter (through ctypes).
extern "C" {
__attribute__((visibility("default"))) float gamma_sinf(float x);
__attribute__((visibility("default"))) float gamma_cosf(float x);
__attribute__((visibility("default"))) float gamma_tanf(float x);
__attribute__((visibility("default"))) float gamma_atan2f(float y, float x);
__attribute__((visibility("default"))) float gamma_expf(float x);
__attribute__((visibility("default"))) float gamma_logf(float x);
__attribute__((visibility("default"))) float gamma_powf(float x, float y);
}
