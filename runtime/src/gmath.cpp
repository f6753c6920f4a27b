// The project's own float transcendental functions (see gamma/gmath.h).
// Each core is a template over the lane type: D = double (scalar) or d8
// (eight lanes), with M its mask (bool or l8) and L its 64-bit integers.
#include "gamma/gmath.h"

namespace gammart::gm {

namespace {

// ---- lane helpers: the same operation for one lane and for eight ----

inline double widen(float x) { return double(x); }
inline d8 widen(f8 x) { return __builtin_convertvector(x, d8); }
inline float narrow(double x) { return float(x); }
inline f8 narrow(d8 x) { return __builtin_convertvector(x, f8); }
inline int64_t bits(double x) {
    int64_t b;
    std::memcpy(&b, &x, sizeof b);
    return b;
}
inline l8 bits(d8 x) { return reinterpret_cast<l8>(x); }
inline double from_bits(int64_t b) {
    double x;
    std::memcpy(&x, &b, sizeof x);
    return x;
}
inline d8 from_bits(l8 b) { return reinterpret_cast<d8>(b); }
inline int64_t to_int(double x) { return int64_t(x); }  // x integral, |x| < 2^52
// (by the bits of x + 1.5 * 2^52, whose low bits are then the integer: a
// conversion instruction for 64-bit lanes needs AVX-512, and without it GCC
// converts lane by lane)
inline l8 to_int(d8 x) { return reinterpret_cast<l8>(x + 0x1.8p52) - reinterpret_cast<l8>(d8{} + 0x1.8p52); }
inline double to_double(int64_t x) { return double(x); }
inline d8 to_double(l8 x) { return __builtin_convertvector(x, d8); }
inline double sel(bool m, double a, double b) { return m ? a : b; }
inline d8 sel(l8 m, d8 a, d8 b) { return m ? a : b; }
inline bool both(bool a, bool b) { return a && b; }
inline l8 both(l8 a, l8 b) { return a & b; }
inline bool either(bool a, bool b) { return a || b; }
inline l8 either(l8 a, l8 b) { return a | b; }
inline bool invert(bool a) { return !a; }
inline l8 invert(l8 a) { return ~a; }
inline bool odd(int64_t k) { return (k & 1) != 0; }
inline l8 odd(l8 k) { return (k & 1) != 0; }
inline bool signbit(double x) { return bits(x) < 0; }
inline l8 signbit(d8 x) { return bits(x) < 0; }

constexpr int64_t kSignBit = INT64_MIN;
constexpr double kInf = __builtin_inf();
constexpr double kNaN = __builtin_nan("");

template <class D>
D fabs(D x) {
    return from_bits(bits(x) & ~kSignBit);
}

// x rounded to the nearest integer (ties to even) for |x| < 2^51, by the
// addition of 1.5 * 2^52 (round-to-nearest mode; no fast-math).
template <class D>
D rint(D x) {
    return (x + 0x1.8p52) - 0x1.8p52;
}

// a / b rounded once at compile time.  The build's -frounding-math keeps an
// inexact quotient of two literals as a division at run time (it cannot
// know the rounding mode); as the initializer of a constexpr variable it is
// folded in round-to-nearest, the mode the runtime always runs in, so the
// series' coefficients are the same doubles without a division per term.
template <int64_t A, int64_t B>
constexpr double kQuotient = double(A) / double(B);

// ---- exp ----

// e^t for finite t in [-200, 200], relative error ~1e-16.
template <class D>
D exp_core(D t) {
    const D k = rint(t * 1.4426950408889634074);  // t / ln 2
    // ln 2 in two parts, the first with 32 significant bits: k * kLn2Hi is exact
    const D r = (t - k * 0x1.62e42fee00000p-1) - k * 0x1.a39ef35793c76p-33;  // |r| <= 0.347
    // Taylor series to r^13 (the next term is below 2^-57 relative)
    D p = D{} + (kQuotient<1, 6227020800>);
    p = p * r + kQuotient<1, 479001600>;
    p = p * r + kQuotient<1, 39916800>;
    p = p * r + kQuotient<1, 3628800>;
    p = p * r + kQuotient<1, 362880>;
    p = p * r + kQuotient<1, 40320>;
    p = p * r + kQuotient<1, 5040>;
    p = p * r + kQuotient<1, 720>;
    p = p * r + kQuotient<1, 120>;
    p = p * r + kQuotient<1, 24>;
    p = p * r + kQuotient<1, 6>;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    return p * from_bits((to_int(k) + 1023) << 52);  // |k| <= 289: a normal power of two
}

// e^t for any double t (NaN stays NaN; large |t| saturate to e^+-200,
// beyond a float's range).
template <class D>
D exp_any(D t) {
    const auto nan = t != t;
    D s = sel(nan, D{} + 0.0, t);
    s = sel(s > 200.0, D{} + 200.0, s);
    s = sel(s < -200.0, D{} - 200.0, s);
    return sel(nan, t, exp_core(s));
}

// ---- log ----

// ln a for a positive, finite, normal double; relative error ~1e-16.
template <class D>
D log_core(D a) {
    const auto b = bits(a);
    const auto e = (b >> 52) - 1023;
    D m = from_bits((b & 0x000fffffffffffffLL) | 0x3ff0000000000000LL);  // [1, 2)
    const auto big = m > 1.4142135623730951;
    m = sel(big, m * 0.5, m);                                     // [sqrt(2)/2, sqrt(2)]
    const D ed = to_double(e) + sel(big, D{} + 1.0, D{} + 0.0);
    // ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.1716: series to s^19
    const D s = (m - 1.0) / (m + 1.0);
    const D z = s * s;
    D p = D{} + (kQuotient<2, 19>);
    p = p * z + kQuotient<2, 17>;
    p = p * z + kQuotient<2, 15>;
    p = p * z + kQuotient<2, 13>;
    p = p * z + kQuotient<2, 11>;
    p = p * z + kQuotient<2, 9>;
    p = p * z + kQuotient<2, 7>;
    p = p * z + kQuotient<2, 5>;
    p = p * z + kQuotient<2, 3>;
    p = p * z + 2.0;
    return ed * 0x1.62e42fee00000p-1 + (s * p + ed * 0x1.a39ef35793c76p-33);
}

// ln a for any double a >= 0 or NaN (0 -> -inf, inf -> inf); negative a -> NaN.
template <class D>
D log_any(D a) {
    const auto ok = both(a > 0.0, a < kInf);
    D r = log_core(sel(ok, a, D{} + 1.0));
    r = sel(a == 0.0, D{} - kInf, r);
    r = sel(a == kInf, D{} + kInf, r);
    return sel(either(a < 0.0, a != a), D{} + kNaN, r);
}

// ---- pow (C99 F.10.4.4) ----

template <class D>
D pow_core(D x, D y) {
    const D ax = fabs(x), ay = fabs(y);
    const D e = exp_any(y * log_any(ax));
    // every float this large is an even integer (or inf); NaN too, so that no
    // NaN is converted to an integer (its result is NaN through e anyway)
    const auto huge = invert(ay < 16777216.0);
    const D yr = rint(sel(huge, D{} + 0.0, y));
    const auto integral = either(huge, yr == y);
    const auto is_odd = both(invert(huge), both(yr == y, odd(to_int(yr))));
    D r = sel(both(signbit(x), is_odd), -e, e);
    r = sel(both(both(x < 0.0, x != -kInf), invert(integral)), D{} + kNaN, r);
    r = sel(both(ax == 1.0, ay == kInf), D{} + 1.0, r);
    return sel(either(y == 0.0, x == 1.0), D{} + 1.0, r);
}

// ---- sin, cos, tan ----

constexpr double kTwoOverPi = 0x1.45f306dc9c883p-1;
constexpr double kPio2 = 0x1.921fb54442d18p+0;
constexpr double kPio2_1 = 0x1.921fb54400000p+0;  // 33 significant bits
constexpr double kPio2_2 = 0x1.0b4611a600000p-34;
constexpr double kPio2_3 = 0x1.3198a2e000000p-69;
constexpr double kPio2_3t = 0x1.b839a252049c1p-104;
constexpr double kSmall = 1048576.0;  // 2^20: Cody-Waite below, Payne-Hanek above

// x - k pi/2 for |x| < 2^20 (k < 2^20: each product with a 33-bit part is exact).
template <class D>
D reduce_small(D x, D& k) {
    k = rint(x * kTwoOverPi);
    return ((x - k * kPio2_1) - k * kPio2_2) - k * kPio2_3 - k * kPio2_3t;
}

// Bits of 2/pi after the binary point, most significant first.
constexpr uint32_t kTwoOverPiBits[] = {0x00000000u, 0xA2F9836Eu, 0x4E441529u, 0xFC2757D1u, 0xF534DDC0u, 0xDB629599u,
                                       0x3C439041u, 0xFE5163ABu, 0xDEBBC561u, 0xB7246E3Au, 0x424DD2E0u};

// Payne-Hanek: x - q pi/2 (q returned mod 4) for finite |x| >= 2^20, scalar.
// x = m 2^e (m < 2^24 an integer, e in [-3, 104]); the bits of 2/pi of
// weight 2^-i with i <= e - 2 add multiples of 4 to x 2/pi, so 96 bits from
// i = e - 1 give x 2/pi mod 4 with 94 fraction bits (truncation error < 2^-70).
double reduce_large(float x, int64_t& q) {
    uint32_t u;
    std::memcpy(&u, &x, sizeof u);
    const int e = int((u >> 23) & 0xff) - 150;
    const uint64_t m = (u & 0x7fffffu) | 0x800000u;
    // bit i of 2/pi (i >= 1) is bit (i + 31) of the table (a zero word first)
    const int first = e - 1 + 31;  // >= 27
    const int word = first / 32, shift = first % 32;
    unsigned __int128 w = 0;
    for (int j = 0; j < 4; ++j) w = (w << 32) | kTwoOverPiBits[word + j];
    // the 96 bits from `first`: drop `shift` leading bits, keep 96
    const unsigned __int128 window = (w << shift) >> 32;
    const unsigned __int128 p = window * m;  // < 2^120
    q = int64_t(p >> 94) & 3;
    __int128 f = __int128(p & ((((unsigned __int128)1) << 94) - 1));
    if (f >= (__int128(1) << 93)) {  // fraction >= 1/2: round to the next quadrant
        f -= __int128(1) << 94;
        q = (q + 1) & 3;
    }
    double r = double(f) * 0x1p-94 * kPio2;
    if (u >> 31) {
        r = -r;
        q = (4 - q) & 3;
    }
    return r;
}

// sin r and cos r for |r| <= pi/4 (+ a little): Taylor series to r^17 / r^16.
template <class D>
void sincos_poly(D r, D& s, D& c) {
    const D z = r * r;
    D ps = D{} + (-kQuotient<1, 355687428096000>);
    ps = ps * z + kQuotient<1, 1307674368000>;
    ps = ps * z - kQuotient<1, 6227020800>;
    ps = ps * z + kQuotient<1, 39916800>;
    ps = ps * z - kQuotient<1, 362880>;
    ps = ps * z + kQuotient<1, 5040>;
    ps = ps * z - kQuotient<1, 120>;
    ps = ps * z + kQuotient<1, 6>;
    s = r - (r * z) * ps;  // r - r^3/6 + ...; exact sign of zero kept (r = -0 gives -0)
    D pc = D{} + (kQuotient<1, 20922789888000>);
    pc = pc * z - kQuotient<1, 87178291200>;
    pc = pc * z + kQuotient<1, 479001600>;
    pc = pc * z - kQuotient<1, 3628800>;
    pc = pc * z + kQuotient<1, 40320>;
    pc = pc * z - kQuotient<1, 720>;
    pc = pc * z + kQuotient<1, 24>;
    pc = pc * z - 0.5;
    c = 1.0 + z * pc;
}

enum class Trig { Sin, Cos, Tan };

// The result from the reduced argument and the quadrant (q mod 4).
template <Trig F, class D, class L>
D trig_from(D r, L q) {
    D s, c;
    sincos_poly(r, s, c);
    const L qm = q & 3;
    if constexpr (F == Trig::Sin) {
        const D v = sel(odd(qm), c, s);
        return sel((qm & 2) != 0, -v, v);
    } else if constexpr (F == Trig::Cos) {
        const D v = sel(odd(qm), s, c);
        return sel(((qm + 1) & 2) != 0, -v, v);
    } else {
        return sel(odd(qm), -c / s, s / c);
    }
}

// sin(+-0) = tan(+-0) = +-0 (the series gives +0 for -0).
template <Trig F, class D>
D keep_zero(D x, D v) {
    if constexpr (F == Trig::Cos) return v;
    return sel(x == 0.0, x, v);
}

// sin and cos from the reduced argument r and quadrant q: trig_from's
// selections done without branches (the quadrant is random in the tracer's
// azimuths, so branches on it were mispredicted half the time), and the
// series evaluated once for both: the same values bit for bit.
template <class D, class L, class F>
void sincos_from(D xd, D r, L q, F& s, F& c) {
    D ps, pc;
    sincos_poly(r, ps, pc);
    const L swap = -(q & 1);                              // all ones in odd quadrants
    const L sin_sign = ((q >> 1) & 1) << 63, cos_sign = (((q + 1) >> 1) & 1) << 63;
    s = narrow(keep_zero<Trig::Sin>(xd, from_bits(((bits(ps) & ~swap) | (bits(pc) & swap)) ^ sin_sign)));
    c = narrow(from_bits(((bits(pc) & ~swap) | (bits(ps) & swap)) ^ cos_sign));
}

template <Trig F>
float trig(float x) {
    const double xd = x;
    if (fabs(xd) < kSmall) {
        double k;
        const double r = reduce_small(xd, k);
        return narrow(keep_zero<F>(xd, trig_from<F>(r, to_int(k))));
    }
    if (!(fabs(xd) < kInf)) return float(kNaN);
    int64_t q;
    const double r = reduce_large(x, q);
    return narrow(trig_from<F>(r, q));
}

template <Trig F>
f8 trig(f8 x) {
    const d8 xd = widen(x);
    const l8 small = fabs(xd) < kSmall;
    d8 k;
    const d8 r = reduce_small(sel(small, xd, d8{}), k);
    f8 out = narrow(keep_zero<F>(xd, trig_from<F>(r, to_int(k))));
    for (int j = 0; j < 8; ++j)
        if (!small[j]) out[j] = trig<F>(x[j]);  // large, inf or NaN: the scalar form
    return out;
}

// sin and cos of eight lanes from one reduction and one series each
// (large, infinite or NaN lanes by the scalar form).
void sincos8(f8 x, f8& s, f8& c) {
    const d8 xd = widen(x);
    const l8 small = fabs(xd) < kSmall;
    d8 k;
    const d8 r = reduce_small(sel(small, xd, d8{}), k);
    sincos_from(xd, r, to_int(k), s, c);
    for (int j = 0; j < 8; ++j)
        if (!small[j]) {
            float sj, cj;
            sincos(x[j], sj, cj);
            s[j] = sj;
            c[j] = cj;
        }
}

// ---- atan2 (C99 F.10.1.4) ----

// atan t for t in [0, 1]: t - c over 1 + t c with c in {0, 1/2, 1}, then
// the series to w^27 (|w| <= 1/4).
template <class D>
D atan_unit(D t) {
    const auto mid = t > 0.25, high = t > 0.75;
    const D c = sel(high, D{} + 1.0, sel(mid, D{} + 0.5, D{} + 0.0));
    const D base = sel(high, D{} + 0.78539816339744830962, sel(mid, D{} + 0.46364760900080611621, D{} + 0.0));
    const D w = (t - c) / (1.0 + t * c);
    const D z = w * w;
    D p = D{} + (-kQuotient<1, 27>);
    p = p * z + kQuotient<1, 25>;
    p = p * z - kQuotient<1, 23>;
    p = p * z + kQuotient<1, 21>;
    p = p * z - kQuotient<1, 19>;
    p = p * z + kQuotient<1, 17>;
    p = p * z - kQuotient<1, 15>;
    p = p * z + kQuotient<1, 13>;
    p = p * z - kQuotient<1, 11>;
    p = p * z + kQuotient<1, 9>;
    p = p * z - kQuotient<1, 7>;
    p = p * z + kQuotient<1, 5>;
    p = p * z - kQuotient<1, 3>;
    return base + (w + (w * z) * p);
}

template <class D>
D atan2_core(D y, D x) {
    const D a = fabs(y), b = fabs(x);
    const auto swap = a > b;
    const D hi = sel(swap, a, b), lo = sel(swap, b, a);
    D t = lo / hi;
    t = sel(hi == 0.0, D{} + 0.0, t);                        // atan2(+-0, +-0)
    t = sel(both(a == kInf, b == kInf), D{} + 1.0, t);       // atan2(+-inf, +-inf)
    D theta = atan_unit(t);                                  // in [0, pi/4]
    theta = sel(swap, kPio2 - theta, theta);                 // [0, pi/2]
    theta = sel(signbit(x), 2.0 * kPio2 - theta, theta);     // x < 0 or x = -0
    theta = sel(signbit(y), -theta, theta);
    return sel(either(x != x, y != y), D{} + kNaN, theta);
}

}  // namespace

float sin(float x) { return trig<Trig::Sin>(x); }
float cos(float x) { return trig<Trig::Cos>(x); }
float tan(float x) { return trig<Trig::Tan>(x); }
// sin and cos from one reduction: the same operations as sin(x) and cos(x)
// apart, so the same bits.
void sincos(float x, float& s, float& c) {
    const double xd = x;
    double r;
    int64_t q;
    if (fabs(xd) < kSmall) {
        double k;
        r = reduce_small(xd, k);
        q = to_int(k);
    } else if (!(fabs(xd) < kInf)) {
        s = c = float(kNaN);
        return;
    } else {
        r = reduce_large(x, q);
    }
    sincos_from(xd, r, q, s, c);
}
float atan2(float y, float x) { return narrow(atan2_core(widen(y), widen(x))); }
float exp(float x) { return narrow(exp_any(widen(x))); }
float log(float x) { return narrow(log_any(widen(x))); }
float pow(float x, float y) { return narrow(pow_core(widen(x), widen(y))); }

f8 sin(f8 x) { return trig<Trig::Sin>(x); }
f8 cos(f8 x) { return trig<Trig::Cos>(x); }
f8 tan(f8 x) { return trig<Trig::Tan>(x); }
void sincos(f8 x, f8& s, f8& c) { sincos8(x, s, c); }

namespace {
// The eight-lane form compiled for AVX2 (four doubles to a register; no
// fused multiply-add: -ffp-contract=off, and FMA is not enabled): the same
// operations in the same order as every other form, so the same bits.
__attribute__((target("avx2"), flatten)) void sincos8_avx2(const float* x, float* s, float* c) {
    f8 xv, sv, cv;
    std::memcpy(&xv, x, sizeof xv);
    sincos8(xv, sv, cv);
    std::memcpy(s, &sv, sizeof sv);
    std::memcpy(c, &cv, sizeof cv);
}
}  // namespace

void sincos_n(const float* x, float* s, float* c, size_t n) {
    static const bool avx2 = __builtin_cpu_supports("avx2");
    size_t i = 0;
    if (avx2) {
        for (; i + 8 <= n; i += 8) sincos8_avx2(x + i, s + i, c + i);
        if (i < n) {
            float xs[8] = {}, ss[8], cs[8];
            std::memcpy(xs, x + i, (n - i) * sizeof(float));
            sincos8_avx2(xs, ss, cs);
            std::memcpy(s + i, ss, (n - i) * sizeof(float));
            std::memcpy(c + i, cs, (n - i) * sizeof(float));
        }
        return;
    }
    for (; i < n; ++i) sincos(x[i], s[i], c[i]);
}
f8 atan2(f8 y, f8 x) { return narrow(atan2_core(widen(y), widen(x))); }
f8 exp(f8 x) { return narrow(exp_any(widen(x))); }
f8 log(f8 x) { return narrow(log_any(widen(x))); }
f8 pow(f8 x, f8 y) { return narrow(pow_core(widen(x), widen(y))); }

}  // namespace gammart::gm

