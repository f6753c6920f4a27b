// The project's own math (gamma/gmath.h): error bounds against a long double
// (64-bit mantissa) reference, special values per C99 Annex F, and the
// vector form equal to the scalar form bit for bit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "gamma/gmath.h"
#include "gamma/philox.h"

using namespace gammart;

namespace {

// The documented bound (gmath.h): the correctly rounded result, except
// within a hair of a rounding boundary.
constexpr double kMaxUlp = 0.5 + 1.0 / (1 << 20);

float from_bits(uint32_t b) {
    float f;
    std::memcpy(&f, &b, 4);
    return f;
}
uint32_t to_bits(float f) {
    uint32_t b;
    std::memcpy(&b, &f, 4);
    return b;
}

// |got - ref| in units of the float ulp at ref (denormal spacing below).
double ulp_error(float got, long double ref) {
    if (std::isnan(ref)) return std::isnan(got) ? 0.0 : 1e9;
    if (std::isinf(got) || std::isinf(ref)) {
        // above FLT_MAX's rounding boundary a float result is inf
        const long double boundary = std::ldexp(1.0L, 128) * (1.0L - std::ldexp(1.0L, -25));
        if (std::isinf(got) && !std::isinf(ref) && std::fabs(ref) >= boundary && std::signbit(got) == std::signbit(ref))
            return 0.0;
        return (got == ref) ? 0.0 : 1e9;
    }
    int e;
    std::frexp(ref, &e);  // |ref| in [2^(e-1), 2^e)
    const long double ulp = std::ldexp(1.0L, std::max(e - 1 - 23, -149));
    return double(std::fabs((long double)got - ref) / ulp);
}

// Every float with bit pattern k * stride (both signs), then a dense sweep of [-lo, lo].
std::vector<float> sweep(uint32_t stride, float lo, int dense) {
    std::vector<float> xs;
    for (uint64_t b = 0; b < 0x7f800000u; b += stride) {
        xs.push_back(from_bits(uint32_t(b)));
        xs.push_back(-from_bits(uint32_t(b)));
    }
    for (int i = 0; i <= dense; ++i) xs.push_back(-lo + 2 * lo * float(i) / float(dense));
    for (float x : {0.0f, -0.0f, 1.4e-45f, -1.4e-45f, 1.17549435e-38f, 1.0f, -1.0f, 3.4028235e38f, -3.4028235e38f,
                    float(INFINITY), -float(INFINITY), float(NAN), 1.5707964f, 3.1415927f, 1048576.0f, 1048575.9f,
                    88.72283f, 88.72284f, -103.97208f, -87.33655f, 0.69314718f, 2.7182817f})
        xs.push_back(x);
    return xs;
}

void expect_same_bits(float a, float b, const char* what, float x, float y = 0) {
    if (std::isnan(a) && std::isnan(b)) return;
    EXPECT_EQ(to_bits(a), to_bits(b)) << what << "(" << x << ", " << y << "): vector " << a << " scalar " << b;
}

template <class Scalar, class Vector, class Ref>
double check_unary(const char* name, const std::vector<float>& xs, Scalar scalar, Vector vector, Ref ref) {
    double worst = 0;
    float worst_x = 0;
    for (size_t i = 0; i < xs.size(); i += 8) {
        gm::f8 v{};
        for (size_t j = 0; j < 8; ++j) v[j] = xs[std::min(i + j, xs.size() - 1)];
        const gm::f8 out = vector(v);
        for (size_t j = 0; j < 8; ++j) {
            const float x = v[j], got = scalar(x);
            expect_same_bits(out[j], got, name, x);
            const double err = ulp_error(got, ref((long double)x));
            if (err > worst) worst = err, worst_x = x;
        }
    }
    EXPECT_LE(worst, kMaxUlp) << name << " at x = " << worst_x << " (" << std::hexfloat << worst_x << ")";
    std::printf("%s: max error %.6f ulp over %zu arguments\n", name, worst, xs.size());
    return worst;
}

template <class Scalar, class Vector, class Ref>
double check_binary(const char* name, const std::vector<std::pair<float, float>>& xy, Scalar scalar, Vector vector,
                    Ref ref) {
    double worst = 0;
    std::pair<float, float> at{};
    for (size_t i = 0; i < xy.size(); i += 8) {
        gm::f8 a{}, b{};
        for (size_t j = 0; j < 8; ++j) {
            const auto& p = xy[std::min(i + j, xy.size() - 1)];
            a[j] = p.first;
            b[j] = p.second;
        }
        const gm::f8 out = vector(a, b);
        for (size_t j = 0; j < 8; ++j) {
            const float got = scalar(a[j], b[j]);
            expect_same_bits(out[j], got, name, a[j], b[j]);
            const double err = ulp_error(got, ref((long double)a[j], (long double)b[j]));
            if (err > worst) worst = err, at = {a[j], b[j]};
        }
    }
    EXPECT_LE(worst, kMaxUlp) << name << " at (" << at.first << ", " << at.second << ")";
    std::printf("%s: max error %.6f ulp over %zu argument pairs\n", name, worst, xy.size());
    return worst;
}

const std::vector<float>& arguments() {
    static const std::vector<float> xs = sweep(997, 12.0f, 400000);
    return xs;
}

// Pairs: random floats of every magnitude, and the special values crossed.
std::vector<std::pair<float, float>> pairs(bool exponents_small) {
    std::vector<std::pair<float, float>> xy;
    PhiloxStream rng(7, 0, exponents_small ? 1 : 2);
    for (int i = 0; i < 300000; ++i) {
        float x = from_bits(rng.next_u32() & 0x7f7fffffu) * ((rng.next_u32() & 1) ? -1.0f : 1.0f);
        float y = from_bits(rng.next_u32() & 0x7f7fffffu) * ((rng.next_u32() & 1) ? -1.0f : 1.0f);
        if (exponents_small) {
            // pow: a result in range mostly; |x| near 1 and |y| of any size, or moderate both
            x = std::ldexp(1.0f + rng.next(), int(rng.next_u32() % 40) - 20);
            y = (rng.next() - 0.5f) * 60.0f;
            if (i % 3 == 0) x = 1.0f + (rng.next() - 0.5f) * 1e-3f, y = std::ldexp(rng.next() - 0.5f, int(rng.next_u32() % 24));
            if (i % 7 == 0) x = -x, y = std::nearbyint(y);
        }
        xy.push_back({x, y});
    }
    const float specials[] = {0.0f, -0.0f, 1.0f, -1.0f, 0.5f, -0.5f, 2.0f, -2.0f, 3.0f, -3.0f, 1.4e-45f, -1.4e-45f,
                              1e20f, -1e20f, 16777216.0f, 16777217.0f * 2, -16777215.0f, float(INFINITY),
                              -float(INFINITY), float(NAN)};
    for (float a : specials)
        for (float b : specials) xy.push_back({a, b});
    return xy;
}

}  // namespace

