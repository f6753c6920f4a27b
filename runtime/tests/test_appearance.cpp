// UVs, textures, property smoothing and the appearance renderer.
#include <gtest/gtest.h>

#include <cmath>
#include <array>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/mesh.h"
#include "gamma/render.h"
#include "gamma/renderer.h"
#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;

namespace {


uint64_t address(GammaAppearanceKernel fn) { return uint64_t(reinterpret_cast<uintptr_t>(fn)); }

// The texture sample, unchanged, if the row is the expected constant and the
// context is as documented; magenta otherwise.
int32_t texture_kernel(const float* surf, const float* tex, float* rgb, const GammaContext* ctx) {
    const bool ok = surf[3] == 0.625f && surf[4] == 0.375f && ctx->interactions == 0 && ctx->iteration == 7;
    rgb[0] = ok ? tex[0] : 1.0f;
    rgb[1] = ok ? tex[1] : 0.0f;
    rgb[2] = ok ? tex[2] : 1.0f;
    return 0;
}

int32_t uv_kernel(const float*, const float*, float* rgb, const GammaContext* ctx) {
    rgb[0] = ctx->uv[0];
    rgb[1] = ctx->uv[1];
    rgb[2] = 0.0f;
    return 0;
}

// Depends on the row, the texture, the random key and the position.
int32_t busy_kernel(const float* surf, const float* tex, float* rgb, const GammaContext* ctx) {
    const float noise = float(ctx->random_key[0] >> 8) * (1.0f / 16777216.0f);
    rgb[0] = 0.5f * tex[0] + 0.5f * surf[3];
    rgb[1] = 0.8f * tex[1] + 0.1f * noise;
    rgb[2] = 0.3f + 0.5f * ctx->position[1] + 0.2f * tex[5];
    return 0;
}

int32_t failing_kernel(const float*, const float*, float* rgb, const GammaContext*) {
    rgb[0] = rgb[1] = rgb[2] = std::numeric_limits<float>::quiet_NaN();
    return 3;
}

// Quad [-1,1]^2 in the plane z = 0 (normal +z), uv = ((x+1)/2, (y+1)/2).
Mesh uv_quad(bool with_uvs = true) {
    const std::vector<float> v = {-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    const std::vector<int32_t> t = {0, 1, 2, 0, 2, 3};
    const std::vector<float> uv = {0, 0, 1, 0, 1, 1, 0, 0, 1, 1, 0, 1};
    return Mesh::from_arrays(v.data(), 4, t.data(), 2, "quad", with_uvs ? uv.data() : nullptr);
}

// 8x8 texture, four 4x4 blocks of one colour each (row 0 = top).
const float kBlocks[4][3] = {{0.9f, 0.1f, 0.2f}, {0.2f, 0.8f, 0.3f}, {0.1f, 0.2f, 0.7f}, {0.6f, 0.55f, 0.05f}};
Texture block_texture() {
    Texture t;
    t.width = t.height = 8;
    t.rgb.resize(8 * 8 * 3);
    for (int i = 0; i < 8; ++i)
        for (int j = 0; j < 8; ++j)
            for (int c = 0; c < 3; ++c) t.rgb[size_t((i * 8 + j) * 3 + c)] = kBlocks[(i >= 4) * 2 + (j >= 4)][c];
    return t;
}

Config one_surface(std::vector<float> row, int64_t surfels) {
    Config c;
    c.surfels = surfels;
    c.row_width = int(row.size());
    c.surface_rows = {row};
    return c;
}

// Camera used with uv_quad: from (0,0,3) towards the origin, tan(fov/2) =
// 0.5, so the image spans [-1.5, 1.5]^2 of the plane z = 0.
// The display value the renderer gives a look seen along to_eye on the quad
// (normal +z, the scene's up +y), as render_appearance encodes shade_look.
std::array<float, 3> shown(std::array<float, 3> colour, V3 to_eye, V3 sun = {0, 0, 0}, float sun_visible = 0.0f,
                           float sky = kAmbientWithoutSun) {
    float look[GAMMA_LOOK_WIDTH] = {colour[0], colour[1], colour[2], GAMMA_LOOK_DEFAULT_ROUGHNESS,
                                    GAMMA_LOOK_DEFAULT_METALLIC, 0.0f, 1.0f};
    const Radiance r = shade_look(look, V3{0, 0, 1}, normalize(to_eye), V3{0, 1, 0}, sun, sun_visible, sky);
    std::array<float, 3> out{};
    for (int c = 0; c < 3; ++c) {
        const float x = r.c[c] > 0.0f ? (r.c[c] < 1.0f ? r.c[c] : 1.0f) : 0.0f;
        out[size_t(c)] = std::pow(x, 1.0f / kDisplayGamma);
    }
    return out;
}

// Towards the eye of quad_view from the quad's point (X, Y, 0).
V3 to_quad_eye(double X, double Y) { return normalize(V3{float(-X), float(-Y), 3.0f}); }

AppearanceParams quad_view(int size, int threads) {
    AppearanceParams p;
    p.eye = {0, 0, 3};
    p.target = {0, 0, 0};
    p.up = {0, 1, 0};
    p.fov_deg = float(2.0 * std::atan(0.5) * 180.0 / M_PI);
    p.width = p.height = size;
    p.threads = threads;
    p.samples = 1;
    p.ao_samples = 0;
    p.sun = {0, 0, 0};
    p.iteration = 7;
    return p;
}

}  // namespace

// ---- UVs -------------------------------------------------------------------

TEST(Uv, ObjCornersFanTriangulated) {
    const std::string obj =
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0.0 0.0\nvt 1.0 0.0\nvt 1.0 1.0 0.0\nvt 0.0 1.0\n"
        "vn 0 0 1\n"
        "f 1/1 2/2 3/3 4/4\n"        // quad: (1,2,3), (1,3,4)
        "f 1/-4/1 3/-2/1 4/-1/1\n";  // v/vt/vn with relative vt indices
    Mesh m = Mesh::parse_obj(obj, "uv.obj");
    ASSERT_TRUE(m.has_uvs());
    ASSERT_EQ(m.num_triangles(), 3u);
    const std::vector<float> expect = {0, 0, 1, 0, 1, 1,  0, 0, 1, 1, 0, 1,  0, 0, 1, 1, 0, 1};
    EXPECT_EQ(m.uvs, expect);
}

TEST(Uv, MissingOrBadTextureIndices) {
    // One corner without vt: no UVs at all.
    Mesh m = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nf 1/1 2/2 3\n", "a.obj");
    EXPECT_FALSE(m.has_uvs());
    m = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1//1 2//1 3//1\n", "b.obj");
    EXPECT_FALSE(m.has_uvs());
    // vt defined after the face, and a vt with only u (v = 0).
    m = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/2 3/1\nvt 0.25 0.5\nvt 0.75\n", "c.obj");
    ASSERT_TRUE(m.has_uvs());
    EXPECT_EQ(m.uvs, (std::vector<float>{0.25f, 0.5f, 0.75f, 0.0f, 0.25f, 0.5f}));
    EXPECT_EQ(gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/5 3/1\n", "d.obj"); }),
              "mesh 'd.obj': face on line 5 has texture index 5 out of range (1 texture coordinates)");
    EXPECT_EQ(gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/-2 2/1 3/1\n", "e.obj"); }),
              "mesh 'e.obj': face on line 5 has texture index -2 out of range (1 texture coordinates)");
    EXPECT_EQ(gamma_test::expect_error([] { Mesh::parse_obj("vt x y\n", "f.obj"); }),
              "mesh 'f.obj': line 1: cannot read texture coordinates");
    EXPECT_EQ(gamma_test::expect_error([] { Mesh::parse_obj("vt nan 0\n", "g.obj"); }),
              "mesh 'g.obj': line 1: texture coordinate is not finite");
    EXPECT_EQ(gamma_test::expect_error([] { Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/a 2/1 3/1\n", "h.obj"); }),
              "mesh 'h.obj': face on line 5: cannot read '1/a'");
}

TEST(Uv, DegenerateTrianglesDropTheirUvs) {
    // Second face is degenerate (repeated vertex): the kept UVs are the first face's.
    Mesh m = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.1 0.2\nvt 0.3 0.4\nvt 0.5 0.6\n"
                             "f 1/1 1/2 2/3\nf 1/3 2/2 3/1\n", "deg.obj");
    ASSERT_EQ(m.num_triangles(), 1u);
    EXPECT_EQ(m.degenerate_dropped, 1u);
    EXPECT_EQ(m.uvs, (std::vector<float>{0.5f, 0.6f, 0.3f, 0.4f, 0.1f, 0.2f}));
}

TEST(Uv, SpotHasUvs) {
    Mesh m = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/spot.obj");
    ASSERT_TRUE(m.has_uvs());
    ASSERT_EQ(m.uvs.size(), 6 * m.num_triangles());
    for (float x : m.uvs) {
        EXPECT_TRUE(std::isfinite(x));
        EXPECT_GT(x, -0.1f);
        EXPECT_LT(x, 1.1f);
    }
}

TEST(Uv, FromArrays) {
    EXPECT_TRUE(uv_quad(true).has_uvs());
    EXPECT_FALSE(uv_quad(false).has_uvs());
    EXPECT_FALSE(gamma_test::icosphere(1).has_uvs());
    const std::vector<float> v = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    const std::vector<int32_t> t = {0, 1, 2};
    const std::vector<float> uv = {0, 0, 1, 0, 0, std::numeric_limits<float>::infinity()};
    EXPECT_EQ(gamma_test::expect_error([&] { Mesh::from_arrays(v.data(), 3, t.data(), 1, "x", uv.data()); }),
              "mesh 'x': triangle 0 has a non-finite texture coordinate");
}

// ---- Textures ----------------------------------------------------------------

TEST(Texture, BilinearAndWrap) {
    // 4 wide, 2 high; texel (i, j) = (j, i, 10 + j + 4 i).
    Texture t;
    t.width = 4;
    t.height = 2;
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 4; ++j) t.rgb.insert(t.rgb.end(), {float(j), float(i), float(10 + j + 4 * i)});
    float out[3];
    // Texel centres are exact: row 0 is the top (v near 1).
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 4; ++j) {
            sample_texture(t, (j + 0.5f) / 4.0f, 1.0f - (i + 0.5f) / 2.0f, out);
            EXPECT_EQ(out[0], float(j));
            EXPECT_EQ(out[1], float(i));
            EXPECT_EQ(out[2], float(10 + j + 4 * i));
        }
    // Half-way between columns 1 and 2 of the top row.
    sample_texture(t, 0.5f, 0.75f, out);
    EXPECT_EQ(out[0], 1.5f);
    EXPECT_EQ(out[1], 0.0f);
    // A quarter of the way from column 0 to 1, 3/4 from row 0 to row 1.
    sample_texture(t, 0.1875f, 0.375f, out);
    EXPECT_FLOAT_EQ(out[0], 0.25f);
    EXPECT_FLOAT_EQ(out[1], 0.75f);
    // u = 0 lies half-way between the last and the first column (wrap).
    sample_texture(t, 0.0f, 0.75f, out);
    EXPECT_EQ(out[0], 1.5f);  // (3 + 0) / 2
    // v = 1 (top edge) lies half-way between row 0 and the bottom row (wrap).
    sample_texture(t, 0.125f, 1.0f, out);
    EXPECT_EQ(out[1], 0.5f);
    // Periodic in both directions.
    float a[3], b[3], c[3];
    sample_texture(t, 0.3f, 0.8f, a);
    sample_texture(t, 2.3f, -1.2f, b);
    sample_texture(t, -0.7f, 0.8f, c);
    for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(a[k], b[k], 1e-5f);
        EXPECT_NEAR(a[k], c[k], 1e-5f);
    }
    // Non-finite coordinates are 0.
    float z[3];
    sample_texture(t, std::numeric_limits<float>::quiet_NaN(), 0.0f, out);
    sample_texture(t, 0.0f, 0.0f, z);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(out[k], z[k]);
}