extern "C" {
float gamma_sinf(float x) { return gammart::gm::sin(x); }
float gamma_cosf(float x) { return gammart::gm::cos(x); }
float gamma_tanf(float x) { return gammart::gm::tan(x); }
float gamma_atan2f(float y, float x) { return gammart::gm::atan2(y, x); }
float gamma_expf(float x) { return gammart::gm::exp(x); }
float gamma_logf(float x) { return gammart::gm::log(x); }
float gamma_powf(float x, float y) { return gammart::gm::pow(x, y); }
}

// Template code of OpenMesh and CGAL compiled into the extension (a feature
// edge test, the remesher's edge flips) calls the C library's double cos.
// This definition, hidden inside the extension, serves those calls, so the
// extension imports no transcendental function from the C library (a test
// checks `nm -D --undefined-only`).  Double precision: the same Cody-Waite
// reduction and series in double, within 2 double ulp for |x| < 2^20 (the
// angles those callers pass); NaN for |x| >= 2^51, inf and NaN.  (Named cos
// for the linker only: a C++ name with the assembler name "cos", hidden.)
__attribute__((visibility("hidden"))) double gamma_cos_for_libraries(double x) __asm__("cos");
double gamma_cos_for_libraries(double x) {
    using namespace gammart::gm;
    if (!(fabs(x) < 0x1p51)) return kNaN;
    double k;
    const double r = reduce_small(x, k);
    return trig_from<Trig::Cos>(r, to_int(k));
}
