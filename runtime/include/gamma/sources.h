// Gamma-ton sources: validation of the configured sources, their
// precomputed form in scene units, the emission of one gamma-ton (origin and
// direction from Philox draws), and which sources emit in an iteration.
#pragma once
#include <cstdint>
#include <vector>

#include "gamma/config.h"
#include "gamma/philox.h"
#include "gamma/scene_index.h"
#include "gamma/vec.h"

namespace gammart {

enum class SourceKind { Point, Spot, Rect, Disk, Directional, Sphere, Hemisphere };
enum class Emission { Parallel, Uniform, Cosine };

// Source with everything precomputed in scene units.
struct SourceRt {
    SourceKind kind = SourceKind::Point;
    Emission emission = Emission::Parallel;
    V3 pos, dir, u, v;          // dir normalised; u, v in-plane axes (plane_axes(dir))
    float cos_a = -1, falloff = 0, w = 0, h = 0, radius = 0;
    float u0 = 0, du = 0, v0 = 0, dv = 0;  // directional: projected bbox rectangle
    V3 env_centre, env_up;      // sphere / hemisphere: bbox centre and up
    float env_radius = 1;
};

// Validates c.sources (throws gammart::Error naming the source) and
// precomputes them for the scene frame.
std::vector<SourceRt> build_sources(const Config& c, const SceneFrame& frame);

// Environment-sphere emission (origin on the sphere of radius R about c,
// cosine about the inward normal); `upper` reflects origins into the half
// dot(o, up) >= 0.  4 draws.
void emit_environment(V3 centre, float radius, V3 up, PhiloxStream& rng, bool upper, V3& org, V3& dir);

// Origin and direction of one gamma-ton of source s.
void emit(const SourceRt& s, PhiloxStream& rng, V3& org, V3& dir);

// emit() for the n consecutive gamma-tons first .. first + n - 1 of source
// s, bit for bit: rng[i] = PhiloxStream(seed, iteration, first + i) as emit
// leaves it, org[i], dir[i].  Environment sources are emitted eight at a
// time in AVX2 where the processor has it (IEEE operations in emit's order,
// no fused multiply-add; the sines and cosines the same libm calls give,
// eight at a time by sincosf8 where it reproduces them).
void emit_run(const SourceRt& s, uint64_t seed, uint32_t iteration, int64_t first, size_t n, PhiloxStream* rng,
              V3* org, V3* dir);

// The sources active in an iteration, in declaration order, and the first
// global gamma-ton index of each: source active[k] emits indices
// start[k] .. start[k+1]-1; start.back() is the iteration's total.
struct EmissionSchedule {
    std::vector<size_t> active;
    std::vector<int64_t> start{0};
    int64_t total() const { return start.back(); }
};
EmissionSchedule schedule(const std::vector<Source>& sources, int iteration);

}  // namespace gammart
