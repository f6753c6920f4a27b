// False-colour and appearance renders (see gamma/renderer.h).
#include "gamma/renderer.h"

#include "gamma/shading.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <cstring>
#include <cmath>
#include <limits>
#include <mutex>
#include <string>

#include "gamma/error.h"
#include "gamma/gmath.h"
#include "gamma/philox.h"
#include "gamma/sampling.h"
#include "gamma/threads.h"

namespace gammart {

namespace {

// Pinhole camera, vertical field of view fov_deg, row 0 = top.  dir(px, py)
// is the ray through image position (px, py) in pixels ((x + 0.5, y + 0.5) =
// the centre of pixel (x, y)).
struct Camera {
    V3 eye, fwd, right, camup;
    float th = 1, aspect = 1, w = 1, h = 1;
    Camera(std::array<float, 3> e, std::array<float, 3> target, std::array<float, 3> up, float fov_deg, int width,
           int height) {
        eye = V3{e[0], e[1], e[2]};
        fwd = normalize(V3{target[0], target[1], target[2]} - eye);
        right = normalize(cross(fwd, V3{up[0], up[1], up[2]}));
        if (!(length(right) > 0.5f)) {
            V3 t, b;
            onb(fwd, t, b);
            right = t;
        }
        camup = cross(right, fwd);
        th = gm::tan(0.5f * fov_deg * 3.14159265358979f / 180.0f);
        w = float(width);
        h = float(std::max(height, 1));
        aspect = float(width) / h;
    }
    V3 dir(float px, float py) const {
        const float sx = (2.0f * px / w - 1.0f) * th * aspect;
        const float sy = (1.0f - 2.0f * py / h) * th;
        return normalize(fwd + right * sx + camup * sy);
    }
};

inline float clamp01(float x) { return x > 0.0f ? (x < 1.0f ? x : 1.0f) : 0.0f; }  // NaN -> 0

}  // namespace

void validate_textures(const std::vector<Texture>& textures) {
    for (size_t i = 0; i < textures.size(); ++i) {
        const Texture& t = textures[i];
        const std::string at = "set_textures: texture " + std::to_string(i) + " ";
        if (t.width < 1 || t.height < 1) throw Error(at + "must have a positive width and height");
        if (t.rgb.size() != size_t(t.width) * size_t(t.height) * 3)
            throw Error(at + "must have height*width*3 floats");
        for (float x : t.rgb)
            if (!std::isfinite(x)) throw Error(at + "has a non-finite value");
    }
}

namespace {

// The accessibility and curvature an appearance block reads at point p
// (SPEC §12): the surfels' values smoothed with the rows' weights, each
// neighbour's on the side of the point's normal n.  Zero when the effect
// reads neither (nothing was measured), without a neighbour search.
void smoothed_measures(const RenderScene& rs, int surface, const float p[3], const float n[3], float* accessibility,
                       float* curvature) {
    const SurfelMeasures& m = rs.state.measures;
    *accessibility = *curvature = 0.0f;
    if (m.accessibility.empty() && m.curvature.empty()) return;
    uint32_t idx[kSmoothingNeighbours];
    double w[kSmoothingNeighbours];
    const size_t k = rs.index.smooth(surface, p, idx, w);
    double open_sum = 0, curvature_sum = 0;
    for (size_t j = 0; j < k; ++j) {
        const float* sn = rs.state.surf.normal.data() + 3 * size_t(idx[j]);
        const bool back = n[0] * sn[0] + n[1] * sn[1] + n[2] * sn[2] < 0.0f;
        if (!m.accessibility.empty())
            open_sum += w[j] * (back ? m.accessibility_back[idx[j]] : m.accessibility[idx[j]]);
        if (!m.curvature.empty()) curvature_sum += w[j] * (back ? -m.curvature[idx[j]] : m.curvature[idx[j]]);
    }
    *accessibility = float(open_sum);
    *curvature = float(curvature_sum);
}

}  // namespace

void interpolate_row(const RenderScene& rs, int surface, const float p[3], float* out) {
    uint32_t idx[kSmoothingNeighbours];
    double w[kSmoothingNeighbours];
    const size_t k = rs.index.smooth(surface, p, idx, w);
    const float* rows = rs.state.rows.data();
    const int W = rs.state.width;
    for (int c = 0; c < W; ++c) {
        double acc = 0;
        for (size_t j = 0; j < k; ++j) acc += w[j] * rows[size_t(idx[j]) * size_t(W) + size_t(c)];
        out[c] = float(acc);
    }
}

int32_t look_at(const RenderScene& rs, uint32_t triangle, const float p[3], const float n[3], const float dir[3],
                const float uv[2], int iteration, uint64_t random_key, float* row, float* tex,
                float out_look[GAMMA_LOOK_WIDTH]) {
    const int surface = rs.index.tri_surface()[triangle];
    if (rs.kernels.appearance[size_t(surface)]) interpolate_row(rs, surface, p, row);
    return look_of_row(rs, triangle, p, n, dir, uv, iteration, random_key, row, tex, out_look);
}

int32_t look_of_row(const RenderScene& rs, uint32_t triangle, const float p[3], const float n[3],
                    const float dir[3], const float uv[2], int iteration, uint64_t random_key, const float* row,
                    float* tex, float out_look[GAMMA_LOOK_WIDTH]) {
    const int surface = rs.index.tri_surface()[triangle];
    GammaAppearanceKernel fn = rs.kernels.appearance[size_t(surface)];
    const size_t T = rs.textures.size();
    rs.base.at(triangle, uv, tex + 3 * T);      // base_color() reads the slot after the effect's textures
    rs.base.start_look(triangle, uv, out_look);
    int32_t bad = 0;
    if (fn) {
        GammaContext ctx;
        smoothed_measures(rs, surface, p, n, &ctx.accessibility, &ctx.curvature);
        for (int c = 0; c < 3; ++c) {
            ctx.position[c] = p[c];
            ctx.normal[c] = n[c];
            ctx.direction[c] = dir[c];
        }
        ctx.height = dot(V3{p[0], p[1], p[2]}, rs.frame.up) - rs.frame.min_up;
        ctx.iteration = iteration;
        ctx.interactions = 0;
        set_random_key(ctx, random_key);
        ctx.uv[0] = uv[0];
        ctx.uv[1] = uv[1];
        ctx.up[0] = rs.frame.up.x; ctx.up[1] = rs.frame.up.y; ctx.up[2] = rs.frame.up.z;
        for (size_t ti = 0; ti < T; ++ti) sample_texture(rs.textures[ti], uv[0], uv[1], tex + 3 * ti);
        bad = fn(row, tex, out_look, &ctx);
    }
    // Colour, roughness, metallic and occlusion are fractions; the
    // displacement is a length (the kernel never stores a non-finite one).
    for (int c = 0; c < GAMMA_LOOK_WIDTH; ++c)
        if (c != GAMMA_LOOK_DISPLACEMENT) out_look[c] = clamp01(out_look[c]);
    return bad;
}

Radiance shade_look(const float look[GAMMA_LOOK_WIDTH], V3 n, V3 to_eye, V3 up, V3 sun, float sun_visible,
                    float sky) {
    const float metallic = look[GAMMA_LOOK_METALLIC];
    // Perceptual roughness squared; kept above 0.045 so a mirror's sun
    // highlight stays a few pixels wide instead of a sub-pixel spike.
    const float r = std::max(look[GAMMA_LOOK_ROUGHNESS], 0.045f);
    const float alpha = r * r, a2 = alpha * alpha;
    const float nv = std::max(dot(n, to_eye), 1e-4f);
    float base[3], f0[3];
    for (int c = 0; c < 3; ++c) {
        base[c] = gm::pow(look[GAMMA_LOOK_COLOR + c], kDisplayGamma);
        f0[c] = 0.04f + metallic * (base[c] - 0.04f);
    }
    // Karis' fit of the split-sum environment BRDF (scale a, bias b of F0).
    const float c0[4] = {-1.0f, -0.0275f, -0.572f, 0.022f}, c1[4] = {1.0f, 0.0425f, 1.04f, -0.04f};
    float q[4];
    for (int k = 0; k < 4; ++k) q[k] = r * c0[k] + c1[k];
    const float a004 = std::min(q[0] * q[0], gm::pow(2.0f, -9.28f * nv)) * q[0] + q[1];
    const float env_a = a004 * -1.04f + q[2], env_b = a004 * 1.04f + q[3];
    // The sky seen in the mirror direction: brighter above than below, less
    // so the rougher the surface (the reflection averages the whole sky).
    const V3 refl = n * (2.0f * dot(n, to_eye)) - to_eye;
    const float smooth = 1.0f - r;
    const float sky_spec = sky * (1.0f + smooth * (0.8f * (0.5f + 0.5f * dot(refl, up)) - 0.4f));
    const float ambient = sky * look[GAMMA_LOOK_OCCLUSION];
    float spec_sun = 0.0f, nl = 0.0f;
    V3 h{0, 0, 0};
    if (sun_visible > 0.0f) {
        nl = dot(n, sun);
        if (nl > 0.0f) {
            h = normalize(sun + to_eye);
            const float nh = std::max(dot(n, h), 0.0f);
            const float d = nh * nh * (a2 - 1.0f) + 1.0f;
            const float D = a2 / (3.14159265f * d * d);
            const float vis = 0.5f / (nl * std::sqrt(nv * nv * (1.0f - a2) + a2) +
                                      nv * std::sqrt(nl * nl * (1.0f - a2) + a2));
            // Radiance units of the renderer: a white Lambert surface under
            // light E shows E, so the BRDF is scaled by pi.
            spec_sun = 3.14159265f * D * vis * kSunIntensity * nl * sun_visible;
        } else {
            nl = 0.0f;
        }
    }
    const float vh = dot(to_eye, h);
    const float fresnel = gm::pow(1.0f - std::min(std::max(vh, 0.0f), 1.0f), 5.0f);
    Radiance out;
    for (int c = 0; c < 3; ++c) {
        const float diffuse = base[c] * (1.0f - metallic) * (ambient + kSunIntensity * nl * sun_visible);
        const float f_sun = f0[c] + (1.0f - f0[c]) * fresnel;
        const float specular = spec_sun * f_sun + sky_spec * look[GAMMA_LOOK_OCCLUSION] * (f0[c] * env_a + env_b);
        out.c[c] = diffuse + specular;
    }
    return out;
}

namespace {

// The false-colour render's camera ray through pixel (x, y): false where it
// misses; else the smoothing's neighbours (idx, w; their number in *k) at the
// hit point and the shade there.
bool false_colour_pixel(const RenderScene& rs, const Camera& cam, const V3& light, int x, int y,
                        uint32_t idx[kSmoothingNeighbours], double w[kSmoothingNeighbours], size_t* k,
                        float* shade) {
    const SceneIndex& I = rs.index;
    const V3 dir = cam.dir(float(x) + 0.5f, float(y) + 0.5f);
    RTCRayHit rh;
    I.cast(rh, cam.eye, dir, 0.0f);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    const V3 p = cam.eye + dir * rh.ray.tfar;
    const float q[3] = {p.x, p.y, p.z};
    *k = I.smooth(I.tri_surface()[rh.hit.primID], q, idx, w);
    V3 ng = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
    if (dot(ng, dir) > 0) ng = ng * -1.0f;
    const V3 n = shading_normal(*rs.corner_normals, rh.hit.primID, rh.hit.u, rh.hit.v, ng);
    *shade = 0.25f + 0.75f * std::fabs(dot(n, light));
    return true;
}

V3 false_colour_light(const Camera& cam) { return normalize(cam.fwd * -1.0f + cam.camup * 0.35f - cam.right * 0.35f); }

}  // namespace

FalseColourView false_colour_view(const RenderScene& rs, std::array<float, 3> eye, std::array<float, 3> target,
                                  std::array<float, 3> up, float fov_deg, int width, int height, int threads) {
    const Camera cam(eye, target, up, fov_deg, width, height);
    const V3 light = false_colour_light(cam);
    constexpr size_t K = kSmoothingNeighbours;
    FalseColourView view;
    view.width = width;
    view.height = height;
    view.surfels = rs.state.size();
    const size_t npx = size_t(width) * size_t(height);
    view.count.assign(npx, FalseColourView::kMissed);
    view.first.assign(npx, 0);
    view.shade.assign(npx, std::numeric_limits<float>::quiet_NaN());
    // Each row's neighbours in a buffer of its own, then the rows' one after
    // the other (in row order: the same arrays at any thread count).
    std::vector<std::vector<uint32_t>> row_index(static_cast<size_t>(height));
    std::vector<std::vector<double>> row_weight(static_cast<size_t>(height));
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, height, 1), [&](const tbb::blocked_range<int>& r) {
            rs.cancel.check("the render");
            uint32_t idx[K];
            double w[K];
            for (int y = r.begin(); y < r.end(); ++y) {
                std::vector<uint32_t>& ri = row_index[size_t(y)];
                std::vector<double>& rw = row_weight[size_t(y)];
                for (int x = 0; x < width; ++x) {
                    const size_t px = size_t(y) * size_t(width) + size_t(x);
                    size_t k = 0;
                    if (false_colour_pixel(rs, cam, light, x, y, idx, w, &k, &view.shade[px])) {
                        view.count[px] = uint8_t(k);
                        view.first[px] = uint32_t(ri.size());   // within the row: offset below
                        ri.insert(ri.end(), idx, idx + k);
                        rw.insert(rw.end(), w, w + k);
                    }
                }
            }
        });
    });
    size_t entries = 0;
    for (int y = 0; y < height; ++y) entries += row_index[size_t(y)].size();
    if (entries > size_t(UINT32_MAX)) throw Error("false_colour_view: the picture is too large");
    view.index.reserve(entries);
    view.weight.reserve(entries);
    for (int y = 0; y < height; ++y) {
        const uint32_t base = uint32_t(view.index.size());
        for (int x = 0; x < width; ++x) {
            const size_t px = size_t(y) * size_t(width) + size_t(x);
            if (view.count[px] != FalseColourView::kMissed) view.first[px] += base;
        }
        view.index.insert(view.index.end(), row_index[size_t(y)].begin(), row_index[size_t(y)].end());
        view.weight.insert(view.weight.end(), row_weight[size_t(y)].begin(), row_weight[size_t(y)].end());
        std::vector<uint32_t>().swap(row_index[size_t(y)]);
        std::vector<double>().swap(row_weight[size_t(y)]);
    }
    return view;
}

