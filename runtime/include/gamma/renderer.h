// The renderers: the false-colour render of one value per surfel and the
// appearance render (appearance kernels per camera sample, shaded by a
// metallic-roughness model under a sky x AO and a sun with shadows); the
// property smoothing and the per-point look they
// share with the baker.  See runtime/README.md, "Render" and "Appearance
// render".
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "gamma/cancel.h"
#include "gamma/kernel_table.h"
#include "gamma/mesh.h"
#include "gamma/render.h"
#include "gamma/scene_index.h"
#include "gamma/stats.h"
#include "gamma/surfel_state.h"

namespace gammart {

// Fixed Philox key and stream of the appearance render (independent of the
// simulation seed: the picture's noise does not change between runs).
constexpr uint64_t kRenderKey = 0x47414D4D41524E44ULL;  // "GAMMARND"
constexpr uint32_t kRenderStream = 0xFFFFFFFEu;         // sampling uses 0xFFFFFFFF

// What a render reads (all by reference; nothing is modified).
struct RenderScene {
    const SceneIndex& index;
    const SceneFrame& frame;
    const SurfelState& state;
    const KernelTable& kernels;
    const std::vector<Texture>& textures;
    const Mesh& mesh;
    std::shared_ptr<const std::vector<float>> corner_normals;  // shading.h; empty: flat shading
    const BaseColours& base;                   // the scene's own colours (glTF materials)
    const CancelToken& cancel;                 // checked by the renders and bakes between rows and blocks
};

// Checks textures (positive size, height*width*3 finite floats); throws
// gammart::Error naming the texture.
void validate_textures(const std::vector<Texture>& textures);

// The smoothed row (W floats) of `surface` at p: out[c] = float(sum_j w_j *
// row_j[c]) over SceneIndex::smooth's neighbours.
void interpolate_row(const RenderScene& rs, int surface, const float p[3], float* out);

// The look the surface's appearance kernel gives at point p of triangle
// `triangle` (normal n, texture coordinates uv) with the smoothed row:
// abi.py's APPEARANCE_OUTPUTS (colour, roughness, metallic, displacement,
// occlusion), started from the scene's material there (BaseColours::
// start_look) and clamped to [0, 1] but for the displacement; the material
// itself without a kernel.  `row` (W floats) and `tex` (3 per texture, then 3
// for the base colour) are scratch; returns the kernel's non-finite report.
int32_t look_at(const RenderScene& rs, uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                const float uv[2], int iteration, uint64_t random_key, float* row, float* tex,
                float out_look[GAMMA_LOOK_WIDTH]);

// look_at with the smoothed row already in `row` (W floats, as
// interpolate_row gives it for the triangle's surface).
int32_t look_of_row(const RenderScene& rs, uint32_t triangle, const float p[3], const float n[3],
                    const float dir[3], const float uv[2], int iteration, uint64_t random_key, const float* row,
                    float* tex, float out_look[GAMMA_LOOK_WIDTH]);

struct Radiance {
    float c[3] = {0, 0, 0};  // linear; display = clamp01(c)^(1/kDisplayGamma)
};

// The light a look reflects towards the eye (unit vectors: shading normal n,
// to_eye, the scene's up, towards the sun): a metallic-roughness model (GGX
// distribution, height-correlated Smith visibility, Schlick Fresnel; the
// base colour's diffuse share 1 - metallic, F0 = mix(0.04, base, metallic))
// under a sun of kSunIntensity (sun_visible: 1 lit, 0 in shadow) and a sky
// of radiance `sky` (the ambient light times its unoccluded fraction),
// brighter above than below in the mirror direction of smooth surfaces.
// The ambient terms are multiplied by the look's occlusion.  A white,
// non-metallic, rough surface shows about what the Lambert model gives.
Radiance shade_look(const float look[GAMMA_LOOK_WIDTH], V3 n, V3 to_eye, V3 up, V3 sun, float sun_visible,
                    float sky);

// False colour: smoothed `values` (one per surfel) and a shade per pixel
// (height*width each; NaN on the background).
void render_false_colour(const RenderScene& rs, const float* values, std::array<float, 3> eye,
                         std::array<float, 3> target, std::array<float, 3> up, float fov_deg, int width,
                         int height, int threads, float* out_value, float* out_shade);

// What a false-colour render needs of the scene for one camera, kept so that
// the pictures of every iteration cast their rays once: per pixel whether the
// ray hit, SceneIndex::smooth's neighbours and weights at the hit point, and
// the shade.  value() gives render_false_colour's out_value for any values.
struct FalseColourView {
    int width = 0, height = 0;
    size_t surfels = 0;            // the values read have one per surfel
    std::vector<uint8_t> count;    // neighbours per pixel; kMissed where the ray missed
    // The neighbours of the pixels that hit, one after the other in pixel
    // order: pixel px's are index/weight[first[px]] .. + count[px] (a
    // picture of the bunny at 512 x 512 hits ~20 % of its pixels: ~5 MB
    // here, against 25 MB for kSmoothingNeighbours slots per pixel).
    std::vector<uint32_t> first;   // height*width; 0 where the ray missed
    std::vector<uint32_t> index;
    std::vector<double> weight;
    std::vector<float> shade;      // height*width; NaN on the background
    static constexpr uint8_t kMissed = 0xFF;

    // The smoothed value at pixel px (NaN where the ray missed): the same
    // sum, in the same order, as render_false_colour's.
    float value(size_t px, const float* values) const;

    // The false-colour picture (height*width*3 bytes) of `values`, as
    // gamma/driver/outputs.py's FalseColourCanvas.picture computes it from
    // render_false_colour's images: t = float32((v - vmin) / (vmax - vmin))
    // (the bounds as float32, the arithmetic in float32), viridis(t) in double
    // (the same polynomial, no fused multiply-add), times the shade, to bytes
    // as uint8(x * 255 + 0.5); `background` (height*width*3) where the value
    // is NaN.  vmax > vmin.
    void picture(const float* values, double vmin, double vmax, const uint8_t* background, int threads,
                 uint8_t* out_rgb) const;

    // The view as bytes, for gammac's cache of views (driver/view_cache.py):
    // a header, count and shade per pixel, then the neighbours and weights
    // of the pixels whose ray hit (the others' are never read); and back.
    // from_bytes checks every count and index against the header (a
    // gammart::Error for bytes that are not a whole view of this layout),
    // so a view read back is safe to use whatever the bytes.
    std::vector<uint8_t> to_bytes() const;
    static FalseColourView from_bytes(const uint8_t* data, size_t size);
};

// Casts the camera's rays once (out arrays as render_false_colour's).
FalseColourView false_colour_view(const RenderScene& rs, std::array<float, 3> eye, std::array<float, 3> target,
                                  std::array<float, 3> up, float fov_deg, int width, int height, int threads);

// Appearance render into out_rgba (height*width*4).  Throws gammart::Error
// on bad parameters.
RenderStats render_appearance(const RenderScene& rs, const AppearanceParams& params, float* out_rgba);

}  // namespace gammart