TEST(Texture, Validation) {
    Simulation sim(uv_quad(), one_surface({0, 0, 0}, 50));
    Texture t;
    t.width = 2;
    t.height = 1;
    t.rgb = {0, 0, 0, 1, 1};
    EXPECT_EQ(gamma_test::expect_error([&] { sim.set_textures({t}); }), "set_textures: texture 0 must have height*width*3 floats");
    t.rgb = {0, 0, 0, 1, 1, std::numeric_limits<float>::quiet_NaN()};
    EXPECT_EQ(gamma_test::expect_error([&] { sim.set_textures({block_texture(), t}); }),
              "set_textures: texture 1 has a non-finite value");
    sim.set_textures({block_texture()});
    EXPECT_EQ(sim.textures().size(), 1u);
}

// ---- Smoothing -----------------------------------------------------------------

TEST(Smoothing, WeightsSumToOneAndConstantRowsAreExact) {
    gamma_test::Builder b;
    b.add(gamma_test::icosphere(2));
    b.add(gamma_test::icosphere(2), {1.5f, 0, 0});  // touching spheres: two surfaces
    Mesh mesh = b.mesh();
    Config c;
    c.surfels = 4000;
    c.row_width = 5;
    c.surface_rows = {{0.1f, 0.2f, 0.3f, 0.7f, -3.25f}, {0.0f, 0.0f, 0.0f, 123.456f, 1e-7f}};
    c.triangle_surface.assign(mesh.num_triangles(), 0);
    for (size_t t = mesh.num_triangles() / 2; t < mesh.num_triangles(); ++t) c.triangle_surface[t] = 1;
    Simulation sim(mesh, c);
    float row[5];
    for (int k = 0; k < 200; ++k) {
        const float a = 0.37f * float(k), z = std::cos(1.3f * float(k));
        const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
        const int surface = k % 2;
        const float p[3] = {r * std::cos(a) + 1.5f * float(surface), r * std::sin(a), z};
        uint32_t idx[kSmoothingNeighbours];
        double w[kSmoothingNeighbours];
        const size_t n = sim.smoothing_weights(surface, p, idx, w);
        ASSERT_EQ(n, size_t(kSmoothingNeighbours));
        double sum = 0;
        for (size_t j = 0; j < n; ++j) {
            EXPECT_EQ(sim.surfel_surfaces()[idx[j]], surface);  // only the hit surface's surfels
            EXPECT_GT(w[j], 0.0);
            if (j > 0) {
                EXPECT_LE(w[j], w[j - 1] * (1 + 1e-12));  // nearest first
            }
            sum += w[j];
        }
        EXPECT_NEAR(sum, 1.0, 1e-12);
        sim.interpolate_row(surface, p, row);
        for (int col = 0; col < 5; ++col) EXPECT_EQ(row[col], c.surface_rows[size_t(surface)][size_t(col)]);
    }
    // Far away every weight underflows: the nearest surfel alone.
    const float far[3] = {1e6f, 0, 0};
    uint32_t idx[kSmoothingNeighbours];
    double w[kSmoothingNeighbours];
    ASSERT_EQ(sim.smoothing_weights(1, far, idx, w), 1u);
    EXPECT_EQ(w[0], 1.0);
    EXPECT_EQ(idx[0], sim.nearest_surfel_of(1, far));
}

