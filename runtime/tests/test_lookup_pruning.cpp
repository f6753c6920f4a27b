// The triangle lookup's pruning test: the SSE2 form (all x at once, no
// branch per x) and, where the CPU has it, the AVX-512 form answer as the
// scalar rule does, case for case, including cases near the test's
// boundary, y's own slot and fewer than kNearest x; `keep` keeps what the
// scalar rule keeps.  (Compiled with -ffp-contract=off, as the lookup is.)
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "gamma/lookup_pruning.h"

using namespace gammart;

namespace {

struct Sphere {
    float c[3];
    double r;
};

// The x of a sphere as the lookup takes them: the n points nearest to c, in
// order of (float) squared distance.
LookupPruning::Nearest nearest_of(const Sphere& s, const std::vector<float>& pts, size_t n,
                                  std::vector<size_t>* order_out) {
    std::vector<size_t> order(pts.size() / 3);
    std::vector<float> d2(order.size());
    for (size_t i = 0; i < order.size(); ++i) {
        order[i] = i;
        float d = 0.0f;
        for (int k = 0; k < 3; ++k) d += (s.c[k] - pts[3 * i + k]) * (s.c[k] - pts[3 * i + k]);
        d2[i] = d;
    }
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return d2[a] < d2[b] || (d2[a] == d2[b] && a < b); });
    LookupPruning::Nearest X;
    n = std::min(n, order.size());
    for (size_t k = 0; k < n; ++k) X.set(k, &pts[3 * order[k]], d2[order[k]]);
    X.close(n);
    *order_out = order;
    return X;
}

float squared_distance(const float* a, const float* b) {
    float d = 0.0f;
    for (int k = 0; k < 3; ++k) d += (a[k] - b[k]) * (a[k] - b[k]);
    return d;
}

// A sphere of radius r (a triangle's) and min_count + (a draw mod
// count_range) points around it on a slightly bent sheet, as surfels around
// a triangle.
std::vector<float> bent_sheet(std::mt19937& rng, int min_count, int count_range, Sphere* sphere) {
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    Sphere& s = *sphere;
    s = Sphere{{u(rng), u(rng), u(rng)}, 0.02 + 0.2 * std::fabs(double(u(rng)))};
    const float spread = float(3.0 * s.r) * (1.0f + std::fabs(u(rng)));
    std::vector<float> pts;
    const int count = min_count + int(rng() % unsigned(count_range));
    for (int i = 0; i < count; ++i) {
        const float a = spread * u(rng), b = spread * u(rng);
        pts.insert(pts.end(), {s.c[0] + a, s.c[1] + b, s.c[2] + 0.1f * (a * a + b * b) + 0.01f * spread * u(rng)});
    }
    return pts;
}

// Both forms on each case, and how often the rule pruned.
struct Tally {
    size_t cases = 0, pruned = 0;
    ::testing::AssertionResult same(const LookupPruning::Nearest& X, const float* y, double cy2, size_t self,
                                    double r) {
        const bool scalar = LookupPruning::never_scalar(X, y, cy2, self, r);
        ++cases;
        pruned += scalar;
        if (LookupPruning::never(X, y, cy2, self, r) != scalar)
            return ::testing::AssertionFailure() << "the packed form says " << (scalar ? "keep" : "prune");
#if defined(GAMMA_LOOKUP_PRUNING_AVX512)
        if (LookupPruning::has_avx512()) {
            ++avx512_cases;
            if (LookupPruning::never_avx512(X, y, cy2, self, r) != scalar)
                return ::testing::AssertionFailure() << "the AVX-512 form says " << (scalar ? "keep" : "prune");
        }
#endif
        return ::testing::AssertionSuccess();
    }
    size_t avx512_cases = 0;
    // many cases, both outcomes common: the comparison means something
    void expect_both_outcomes() const {
        EXPECT_GT(cases, 50000u);
#if defined(GAMMA_LOOKUP_PRUNING_AVX512)
        if (LookupPruning::has_avx512()) {
            EXPECT_EQ(avx512_cases, cases);
        }
#endif
        EXPECT_GT(pruned, cases / 10);
        EXPECT_LT(pruned, cases - cases / 10);
    }
};

}  // namespace