float FalseColourView::value(size_t px, const float* values) const {
    if (count[px] == kMissed) return std::numeric_limits<float>::quiet_NaN();
    double sv = 0;
    const size_t at = first[px];
    for (size_t j = 0; j < count[px]; ++j) sv += weight[at + j] * values[index[at + j]];
    return float(sv);
}

namespace {

// FalseColourView::to_bytes's header.
struct ViewHeader {
    char magic[4];
    uint32_t version;
    int32_t width, height;
    uint64_t surfels;
    uint32_t neighbours;           // kSmoothingNeighbours when written
    uint32_t unused;
    uint64_t entries;              // neighbours of every pixel that hit, together
};
constexpr char kViewMagic[4] = {'G', 'M', 'F', 'V'};
constexpr uint32_t kViewVersion = 1;

}  // namespace

std::vector<uint8_t> FalseColourView::to_bytes() const {
    constexpr size_t K = kSmoothingNeighbours;
    const size_t npx = count.size();
    const size_t entries = index.size();
    ViewHeader h{};
    std::memcpy(h.magic, kViewMagic, 4);
    h.version = kViewVersion;
    h.width = width;
    h.height = height;
    h.surfels = surfels;
    h.neighbours = uint32_t(K);
    h.entries = entries;
    std::vector<uint8_t> out(sizeof h + npx + npx * sizeof(float) + entries * (sizeof(uint32_t) + sizeof(double)));
    uint8_t* o = out.data();
    auto put = [&o](const void* p, size_t bytes) {
        if (bytes) std::memcpy(o, p, bytes);
        o += bytes;
    };
    put(&h, sizeof h);
    put(count.data(), npx);
    put(shade.data(), npx * sizeof(float));
    put(index.data(), entries * sizeof(uint32_t));
    put(weight.data(), entries * sizeof(double));
    return out;
}

