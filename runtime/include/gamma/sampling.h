// Direction/position sampling and the parabolic flight shared by the tracer
// and its tests.  Every function is deterministic in its uniform inputs.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "gamma/vec.h"
#include "gamma/gmath.h"

namespace gammart {

constexpr float kTwoPi = 6.28318530717958647692f;
constexpr float kPi = 3.14159265358979323846f;

// Chord deviation bound of the piecewise-linear parabola, as a fraction of
// the ton type's bounce distance D: epsilon = 0.02 * D.
constexpr double kParabolaEpsilonFraction = 0.02;
// Segments per parabolic flight before the gamma-ton is capped.
constexpr int64_t kMaxFlightSegments = 100000;
// Spot sources with falloff: cos^n lobe draws before falling back to uniform-in-cone.
constexpr int kSpotMaxRedraws = 64;

// The point of the unit sphere at height 1 - 2u and azimuth phi, given
// sin phi and cos phi.
inline V3 uniform_sphere_sc(float u, float s, float c) {
    float z = 1.0f - 2.0f * u;
    float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    return {r * c, r * s, z};
}

inline V3 uniform_sphere(float u, float v) {
    float s, c;
    gm::sincos(kTwoPi * v, s, c);
    return uniform_sphere_sc(u, s, c);
}

// Direction at polar cos `z` about unit n, at the azimuth whose sine and
// cosine are s and c.
inline V3 around_sc(V3 n, float z, float s, float c) {
    float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    V3 t, b;
    onb(n, t, b);
    return normalize(t * (r * c) + b * (r * s) + n * z);
}

// Direction at polar cos `z` and azimuth 2*pi*v about unit n.
inline V3 around(V3 n, float z, float v) {
    float s, c;
    gm::sincos(kTwoPi * v, s, c);
    return around_sc(n, z, s, c);
}

// Cosine-weighted direction about unit n.
inline V3 cosine_hemisphere(V3 n, float u, float v) { return around(n, std::sqrt(std::max(0.0f, 1.0f - u)), v); }

// Uniform direction over the hemisphere about unit n.
inline V3 uniform_hemisphere(V3 n, float u, float v) { return around(n, u, v); }

// Uniform in solid angle within the cone of cos half-angle cos_a about n.
inline V3 uniform_cone(V3 n, float cos_a, float u, float v) { return around(n, 1.0f - u * (1.0f - cos_a), v); }

// In-plane axes of a plane with unit normal n: a = the world axis with the
// smallest |component| of n (x before y before z on ties), u = normalize(a x n),
// v = n x u.
inline void plane_axes(V3 n, V3& u, V3& v) {
    const float ax = std::fabs(n.x), ay = std::fabs(n.y), az = std::fabs(n.z);
    V3 a = (ax <= ay && ax <= az) ? V3{1, 0, 0} : (ay <= az ? V3{0, 1, 0} : V3{0, 0, 1});
    u = normalize(cross(a, n));
    v = cross(n, u);
}

// Time step of the piecewise-linear parabola (g = 1): the chord of a parabola
// over dt sags g*dt^2/8 from the curve, so dt = sqrt(8*epsilon).
inline double flight_dt(double bounce_distance) {
    return std::sqrt(8.0 * kParabolaEpsilonFraction * bounce_distance);
}

// Launch speed for bounce distance D (range of a 45-degree launch on flat
// ground with g = 1): v = sqrt(g * D).
inline double launch_speed(double bounce_distance) { return std::sqrt(bounce_distance); }

// Position on the parabola at time t (double precision, g = 1).
inline V3 flight_point(V3 p0, V3 vel, V3 down, double t) {
    const double h = 0.5 * t * t;
    return {float(double(p0.x) + double(vel.x) * t + double(down.x) * h),
            float(double(p0.y) + double(vel.y) * t + double(down.y) * h),
            float(double(p0.z) + double(vel.z) * t + double(down.z) * h)};
}

enum class FlightEnd { Landed, Escaped, Capped };

// Piecewise-linear flight: chord k joins p(k*dt) and p((k+1)*dt).
// `segment(a, b)` casts one chord and returns true when it hit something;
// `escaped(b, t)` is asked after every chord that hit nothing (b = p(t)).
template <class Segment, class Escaped>
FlightEnd fly(V3 p0, V3 vel, V3 down, double dt, int64_t& segments, Segment&& segment, Escaped&& escaped) {
    V3 a = p0;
    for (int64_t k = 0; k < kMaxFlightSegments; ++k) {
        const V3 b = flight_point(p0, vel, down, double(k + 1) * dt);
        ++segments;
        if (segment(a, b)) return FlightEnd::Landed;
        if (escaped(b, double(k + 1) * dt)) return FlightEnd::Escaped;
        a = b;
    }
    return FlightEnd::Capped;
}

}  // namespace gammart