TEST(LookupPruning, PackedTestAnswersAsTheScalarRule) {
    std::mt19937 rng(14);
    Tally tally;
    for (int sphere = 0; sphere < 3000; ++sphere) {
        Sphere s;
        std::vector<float> pts = bent_sheet(rng, 2, 60, &s);
        // duplicates and a point at the centre: ties of every kind
        if (sphere % 7 == 0) pts.insert(pts.end(), pts.begin(), pts.begin() + 3);
        if (sphere % 11 == 0) pts.insert(pts.end(), {s.c[0], s.c[1], s.c[2]});
        const size_t nx = 1 + rng() % LookupPruning::kNearest;   // 1..8 x, odd counts too
        std::vector<size_t> order;
        const LookupPruning::Nearest X = nearest_of(s, pts, nx, &order);
        for (size_t p = 0; p < order.size(); ++p) {
            const float* y = &pts[3 * order[p]];
            const double cy2 = double(squared_distance(s.c, y));
            const size_t self = p < X.n ? p : LookupPruning::kNearest;
            ASSERT_TRUE(tally.same(X, y, cy2, self, s.r))
                << "sphere " << sphere << " point " << p << " of " << order.size() << ", " << X.n << " x";
        }
    }
    tally.expect_both_outcomes();
}

TEST(LookupPruning, CasesNearTheBoundaryOfTheTest) {
    // y placed where the test's two sides meet, for one x, and nudged a
    // few float steps either way: the two forms agree there too.  (The
    // sides are never exactly equal for float inputs -- none in 1.9e9
    // lattice points tried -- so `>` against `>=`, or another order of
    // the additions, is not something any input tells apart; what this
    // checks is the lanes, the masks and the operands near the boundary.)
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    Tally tally;
    for (int i = 0; i < 20000; ++i) {
        const double r = 0.05 + u(rng);
        Sphere s{{0.0f, 0.0f, 0.0f}, r};
        const float x[3] = {float(0.3 * r * u(rng)), float(0.3 * r * u(rng)), 0.0f};
        LookupPruning::Nearest X;
        X.set(0, x, squared_distance(s.c, x));
        X.close(1);
        // along a random direction, the distance t where the test's two sides
        // meet, found by bisection in double, then nudged by float steps
        const double th = 6.283185307179586 * u(rng);
        const double dir[3] = {std::cos(th), std::sin(th), 0.0};
        auto gap = [&](double t) {
            const float y[3] = {float(t * dir[0]), float(t * dir[1]), 0.0f};
            const double cy = std::sqrt(double(squared_distance(s.c, y)));
            const double ex = double(y[0]) - x[0], ey = double(y[1]) - x[1];
            const double yx = std::sqrt(ex * ex + ey * ey);
            const double scale = r + cy + yx;
            return cy * cy - X.from_c2[0] - (2.0 * r * yx + 1e-3 * scale * scale);
        };
        double lo = 0.0, hi = 10.0 * r;
        if (!(gap(hi) > 0)) continue;
        for (int it = 0; it < 80; ++it) (gap(0.5 * (lo + hi)) > 0 ? hi : lo) = 0.5 * (lo + hi);
        for (int nudge = -3; nudge <= 3; ++nudge) {
            float y[3] = {float(hi * dir[0]), float(hi * dir[1]), 0.0f};
            for (int k = 0; k < 2; ++k)
                for (int step = 0; step < std::abs(nudge); ++step)
                    y[k] = std::nextafter(y[k], nudge > 0 ? 2.0f * y[k] : 0.0f);
            ASSERT_TRUE(tally.same(X, y, double(squared_distance(s.c, y)), LookupPruning::kNearest, r))
                << "case " << i;
        }
    }
    tally.expect_both_outcomes();
}