// ---- Appearance render -------------------------------------------------------

TEST(AppearanceRender, TextureColourExactAtKnownUvs) {
    Config c = one_surface({0.1f, 0.2f, 0.3f, 0.625f, 0.375f}, 500);
    c.set_appearance(0, address(texture_kernel));
    Simulation sim(uv_quad(), c);
    sim.set_textures({block_texture()});
    const int N = 64;
    // samples = 4: the jitter moves a sample by at most half a pixel (uv
    // 0.012), still inside the clear band below; the average of equal
    // colours is exact (accumulated in double).
    for (int run = 0; run < 4; ++run) {
        const int threads = 1 + run % 2;
        AppearanceParams view = quad_view(N, threads);
        view.samples = run < 2 ? 1 : 4;
        std::vector<float> img(size_t(N) * N * 4, -1.0f);
        RenderStats st = sim.render_appearance(view, img.data());
        EXPECT_TRUE(st.nonfinite.empty());
        int checked = 0, hits = 0;
        for (int y = 0; y < N; ++y)
            for (int x = 0; x < N; ++x) {
                const float* px = &img[size_t(4 * (y * N + x))];
                // The plane point of the pixel centre and its uv.
                const double X = 1.5 * (2.0 * (x + 0.5) / N - 1.0), Y = 1.5 * (1.0 - 2.0 * (y + 0.5) / N);
                const double u = (X + 1) / 2, v = (Y + 1) / 2;
                const bool inside = std::fabs(X) < 0.98 && std::fabs(Y) < 0.98;
                const bool outside = std::fabs(X) > 1.02 || std::fabs(Y) > 1.02;
                if (outside) {
                    EXPECT_EQ(px[3], 0.0f);
                    for (int k = 0; k < 3; ++k) {
                        EXPECT_GE(px[k], 0.0f);
                        EXPECT_LE(px[k], 1.0f);
                    }
                }
                if (!inside) continue;
                ++hits;
                EXPECT_EQ(px[3], 1.0f);
                // Away from the block edges (at u, v = 0, 0.5, 1) every
                // bilinear tap is the block's colour.
                auto clear = [](double s) { return (s > 0.08 && s < 0.42) || (s > 0.58 && s < 0.92); };
                if (!clear(u) || !clear(v)) continue;
                const int block = (v < 0.5) * 2 + (u >= 0.5);
                // The block's colour, shaded (a rough dielectric under the sky alone): the
                // four jittered samples see the quad from slightly different directions.
                // The look itself is the block's colour exactly (the texture lookup)...
                const float q[3] = {float(X), float(Y), 0.0f}, nz[3] = {0, 0, 1}, dir[3] = {0, 0, -1};
                const float uv[2] = {float(u), float(v)};
                std::vector<float> row(5), tex(6);
                float look[GAMMA_LOOK_WIDTH];
                sim.look_at(0, q, nz, dir, uv, 7, 0, row.data(), tex.data(), look);
                for (int k = 0; k < 3; ++k) ASSERT_EQ(look[k], kBlocks[block][k]) << x << "," << y;
                // ...and the pixel is it shaded (a rough dielectric under the sky alone): to
                // rounding with one centred sample, within the view's spread with four jittered.
                const std::array<float, 3> want =
                    shown({kBlocks[block][0], kBlocks[block][1], kBlocks[block][2]}, to_quad_eye(X, Y));
                const double tolerance = view.samples == 1 ? 1e-5 : 2e-3;
                for (int k = 0; k < 3; ++k) ASSERT_NEAR(px[k], want[size_t(k)], tolerance) << x << "," << y;
                ++checked;
            }
        EXPECT_GT(checked, 800);
        EXPECT_GE(st.kernel_calls, hits);
    }
}