FalseColourView FalseColourView::from_bytes(const uint8_t* data, size_t size) {
    constexpr size_t K = kSmoothingNeighbours;
    auto fail = [](const std::string& why) -> void { throw Error("false-colour view: " + why); };
    ViewHeader h{};
    if (size < sizeof h) fail("it ends early");
    std::memcpy(&h, data, sizeof h);
    if (std::memcmp(h.magic, kViewMagic, 4) != 0 || h.version != kViewVersion || h.neighbours != K)
        fail("not a view of this layout");
    if (h.width <= 0 || h.height <= 0 || h.surfels == 0 || h.surfels > uint64_t(UINT32_MAX))
        fail("inconsistent sizes");
    // Every size bounded by the bytes there are, by division, before any
    // product is formed: a header's sizes cannot make one wrap around.
    const size_t body = size - sizeof h;
    constexpr size_t kPixelBytes = 1 + sizeof(float), kEntryBytes = sizeof(uint32_t) + sizeof(double);
    if (size_t(h.width) > body / kPixelBytes || size_t(h.height) > body / kPixelBytes / size_t(h.width))
        fail("its size differs from its header's");
    const size_t npx = size_t(h.width) * size_t(h.height);
    const size_t tail = npx * kPixelBytes;
    if (h.entries > (body - tail) / kEntryBytes || h.entries > npx * K || body - tail != h.entries * kEntryBytes)
        fail("its size differs from its header's");
    FalseColourView v;
    v.width = h.width;
    v.height = h.height;
    v.surfels = size_t(h.surfels);
    const uint8_t* p = data + sizeof h;
    v.count.assign(p, p + npx);
    p += npx;
    v.shade.resize(npx);
    std::memcpy(v.shade.data(), p, npx * sizeof(float));
    p += npx * sizeof(float);
    size_t entries = 0;
    for (uint8_t c : v.count) {
        if (c != kMissed && c > K) fail("a pixel has too many neighbours");
        if (c != kMissed) entries += c;
    }
    if (entries != h.entries) fail("its neighbours differ from its header's");
    if (entries > size_t(UINT32_MAX)) fail("it has too many neighbours");
    v.index.resize(entries);
    v.weight.resize(entries);
    if (entries) {
        std::memcpy(v.index.data(), p, entries * sizeof(uint32_t));
        std::memcpy(v.weight.data(), p + entries * sizeof(uint32_t), entries * sizeof(double));
    }
    v.first.assign(npx, 0);
    size_t at = 0;
    for (size_t px = 0; px < npx; ++px) {
        const size_t c = v.count[px];
        if (c == kMissed) continue;
        v.first[px] = uint32_t(at);
        for (size_t j = at; j < at + c; ++j) {
            if (v.index[j] >= v.surfels) fail("a neighbour is not a surfel");
            if (!(v.weight[j] >= 0.0 && v.weight[j] <= 1.0)) fail("a weight is not in [0, 1]");
        }
        at += c;
        // a shade cast is 0.25 + 0.75 |cos|: a picture's bytes come from it
        if (!(v.shade[px] >= 0.0f && v.shade[px] <= 1.0f)) fail("a shade is not in [0, 1]");
    }
    return v;
}

