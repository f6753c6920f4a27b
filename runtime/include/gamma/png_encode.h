// PNG files of 8-bit RGB pictures, byte for byte as Pillow writes them
// (PIL.PngImagePlugin with libImaging/ZipEncode.c), encoded without Python:
// gammac's renders are encoded on the runtime's threads with the GIL
// released, where Pillow's encoder holds the GIL for the whole picture.
//
// Pillow's choices, repeated here: per row the filter (None, Up, Sub, Paeth,
// tried in that order, Average never) whose bytes have the least sum of
// |signed byte|; zlib deflate at `level` with a 32 KiB window, memLevel 9
// and Z_FILTERED, fed one filtered row at a time into an output buffer of
// max(65536, 4 * width) bytes; each full (and the last) buffer one IDAT
// chunk; no chunk besides IHDR, IDAT and IEND.  The bytes equal Pillow's
// when both use the same zlib (tests/test_png_encode.py compares them).
#pragma once
#include <cstdint>
#include <vector>

namespace gammart {

// The PNG of `rgb` (height rows of width * 3 bytes, top row first) at zlib
// `level` (1-9; Pillow's default, -1, is 6).  Throws gammart::Error on bad
// sizes or level.
std::vector<uint8_t> encode_png_rgb(const uint8_t* rgb, int width, int height, int level);

// encode_png_rgb of each picture, up to `threads` at a time (<= 0: all
// cores); the same bytes as one at a time.
struct RgbPicture {
    const uint8_t* rgb = nullptr;
    int width = 0, height = 0;
};
std::vector<std::vector<uint8_t>> encode_pngs_rgb(const std::vector<RgbPicture>& pictures, int level, int threads);

}  // namespace gammart