TEST(LookupPruning, TheSlotGivenAsSelfAndTheSlotsPastTheCountNeverDecide) {
    // In the lookup, y's own slot holds y itself, a pair whose test can
    // never pass (|c-y|^2 - |c-y|^2 = 0); here the slot holds another point
    // that prunes y, so that leaving it out shows.  The other slots hold
    // points as far from c as y, which never prune it.
    const double r = 0.1;
    const float c[3] = {0, 0, 0}, far[3] = {0.5f, 0.0f, 0.0f}, near[3] = {0.01f, 0.0f, 0.0f};
    const double far2 = double(squared_distance(c, far));
    for (size_t slot = 0; slot < LookupPruning::kNearest; ++slot) {
        LookupPruning::Nearest X;
        for (size_t k = 0; k < LookupPruning::kNearest; ++k) {
            const double th = 0.5 + double(k);
            const float mirror[3] = {float(0.5 * std::cos(th)), float(0.5 * std::sin(th)), 0.0f};
            if (k == slot) X.set(k, near, squared_distance(c, near));
            else X.set(k, mirror, squared_distance(c, mirror));
        }
        X.close(LookupPruning::kNearest);
        for (bool packed : {true, false}) {
            auto never = packed ? LookupPruning::never : LookupPruning::never_scalar;
            EXPECT_TRUE(never(X, far, far2, LookupPruning::kNearest, r)) << "slot " << slot;
            EXPECT_FALSE(never(X, far, far2, slot, r)) << "slot " << slot << (packed ? " packed" : " scalar");
            // near as a slot past the count: never tested either
            LookupPruning::Nearest fewer = X;
            fewer.close(slot);
            EXPECT_FALSE(never(fewer, far, far2, LookupPruning::kNearest, r)) << "slot " << slot;
        }
    }
    LookupPruning::Nearest none;
    none.close(0);
    EXPECT_FALSE(LookupPruning::never(none, far, far2, LookupPruning::kNearest, r));
}

TEST(LookupPruning, KeepKeepsWhatTheScalarRuleKeepsInOrder) {
    // found lists as the lookup makes them: distance_key words with the x
    // (the nearest few) first, on sheets of points around spheres
    std::mt19937 rng(23);
    size_t found_total = 0, kept_total = 0;
    for (int sphere = 0; sphere < 2000; ++sphere) {
        Sphere s;
        const std::vector<float> pts = bent_sheet(rng, 1, 80, &s);
        const size_t nx = std::min<size_t>(1 + rng() % LookupPruning::kNearest, pts.size() / 3);
        std::vector<size_t> order;
        const LookupPruning::Nearest X = nearest_of(s, pts, nx, &order);
        // the x first, the rest in a shuffled order
        std::shuffle(order.begin() + std::ptrdiff_t(nx), order.end(), rng);
        std::vector<uint64_t> found, want;
        for (size_t p = 0; p < order.size(); ++p) {
            const float* y = &pts[3 * order[p]];
            const float d2 = squared_distance(s.c, y);
            found.push_back(distance_key(d2, uint32_t(order[p])));
            if (!LookupPruning::never_scalar(X, y, double(d2), p < nx ? p : LookupPruning::kNearest, s.r))
                want.push_back(found.back());
        }
        std::vector<uint64_t> kept(found.size());
        kept.resize(LookupPruning::keep(X, found.data(), found.size(), pts.data(), s.r, kept.data()));
        ASSERT_EQ(kept, want) << "sphere " << sphere;
        found_total += found.size();
        kept_total += kept.size();
    }
    EXPECT_LT(kept_total, found_total - found_total / 10);   // the rule dropped many
    EXPECT_GT(kept_total, found_total / 10);
}