TEST(AppearanceRender, UvInterpolationAndSky) {
    Config c = one_surface({0, 0, 0}, 200);
    c.set_appearance(0, address(uv_kernel));
    Simulation sim(uv_quad(), c);
    const int N = 48;
    std::vector<float> img(size_t(N) * N * 4);
    sim.render_appearance(quad_view(N, 2), img.data());
    for (int y = 0; y < N; ++y)
        for (int x = 0; x < N; ++x) {
            const float* px = &img[size_t(4 * (y * N + x))];
            const double X = 1.5 * (2.0 * (x + 0.5) / N - 1.0), Y = 1.5 * (1.0 - 2.0 * (y + 0.5) / N);
            if (std::fabs(X) < 0.98 && std::fabs(Y) < 0.98) {
                const std::array<float, 3> want = shown({float((X + 1) / 2), float((Y + 1) / 2), 0.0f},
                                                        to_quad_eye(X, Y));
                for (int k = 0; k < 3; ++k) EXPECT_NEAR(px[k], want[size_t(k)], 1e-4);
            } else if (std::fabs(X) > 1.02 || std::fabs(Y) > 1.02) {
                // Sky: horizon + t (zenith - horizon), t = (1 + dot(d, up)) / 2.
                const double dl = std::sqrt(X * X + Y * Y + 9.0);
                const double t = 0.5 + 0.5 * (Y / dl);
                for (int k = 0; k < 3; ++k)
                    EXPECT_NEAR(px[k], kSkyHorizon[k] + t * (kSkyZenith[k] - kSkyHorizon[k]), 1e-5);
            }
        }
    // Without UVs the kernel sees uv = 0; without a kernel the albedo is neutral.
    Simulation plain(uv_quad(false), c);
    plain.render_appearance(quad_view(N, 1), img.data());
    const float* mid = &img[size_t(4 * (N / 2 * N + N / 2))];
    const double centre = 1.5 * (2.0 * (N / 2 + 0.5) / N - 1.0);   // X of the middle pixel; Y = -X
    const std::array<float, 3> black = shown({0, 0, 0}, to_quad_eye(centre, -centre));
    EXPECT_NEAR(mid[0], black[0], 1e-5);
    EXPECT_NEAR(mid[1], black[1], 1e-5);
    Simulation neutral(uv_quad(), one_surface({0, 0, 0}, 200));
    neutral.render_appearance(quad_view(N, 1), img.data());
    const std::array<float, 3> grey = shown({kNeutralAlbedo, kNeutralAlbedo, kNeutralAlbedo},
                                            to_quad_eye(centre, -centre));
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(mid[k], grey[size_t(k)], 1e-5);
    EXPECT_EQ(mid[3], 1.0f);
}