TEST(Gmath, Sin) {
    check_unary("sin", arguments(), [](float x) { return gm::sin(x); }, [](gm::f8 x) { return gm::sin(x); },
                [](long double x) { return sinl(x); });
}

TEST(Gmath, Cos) {
    check_unary("cos", arguments(), [](float x) { return gm::cos(x); }, [](gm::f8 x) { return gm::cos(x); },
                [](long double x) { return cosl(x); });
}

TEST(Gmath, SincosIsSinAndCos) {
    for (float x : arguments()) {
        float s, c;
        gm::sincos(x, s, c);
        expect_same_bits(s, gm::sin(x), "sincos.sin", x);
        expect_same_bits(c, gm::cos(x), "sincos.cos", x);
    }
}

// The eight-lane sincos (f8) and sincos_n (eight at a time compiled for AVX2
// where the CPU has it, in runs of every length so the padded tail is
// used too) give the scalar sincos's bits.
TEST(Gmath, SincosOfEightLanesAndOfArraysIsSincos) {
    const std::vector<float>& xs = arguments();
    std::vector<float> s(xs.size()), c(xs.size());
    size_t at = 0;
    for (size_t run = 1; at < xs.size(); run = run % 19 + 1) {
        const size_t n = std::min(run, xs.size() - at);
        gm::sincos_n(xs.data() + at, s.data() + at, c.data() + at, n);
        at += n;
    }
    for (size_t i = 0; i + 8 <= xs.size(); i += 8) {
        gm::f8 x, s8, c8;
        for (size_t j = 0; j < 8; ++j) x[j] = xs[i + j];
        gm::sincos(x, s8, c8);
        for (size_t j = 0; j < 8; ++j) {
            float s1, c1;
            gm::sincos(xs[i + j], s1, c1);
            expect_same_bits(s8[j], s1, "sincos(f8).sin", xs[i + j]);
            expect_same_bits(c8[j], c1, "sincos(f8).cos", xs[i + j]);
            expect_same_bits(s[i + j], s1, "sincos_n.sin", xs[i + j]);
            expect_same_bits(c[i + j], c1, "sincos_n.cos", xs[i + j]);
        }
    }
}

