// encode_png_rgb: well-formed PNG files that decode to the picture, with
// Pillow's chunking and filter choices, and the same bytes at any thread count.
// (That the bytes are Pillow's own is tests/test_png_encode.py's.)
#include <gtest/gtest.h>
#include <zlib.h>

#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "gamma/error.h"
#include "gamma/png_encode.h"

using namespace gammart;

namespace {

uint32_t be32(const uint8_t* p) { return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | p[3]; }

struct Chunk {
    std::string tag;
    std::vector<uint8_t> data;
};

// The chunks of a PNG file, each CRC checked.
std::vector<Chunk> chunks_of(const std::vector<uint8_t>& png) {
    static const uint8_t signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    EXPECT_GE(png.size(), 8u);
    EXPECT_EQ(std::memcmp(png.data(), signature, 8), 0);
    std::vector<Chunk> out;
    size_t at = 8;
    while (at + 12 <= png.size()) {
        const uint32_t n = be32(&png[at]);
        EXPECT_LE(at + 12 + n, png.size());
        Chunk c{std::string(reinterpret_cast<const char*>(&png[at + 4]), 4),
                std::vector<uint8_t>(png.begin() + at + 8, png.begin() + at + 8 + n)};
        EXPECT_EQ(be32(&png[at + 8 + n]), uint32_t(crc32(0L, &png[at + 4], 4 + n))) << c.tag;
        out.push_back(std::move(c));
        at += 12 + n;
    }
    EXPECT_EQ(at, png.size());
    return out;
}

// The filtered rows (type byte + bytes) and the pixels a PNG decoder reads.
struct Decoded {
    std::vector<uint8_t> types, rgb;
};

Decoded decode(const std::vector<uint8_t>& png, int width, int height) {
    std::vector<uint8_t> stream;
    for (const Chunk& c : chunks_of(png))
        if (c.tag == "IDAT") stream.insert(stream.end(), c.data.begin(), c.data.end());
    const size_t bytes = size_t(width) * 3;
    std::vector<uint8_t> filtered(height * (bytes + 1));
    uLongf size = filtered.size();
    EXPECT_EQ(uncompress(filtered.data(), &size, stream.data(), stream.size()), Z_OK);
    EXPECT_EQ(size, filtered.size());
    Decoded d;
    d.rgb.assign(height * bytes, 0);
    for (int y = 0; y < height; ++y) {
        const uint8_t* f = &filtered[y * (bytes + 1)];
        d.types.push_back(f[0]);
        uint8_t* row = &d.rgb[y * bytes];
        const uint8_t* up = y ? row - bytes : nullptr;
        for (size_t i = 0; i < bytes; ++i) {
            const int a = i >= 3 ? row[i - 3] : 0, b = up ? up[i] : 0, c = (up && i >= 3) ? up[i - 3] : 0;
            int pred = 0;
            switch (f[0]) {
                case 0: pred = 0; break;
                case 1: pred = a; break;
                case 2: pred = b; break;
                case 3: pred = (a + b) / 2; break;
                case 4: {
                    const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
                    pred = (pa <= pb && pa <= pc) ? a : (pb <= pc) ? b : c;
                    break;
                }
                default: ADD_FAILURE() << "filter type " << int(f[0]);
            }
            row[i] = uint8_t(f[1 + i] + pred);
        }
    }
    return d;
}

std::vector<uint8_t> noise(int width, int height, unsigned seed, int levels) {
    std::mt19937 rng(seed);
    std::vector<uint8_t> rgb(size_t(width) * height * 3);
    for (auto& v : rgb) v = uint8_t((rng() % levels) * (255 / std::max(1, levels - 1)));
    return rgb;
}

}  // namespace