TEST(AppearanceRender, SunAndOcclusion) {
    // Neutral quad lit by a sun straight above it (along +z): lighting =
    // 0.45 (nothing occludes the sky above a single quad) + 0.75.
    Simulation sim(uv_quad(), one_surface({0, 0, 0}, 200));
    AppearanceParams p = quad_view(16, 1);
    p.sun = {0, 0, 2};
    p.ao_samples = 8;
    std::vector<float> img(16 * 16 * 4);
    sim.render_appearance(p, img.data());
    const float* mid = &img[size_t(4 * (8 * 16 + 8))];
    const double centre = 1.5 * (2.0 * (8 + 0.5) / 16 - 1.0);
    const std::array<float, 3> grey = {kNeutralAlbedo, kNeutralAlbedo, kNeutralAlbedo};
    const V3 eye = to_quad_eye(centre, -centre);
    EXPECT_NEAR(mid[0], shown(grey, eye, V3{0, 0, 1}, 1.0f, kAmbientWithSun)[0], 1e-5);
    // Sun from behind the quad: ambient only.
    p.sun = {0, 0, -1};
    sim.render_appearance(p, img.data());
    EXPECT_NEAR(mid[0], shown(grey, eye, V3{0, 0, -1}, 0.0f, kAmbientWithSun)[0], 1e-5);
    // A box under a floor: the floor's underside seen from below is fully
    // occluded (AO) and in shadow.
    gamma_test::Builder b;
    gamma_test::floor_quad(b, -2, 2, -2, 2, 1.0f);   // ceiling at y = 1 (normal +y)
    gamma_test::floor_quad(b, -2, 2, -2, 2, -1.0f);  // floor at y = -1
    Simulation box(b.mesh(), one_surface({0, 0, 0}, 300));
    AppearanceParams q;
    q.eye = {0, 0, 0};
    q.target = {0, 1, 0};
    q.up = {0, 0, 1};
    q.fov_deg = 20;
    q.width = q.height = 8;
    q.samples = 4;
    q.ao_samples = 16;
    q.sun = {0, 1, 0};
    std::vector<float> dark(8 * 8 * 4);
    box.render_appearance(q, dark.data());
    // AO rays reach 0.5 diagonal = 3 (> 2 = the gap): about half of them
    // (those within ~45 degrees of straight down) hit the floor.
    const float g = 1.0f / kDisplayGamma;
    EXPECT_LT(dark[4 * 27], kNeutralAlbedo * std::pow(kAmbientWithSun * 0.8f, g));
    EXPECT_GT(dark[4 * 27], kNeutralAlbedo * std::pow(kAmbientWithSun * 0.2f, g));
    EXPECT_EQ(dark[4 * 27 + 3], 1.0f);
}