TEST(Gmath, Tan) {
    check_unary("tan", arguments(), [](float x) { return gm::tan(x); }, [](gm::f8 x) { return gm::tan(x); },
                [](long double x) { return tanl(x); });
}

TEST(Gmath, Exp) {
    check_unary("exp", arguments(), [](float x) { return gm::exp(x); }, [](gm::f8 x) { return gm::exp(x); },
                [](long double x) { return expl(x); });
}

TEST(Gmath, Log) {
    check_unary("log", arguments(), [](float x) { return gm::log(x); }, [](gm::f8 x) { return gm::log(x); },
                [](long double x) { return logl(x); });
}

TEST(Gmath, Atan2) {
    check_binary("atan2", pairs(false), [](float y, float x) { return gm::atan2(y, x); },
                 [](gm::f8 y, gm::f8 x) { return gm::atan2(y, x); },
                 [](long double y, long double x) { return atan2l(y, x); });
}

TEST(Gmath, Pow) {
    check_binary("pow", pairs(true), [](float x, float y) { return gm::pow(x, y); },
                 [](gm::f8 x, gm::f8 y) { return gm::pow(x, y); },
                 [](long double x, long double y) { return powl(x, y); });
    check_binary("pow (any magnitudes)", pairs(false), [](float x, float y) { return gm::pow(x, y); },
                 [](gm::f8 x, gm::f8 y) { return gm::pow(x, y); },
                 [](long double x, long double y) { return powl(x, y); });
}

TEST(Gmath, AnnexFSpecialValues) {
    const float inf = INFINITY;
    auto same = [](float a, float b) { return to_bits(a) == to_bits(b); };
    EXPECT_TRUE(same(gm::sin(-0.0f), -0.0f));
    EXPECT_TRUE(same(gm::tan(-0.0f), -0.0f));
    EXPECT_EQ(gm::cos(-0.0f), 1.0f);
    EXPECT_TRUE(std::isnan(gm::sin(inf)) && std::isnan(gm::cos(-inf)) && std::isnan(gm::tan(NAN)));
    EXPECT_TRUE(same(gm::sin(1.4e-45f), 1.4e-45f));  // denormal: sin x = x
    EXPECT_EQ(gm::exp(0.0f), 1.0f);
    EXPECT_EQ(gm::exp(-inf), 0.0f);
    EXPECT_EQ(gm::exp(inf), inf);
    EXPECT_EQ(gm::exp(89.0f), inf);
    EXPECT_EQ(gm::log(1.0f), 0.0f);
    EXPECT_EQ(gm::log(0.0f), -inf);
    EXPECT_EQ(gm::log(-0.0f), -inf);
    EXPECT_EQ(gm::log(inf), inf);
    EXPECT_TRUE(std::isnan(gm::log(-1.0f)));
    EXPECT_EQ(gm::pow(NAN, 0.0f), 1.0f);
    EXPECT_EQ(gm::pow(1.0f, NAN), 1.0f);
    EXPECT_EQ(gm::pow(-1.0f, inf), 1.0f);
    EXPECT_TRUE(same(gm::pow(-0.0f, 3.0f), -0.0f));
    EXPECT_EQ(gm::pow(-0.0f, -3.0f), -inf);
    EXPECT_EQ(gm::pow(-inf, 3.0f), -inf);
    EXPECT_TRUE(std::isnan(gm::pow(-2.0f, 0.5f)));
    EXPECT_EQ(gm::pow(2.0f, 10.0f), 1024.0f);
    EXPECT_TRUE(same(gm::atan2(-0.0f, 0.0f), -0.0f));
    EXPECT_EQ(gm::atan2(0.0f, -0.0f), float(M_PI));
    EXPECT_EQ(gm::atan2(inf, -inf), float(3 * M_PI / 4));
    EXPECT_EQ(gm::atan2(1.0f, 0.0f), float(M_PI / 2));
}

// the extension's own double cos (gmath.cpp), serving OpenMesh and CGAL
double gamma_cos_for_libraries(double x) __asm__("cos");

TEST(Gmath, DoubleCosForThirdPartyCode) {
    double worst = 0;
    for (int i = -200000; i <= 200000; ++i) {
        const double x = i * 1e-4 * 3.3;
        const long double ref = cosl((long double)x);
        int e;
        std::frexp(ref, &e);
        const long double ulp = std::ldexp(1.0L, std::max(e - 53, -1074));
        worst = std::max(worst, double(std::fabs((long double)gamma_cos_for_libraries(x) - ref) / ulp));
    }
    EXPECT_LE(worst, 2.0);
    std::printf("double cos: max error %.3f ulp on [-66, 66]\n", worst);
}
