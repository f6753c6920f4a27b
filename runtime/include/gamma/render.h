// Textures and the constants of the appearance renderer (see runtime/README.md,
// "Appearance render").  Header-only so the tests can call the sampler.
#pragma once
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "gamma_abi.h"

namespace gammart {

// An RGB image, row 0 = the TOP of the image, 3 floats per texel (row-major).
struct Texture {
    int width = 0, height = 0;
    std::vector<float> rgb;  // height*width*3
};

// Bilinear lookup at (u, v) with wrap-around in both directions: u runs to
// the right, v up (v = 1 is the top row).  Texel (i, j) (row i, column j) has
// its centre at u = (j + 0.5)/W, v = 1 - (i + 0.5)/H.  Non-finite u or v is
// taken as 0.  Interpolation is a + f*(b - a) in double, so a texel centre
// returns the texel exactly and a region of equal texels returns that colour
// exactly.
inline void sample_texture(const Texture& t, float u, float v, float out[3]) {
    const int W = t.width, H = t.height;
    double uu = std::isfinite(u) ? double(u) : 0.0, vv = std::isfinite(v) ? double(v) : 0.0;
    uu -= std::floor(uu);  // [0, 1), exact in double
    vv -= std::floor(vv);
    const double x = uu * W - 0.5, y = (1.0 - vv) * H - 0.5;
    const double xf = std::floor(x), yf = std::floor(y);
    const double fx = x - xf, fy = y - yf;
    auto wrap = [](int64_t i, int n) { i %= n; return int(i < 0 ? i + n : i); };
    const int x0 = wrap(int64_t(xf), W), x1 = wrap(int64_t(xf) + 1, W);
    const int y0 = wrap(int64_t(yf), H), y1 = wrap(int64_t(yf) + 1, H);
    const float* r0 = t.rgb.data() + size_t(y0) * size_t(W) * 3;
    const float* r1 = t.rgb.data() + size_t(y1) * size_t(W) * 3;
    for (int c = 0; c < 3; ++c) {
        const double a = r0[3 * x0 + c], b = r0[3 * x1 + c];
        const double d = r1[3 * x0 + c], e = r1[3 * x1 + c];
        const double top = a + fx * (b - a), bottom = d + fx * (e - d);
        out[c] = float(top + fy * (bottom - top));
    }
}

// Appearance-render constants.
constexpr int kSmoothingNeighbours = 8;        // k of the Gaussian property smoothing
constexpr float kNeutralAlbedo = 0.7f;         // surfaces without an appearance kernel
constexpr float kAmbientWithSun = 0.45f;       // sky ambient when a sun is given
constexpr float kAmbientWithoutSun = 1.0f;     // sky ambient when sun_direction = 0
constexpr float kSunIntensity = 0.75f;
constexpr float kDisplayGamma = 2.2f;          // display = albedo * lighting^(1/2.2), clamped
constexpr float kAoLengthFraction = 0.5f;      // AO ray length = 0.5 x scene diagonal
constexpr int kMaxRenderSamples = 4096;
constexpr int kMaxAoSamples = 4096;
// Sky gradient (display RGB): horizon (view direction level or below) to zenith.
constexpr std::array<float, 3> kSkyHorizon{0.93f, 0.94f, 0.96f};
constexpr std::array<float, 3> kSkyZenith{0.47f, 0.63f, 0.86f};
// Event number used for appearance kernels in NonFinite records.
constexpr int kAppearanceEvent = -2;

// The scene's own material (glTF materials, SPEC §8a `base_color()`): per
// triangle a material (-1: none); per material an RGB factor and an index
// into `images` (-1: no texture) for the base colour, and a roughness and
// metallic factor and an index into `images` (-1: none) of the glTF
// metallic-roughness texture (roughness in its green channel, metallic in
// its blue), which multiplies them.  Without a material the colour is the
// neutral albedo and roughness and metallic are the look's defaults.
struct BaseColours {
    std::vector<int32_t> triangle_material;      // empty: no materials at all
    std::vector<std::array<float, 3>> factor;
    std::vector<int32_t> texture;
    std::vector<std::array<float, 2>> rough_metal;  // per material; empty: the defaults
    std::vector<int32_t> rough_metal_texture;       // per material; empty: none
    std::vector<Texture> images;

    int32_t material(uint32_t triangle) const {
        return triangle < triangle_material.size() ? triangle_material[triangle] : -1;
    }

    void at(uint32_t triangle, const float uv[2], float out[3]) const {
        const int32_t m = material(triangle);
        if (m < 0) {
            out[0] = out[1] = out[2] = kNeutralAlbedo;
            return;
        }
        float texel[3] = {1.0f, 1.0f, 1.0f};
        if (texture[size_t(m)] >= 0) sample_texture(images[size_t(texture[size_t(m)])], uv[0], uv[1], texel);
        for (int c = 0; c < 3; ++c) out[c] = factor[size_t(m)][size_t(c)] * texel[c];
    }

    // The look an appearance block starts from at this point (abi.py's
    // APPEARANCE_OUTPUTS): the base colour, the material's roughness and
    // metallic, no displacement, no occlusion.
    void start_look(uint32_t triangle, const float uv[2], float look[GAMMA_LOOK_WIDTH]) const {
        at(triangle, uv, look + GAMMA_LOOK_COLOR);
        look[GAMMA_LOOK_ROUGHNESS] = GAMMA_LOOK_DEFAULT_ROUGHNESS;
        look[GAMMA_LOOK_METALLIC] = GAMMA_LOOK_DEFAULT_METALLIC;
        look[GAMMA_LOOK_DISPLACEMENT] = GAMMA_LOOK_DEFAULT_DISPLACEMENT;
        look[GAMMA_LOOK_OCCLUSION] = GAMMA_LOOK_DEFAULT_OCCLUSION;
        const int32_t m = material(triangle);
        if (m < 0 || size_t(m) >= rough_metal.size()) return;
        float texel[3] = {1.0f, 1.0f, 1.0f};
        const int32_t t = size_t(m) < rough_metal_texture.size() ? rough_metal_texture[size_t(m)] : -1;
        if (t >= 0) sample_texture(images[size_t(t)], uv[0], uv[1], texel);
        look[GAMMA_LOOK_ROUGHNESS] = rough_metal[size_t(m)][0] * texel[1];
        look[GAMMA_LOOK_METALLIC] = rough_metal[size_t(m)][1] * texel[2];
    }
};

struct AppearanceParams {
    std::array<float, 3> eye{0, 0, 1}, target{0, 0, 0}, up{0, 1, 0};
    float fov_deg = 40;
    int width = 1, height = 1, threads = 1;
    int samples = 1;                     // camera rays per pixel
    std::array<float, 3> sun{0, 0, 0};   // towards the sun; zero = no sun
    int ao_samples = 0;                  // 0 = no ambient occlusion
    int iteration = 0;                   // passed to the kernels' context
};

}  // namespace gammart