namespace {

// Polynomial fit of matplotlib's viridis (the coefficients of
// gamma/driver/outputs.py's _VIRIDIS, row 0 the constant term).
constexpr double kViridis[7][3] = {
    {0.2777273272234177, 0.005407344544966578, 0.3340998053353061},
    {0.1050930431085774, 1.404613529898575, 1.384590162594685},
    {-0.3308618287255563, 0.214847559468213, 0.09509516302823659},
    {-4.634230498983486, -5.799100973351585, -19.33244095627987},
    {6.228269936347081, 14.17993336680509, 56.69055260068105},
    {4.776384997670288, -13.74514537774601, -65.35303263337234},
    {-5.435455855934631, 4.645852612178535, 26.3124352495832},
};

// numpy's clip(x, 0, 1): NaN stays NaN.
inline double clip01(double x) { return x != x ? x : (x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x)); }

}  // namespace

void FalseColourView::picture(const float* values, double vmin, double vmax, const uint8_t* background, int threads,
                              uint8_t* out_rgb) const {
    const float low = float(vmin), span = float(vmax - vmin);
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, height, 1), [&](const tbb::blocked_range<int>& r) {
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < width; ++x) {
                    const size_t px = size_t(y) * size_t(width) + size_t(x);
                    uint8_t* o = out_rgb + 3 * px;
                    const float v = value(px, values);
                    if (std::isnan(v)) {
                        for (int c = 0; c < 3; ++c) o[c] = background[3 * px + size_t(c)];
                        continue;
                    }
                    // Separate statements, each rounded: float32, then double, as numpy does.
                    const float shifted = v - low;
                    const float t32 = shifted / span;
                    const double t = clip01(double(t32));
                    for (int c = 0; c < 3; ++c) {
                        double rgb = kViridis[6][c];
                        for (int k = 5; k >= 0; --k) {
                            const double scaled = t * rgb;
                            rgb = kViridis[k][c] + scaled;
                        }
                        const double shaded = clip01(rgb) * double(shade[px]);
                        const double byte = shaded * 255.0 + 0.5;
                        o[c] = uint8_t(byte);
                    }
                }
        });
    });
}