TEST(AppearanceRender, BitIdenticalAcrossThreads) {
    Mesh spot = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/spot.obj");
    Config c;
    c.surfels = 20000;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 0.2f}, {0, 0, 0, 0.9f}};
    c.triangle_surface.assign(spot.num_triangles(), 0);
    for (size_t t = 0; t < spot.num_triangles(); t += 3) c.triangle_surface[t] = 1;
    c.set_appearance(0, address(busy_kernel));
    c.set_appearance(1, address(uv_kernel));
    Simulation sim(spot, c);
    std::vector<float> rows = sim.rows();
    for (size_t i = 0; i < sim.num_surfels(); ++i) rows[4 * i + 3] = sim.surfels().position[3 * i + 1];
    sim.set_rows(rows.data());
    Texture a = block_texture(), b = block_texture();
    for (float& x : b.rgb) x = 1.0f - x;
    sim.set_textures({a, b});
    AppearanceParams p;
    p.eye = {2.2f, 1.2f, 2.5f};
    p.target = {0, 0.1f, 0.2f};
    p.fov_deg = 35;
    p.width = 80;
    p.height = 60;
    p.samples = 4;
    p.ao_samples = 6;
    p.sun = {0.4f, 1.0f, 0.3f};
    p.iteration = 3;
    std::vector<std::vector<float>> images;
    std::vector<RenderStats> stats;
    for (int threads : {1, 2, 4}) {
        p.threads = threads;
        images.emplace_back(size_t(p.width) * p.height * 4);
        stats.push_back(sim.render_appearance(p, images.back().data()));
    }
    for (size_t i = 1; i < images.size(); ++i) {
        EXPECT_EQ(std::memcmp(images[0].data(), images[i].data(), images[0].size() * sizeof(float)), 0);
        EXPECT_EQ(stats[i].rays, stats[0].rays);
        EXPECT_EQ(stats[i].kernel_calls, stats[0].kernel_calls);
    }
    int covered = 0;
    for (size_t i = 0; i < images[0].size(); i += 4) {
        for (int k = 0; k < 4; ++k) {
            EXPECT_GE(images[0][i + k], 0.0f);
            EXPECT_LE(images[0][i + k], 1.0f);
        }
        covered += images[0][i + 3] > 0;
    }
    EXPECT_GT(covered, 500);
}