TEST(PngEncode, DecodesToThePictureWithPillowsChunks) {
    struct Case {
        int width, height, levels, level;
    };
    // noise of 256 levels does not compress: several IDAT chunks, the last one short
    for (const Case& k : {Case{1, 1, 256, 1}, Case{37, 51, 256, 1}, Case{300, 300, 256, 6}, Case{662, 512, 4, 1},
                          Case{5, 300, 2, 9}, Case{20000, 2, 256, 1}}) {
        const std::vector<uint8_t> rgb = noise(k.width, k.height, 7 + k.width, k.levels);
        const std::vector<uint8_t> png = encode_png_rgb(rgb.data(), k.width, k.height, k.level);
        const std::vector<Chunk> chunks = chunks_of(png);
        ASSERT_GE(chunks.size(), 3u);
        EXPECT_EQ(chunks.front().tag, "IHDR");
        ASSERT_EQ(chunks.front().data.size(), 13u);
        EXPECT_EQ(be32(&chunks.front().data[0]), uint32_t(k.width));
        EXPECT_EQ(be32(&chunks.front().data[4]), uint32_t(k.height));
        EXPECT_EQ(chunks.front().data[8], 8);   // bits
        EXPECT_EQ(chunks.front().data[9], 2);   // RGB
        EXPECT_EQ(chunks.back().tag, "IEND");
        EXPECT_TRUE(chunks.back().data.empty());
        // every IDAT but the last fills Pillow's buffer: max(65536, 4 * width) bytes
        const size_t buffer = std::max<size_t>(65536, size_t(k.width) * 4);
        for (size_t c = 1; c + 1 < chunks.size(); ++c) {
            EXPECT_EQ(chunks[c].tag, "IDAT");
            if (c + 2 < chunks.size()) {
                EXPECT_EQ(chunks[c].data.size(), buffer) << k.width << "x" << k.height;
            } else {
                EXPECT_LE(chunks[c].data.size(), buffer);
            }
        }
        if (k.levels == 256 && k.width * k.height >= 300 * 300) {
            EXPECT_GT(chunks.size(), 4u);
        }
        EXPECT_EQ(decode(png, k.width, k.height).rgb, rgb) << k.width << "x" << k.height;
    }
}

TEST(PngEncode, ChoosesPillowsFilterPerRow) {
    // row 0: zeros (None: nothing beats a sum of 0); row 1: a solid colour (Sub leaves
    // only its first pixel); row 2: row 1 again (Up: all zeros); row 3: a ramp along x
    // under row 2's solid colour (Sub: the ramp's constant step beats Up's and Paeth's);
    // row 4: row 3 plus one (Up: all ones)
    const int width = 40;
    std::vector<uint8_t> rgb(size_t(width) * 5 * 3, 0);
    auto px = [&](int y, int x, int c) -> uint8_t& { return rgb[(size_t(y) * width + x) * 3 + c]; };
    for (int x = 0; x < width; ++x)
        for (int c = 0; c < 3; ++c) {
            px(1, x, c) = px(2, x, c) = uint8_t(90 + 40 * c);
            px(3, x, c) = uint8_t(3 * x + c);
            px(4, x, c) = uint8_t(3 * x + c + 1);
        }
    const std::vector<uint8_t> png = encode_png_rgb(rgb.data(), width, 5, 1);
    const Decoded d = decode(png, width, 5);
    EXPECT_EQ(d.types, (std::vector<uint8_t>{0, 1, 2, 1, 2}));
    EXPECT_EQ(d.rgb, rgb);
}

TEST(PngEncode, ManyAtOnceAreTheSameBytesAtAnyThreadCount) {
    std::vector<std::vector<uint8_t>> pixels;
    std::vector<RgbPicture> pictures;
    for (int k = 0; k < 5; ++k) pixels.push_back(noise(120 + 7 * k, 90, 100 + k, 3 + k));
    for (int k = 0; k < 5; ++k) pictures.push_back({pixels[k].data(), 120 + 7 * k, 90});
    std::vector<std::vector<uint8_t>> one;
    for (const RgbPicture& p : pictures) one.push_back(encode_png_rgb(p.rgb, p.width, p.height, 1));
    for (int threads : {1, 2, 4}) EXPECT_EQ(encode_pngs_rgb(pictures, 1, threads), one) << threads << " threads";
    EXPECT_TRUE(encode_pngs_rgb({}, 1, 2).empty());
}

TEST(PngEncode, RefusesBadSizesAndLevels) {
    const uint8_t rgb[3] = {1, 2, 3};
    EXPECT_THROW(encode_png_rgb(rgb, 0, 1, 1), Error);
    EXPECT_THROW(encode_png_rgb(rgb, 1, 0, 1), Error);
    EXPECT_THROW(encode_png_rgb(rgb, (1 << 22) + 1, 1, 1), Error);   // refused before reading a byte
    EXPECT_THROW(encode_png_rgb(rgb, 1, 1, 10), Error);
    EXPECT_THROW(encode_png_rgb(rgb, 1, 1, -2), Error);
}