void render_false_colour(const RenderScene& rs, const float* values, std::array<float, 3> eye,
                         std::array<float, 3> target, std::array<float, 3> up, float fov_deg, int width,
                         int height, int threads, float* out_value, float* out_shade) {
    const Camera cam(eye, target, up, fov_deg, width, height);
    const V3 light = false_colour_light(cam);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    constexpr size_t K = kSmoothingNeighbours;
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, height, 1), [&](const tbb::blocked_range<int>& r) {
            rs.cancel.check("the render");
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < width; ++x) {
                    const size_t px = size_t(y) * size_t(width) + size_t(x);
                    uint32_t idx[K];
                    double w[K];
                    size_t k = 0;
                    if (!false_colour_pixel(rs, cam, light, x, y, idx, w, &k, &out_shade[px])) {
                        out_value[px] = nan;
                        out_shade[px] = nan;
                        continue;
                    }
                    // the sum of FalseColourView::value, in the same order
                    double sv = 0;
                    for (size_t j = 0; j < k; ++j) sv += w[j] * values[idx[j]];
                    out_value[px] = float(sv);
                }
        });
    });
}

RenderStats render_appearance(const RenderScene& rs, const AppearanceParams& P, float* out) {
    const auto t0 = std::chrono::steady_clock::now();
    const SceneIndex& I = rs.index;
    auto fail = [](const std::string& m) { throw Error("render_appearance: " + m); };
    if (P.width < 1 || P.height < 1) fail("width and height must be positive");
    if (int64_t(P.width) * int64_t(P.height) > (int64_t(1) << 28)) fail("image too large");
    if (!(P.fov_deg > 0 && P.fov_deg < 180)) fail("fov_deg must be in (0, 180)");
    if (!finite3(P.eye) || !finite3(P.target) || !finite3(P.up) || !finite3(P.sun))
        fail("eye, target, up and sun_direction must be finite");
    if (P.eye == P.target) fail("eye and target must differ");
    if (P.samples < 1 || P.samples > kMaxRenderSamples)
        fail("samples must be in 1.." + std::to_string(kMaxRenderSamples));
    if (P.ao_samples < 0 || P.ao_samples > kMaxAoSamples)
        fail("ao_samples must be in 0.." + std::to_string(kMaxAoSamples));
    if (P.threads > kMaxThreads) fail("threads must be at most " + std::to_string(kMaxThreads));

    const Camera cam(P.eye, P.target, P.up, P.fov_deg, P.width, P.height);
    const bool sun_on = nonzero3(P.sun);
    const V3 sun = sun_on ? unit(P.sun) : V3{0, 0, 0};
    const float ambient = sun_on ? kAmbientWithSun : kAmbientWithoutSun;
    const float ao_len = kAoLengthFraction * rs.frame.diag;
    const float inv_gamma = 1.0f / kDisplayGamma;
    const float eps = rs.frame.eps;
    const V3 up = rs.frame.up;
    const float bump_step = std::max(rs.index.sigma(), eps * 16.0f);
    const int S = P.samples, A = P.ao_samples;
    int grid = 1;  // strata per axis: the smallest g with g*g >= S
    while (grid * grid < S) ++grid;
    const int W = rs.state.width;
    const size_t T = rs.textures.size();
    const bool has_uvs = rs.mesh.has_uvs();
    const float* uvs = rs.mesh.uvs.data();
    const int32_t* tri_surface = I.tri_surface().data();
    RenderStats stats;
    std::mutex merge;

    run_with_threads(P.threads, [&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, P.height, 1), [&](const tbb::blocked_range<int>& r) {
            rs.cancel.check("the render");
            // Per-task buffers: nothing is allocated per pixel.
            std::vector<float> row(size_t(W), 0.0f), tex(3 * T + 3, 0.0f);
            std::vector<NonFinite> bad_local;
            int64_t rays = 0, calls = 0;
            for (int y = r.begin(); y < r.end(); ++y)
                for (int x = 0; x < P.width; ++x) {
                    const uint64_t pix = uint64_t(y) * uint64_t(P.width) + uint64_t(x);
                    double acc[3] = {0, 0, 0};
                    int hits = 0;
                    for (int s = 0; s < S; ++s) {
                        PhiloxStream rng(kRenderKey, kRenderStream, pix * uint64_t(S) + uint64_t(s));
                        float jx = 0.5f, jy = 0.5f;
                        if (S > 1) {
                            const float a = rng.next(), b = rng.next();
                            jx = (float(s % grid) + a) / float(grid);
                            jy = (float(s / grid) + b) / float(grid);
                        }
                        const V3 dir = cam.dir(float(x) + jx, float(y) + jy);
                        RTCRayHit rh;
                        I.cast(rh, cam.eye, dir, 0.0f);
                        ++rays;
                        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
                            const float t = 0.5f + 0.5f * dot(dir, up);
                            for (int c = 0; c < 3; ++c)
                                acc[c] += kSkyHorizon[size_t(c)] + t * (kSkyZenith[size_t(c)] - kSkyHorizon[size_t(c)]);
                            continue;
                        }
                        ++hits;
                        const uint32_t prim = rh.hit.primID;
                        const V3 p = cam.eye + dir * rh.ray.tfar;
                        V3 n = normalize(V3{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z});
                        if (dot(n, dir) > 0) n = n * -1.0f;
                        // Shading normal for the sun's cosine; occlusion rays use the geometric one.
                        const V3 ns = shading_normal(*rs.corner_normals, prim, rh.hit.u, rh.hit.v, n);
                        const int surface = tri_surface[prim];
                        float uv[2] = {0.0f, 0.0f};
                        if (has_uvs) {
                            const float bu = rh.hit.u, bv = rh.hit.v, bw = 1.0f - bu - bv;
                            const float* c3 = uvs + 6 * size_t(prim);
                            uv[0] = bw * c3[0] + bu * c3[2] + bv * c3[4];
                            uv[1] = bw * c3[1] + bu * c3[3] + bv * c3[5];
                        }
                        const float q[3] = {p.x, p.y, p.z}, nn[3] = {n.x, n.y, n.z};
                        const float dd[3] = {dir.x, dir.y, dir.z};
                        const uint64_t key = mix64(mix64(kRenderKey ^ pix) ^ uint64_t(s));
                        float look[GAMMA_LOOK_WIDTH];
                        if (rs.kernels.appearance[size_t(surface)]) ++calls;
                        if (int32_t bad = look_at(rs, prim, q, nn, dd, uv, P.iteration, key, row.data(), tex.data(),
                                                  look))
                            count_nonfinite(bad_local, kAppearanceEvent, 0, surface, bad);
                        V3 shade_n = ns;
                        if (rs.kernels.displaces[size_t(surface)]) {
                            // The displacement's slope bends the shading normal: its change
                            // over a surfel spacing along two directions in the surface.
                            V3 t, b;
                            onb(n, t, b);
                            const float step = bump_step;
                            float slope[2];
                            for (int axis = 0; axis < 2; ++axis) {
                                const V3 moved = p + (axis == 0 ? t : b) * step;
                                const float mq[3] = {moved.x, moved.y, moved.z};
                                float other[GAMMA_LOOK_WIDTH];
                                look_at(rs, prim, mq, nn, dd, uv, P.iteration, key, row.data(), tex.data(), other);
                                calls += 1;
                                slope[axis] = (other[GAMMA_LOOK_DISPLACEMENT] - look[GAMMA_LOOK_DISPLACEMENT]) / step;
                            }
                            const V3 bent = normalize(ns - t * slope[0] - b * slope[1]);
                            if (dot(bent, bent) > 0.0f) shade_n = bent;
                        }
                        // Lighting: sky x (1 - occluded fraction), a sun with shadows.
                        float sky = ambient;
                        if (A > 0) {
                            int open = 0;
                            const V3 o = p + n * eps;
                            for (int a = 0; a < A; ++a) {
                                const float u1 = rng.next(), u2 = rng.next();
                                if (!I.occluded(o, cosine_hemisphere(n, u1, u2), eps, ao_len)) ++open;
                            }
                            rays += A;
                            sky = ambient * (float(open) / float(A));
                        }
                        float sun_visible = 0.0f;
                        if (sun_on && dot(shade_n, sun) > 0 && dot(n, sun) > 0) {
                            ++rays;
                            if (!I.occluded(p + n * eps, sun, eps, std::numeric_limits<float>::infinity()))
                                sun_visible = 1.0f;
                        }
                        const Radiance L = shade_look(look, shade_n, dir * -1.0f, up, sun, sun_visible, sky);
                        for (int c = 0; c < 3; ++c) acc[c] += gm::pow(clamp01(L.c[c]), inv_gamma);
                    }
                    float* o = out + 4 * size_t(pix);
                    for (int c = 0; c < 3; ++c) o[c] = float(acc[c] / double(S));
                    o[3] = float(double(hits) / double(S));
                }
            std::lock_guard<std::mutex> hold(merge);  // integer counts: order-free
            stats.rays += rays;
            stats.kernel_calls += calls;
            for (const NonFinite& nf : bad_local)
                count_nonfinite(stats.nonfinite, nf.event, nf.ton_type, nf.surface, nf.statement, nf.count);
        });
    });
    stats.seconds = seconds_since(t0);
    return stats;
}

}  // namespace gammart