TEST(AppearanceRender, NonFiniteCountedAndValidation) {
    Config c = one_surface({0, 0, 0}, 100);
    c.set_appearance(0, address(failing_kernel));
    Simulation sim(uv_quad(), c);
    std::vector<float> img(16 * 16 * 4);
    AppearanceParams p = quad_view(16, 2);
    p.samples = 4;
    RenderStats st = sim.render_appearance(p, img.data());
    ASSERT_EQ(st.nonfinite.size(), 1u);
    EXPECT_EQ(st.nonfinite[0].event, kAppearanceEvent);
    EXPECT_EQ(st.nonfinite[0].statement, 3);
    EXPECT_EQ(st.nonfinite[0].count, st.kernel_calls);
    EXPECT_GT(st.kernel_calls, 0);
    // A NaN colour clamps to black, which still reflects the sky a little.
    const double centre = 1.5 * (2.0 * (8 + 0.5) / 16 - 1.0);
    EXPECT_NEAR(img[size_t(4 * (8 * 16 + 8))], shown({0, 0, 0}, to_quad_eye(centre, -centre))[0], 1e-3);

    auto bad = [&](std::function<void(AppearanceParams&)> edit) {
        AppearanceParams q = quad_view(4, 1);
        edit(q);
        return gamma_test::expect_error([&] { sim.render_appearance(q, img.data()); });
    };
    EXPECT_EQ(bad([](AppearanceParams& q) { q.samples = 0; }), "render_appearance: samples must be in 1..4096");
    EXPECT_EQ(bad([](AppearanceParams& q) { q.ao_samples = -1; }),
              "render_appearance: ao_samples must be in 0..4096");
    EXPECT_EQ(bad([](AppearanceParams& q) { q.fov_deg = 180; }), "render_appearance: fov_deg must be in (0, 180)");
    EXPECT_EQ(bad([](AppearanceParams& q) { q.target = q.eye; }), "render_appearance: eye and target must differ");
    EXPECT_EQ(bad([](AppearanceParams& q) { q.sun[1] = NAN; }),
              "render_appearance: eye, target, up and sun_direction must be finite");
    Config wrong = one_surface({0, 0, 0}, 10);
    wrong.set_appearance(1, address(uv_kernel));
    EXPECT_EQ(gamma_test::expect_error([&] { Simulation s(uv_quad(), wrong); }),
              "config: appearance surface index 1 out of range (1 surfaces)");
}
