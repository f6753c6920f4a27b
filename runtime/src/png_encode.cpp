// PNG encoding of RGB pictures as Pillow does it (see gamma/png_encode.h).
#include "gamma/png_encode.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <string>

#include "gamma/error.h"
#include "gamma/threads.h"

namespace gammart {
namespace {

constexpr int kBytesPerPixel = 3;
// Pillow's ImageFile.MAXBLOCK: the least output buffer, so the least IDAT chunk but the last.
constexpr size_t kMaxBlock = 65536;
// PNG filter types (the first byte of each filtered row).
constexpr uint8_t kNone = 0, kSub = 1, kUp = 2, kPaeth = 4;

// Pillow's "distance from zero" of a row of filtered bytes: the sum of
// |byte as signed|, -128 counting 128, i.e. of min(v, 256 - v).
int cost(const uint8_t* v, size_t n) {
    int sum = 0;
    for (size_t i = 0; i < n; ++i) sum += std::min(v[i], uint8_t(0u - v[i]));
    return sum;
}

void put_u32(std::vector<uint8_t>& out, uint32_t v) {
    const uint8_t b[4] = {uint8_t(v >> 24), uint8_t(v >> 16), uint8_t(v >> 8), uint8_t(v)};
    out.insert(out.end(), b, b + 4);
}

void put_chunk(std::vector<uint8_t>& out, const char tag[4], const uint8_t* data, size_t size) {
    put_u32(out, uint32_t(size));
    const size_t start = out.size();
    out.insert(out.end(), tag, tag + 4);
    if (size) out.insert(out.end(), data, data + size);
    put_u32(out, uint32_t(crc32(0L, out.data() + start, uInt(4 + size))));
}

// The filter ZipEncode.c chooses for the row `raw` under `prev` (zeros above
// the top row): the buffer (type byte, then the filtered bytes) of Up, Sub or
// Paeth, written here, or nullptr for None (the row as it is).  The filters
// are tried in Pillow's order, each only while the best so far is not all
// zeros, and one replaces the best only if strictly better.
const uint8_t* filter_row(const uint8_t* raw, const uint8_t* prev, size_t bytes, uint8_t* up, uint8_t* sub,
                          uint8_t* paeth) {
    constexpr size_t bpp = kBytesPerPixel;
    const size_t head = std::min(bpp, bytes);
    int sum = cost(raw, bytes);
    const uint8_t* best = nullptr;     // nullptr: None
    if (sum > 0) {
        for (size_t i = 0; i < bytes; ++i) up[1 + i] = uint8_t(raw[i] - prev[i]);
        const int s = cost(up + 1, bytes);
        if (s < sum) best = up, sum = s;
    }
    if (sum > 0) {
        for (size_t i = 0; i < head; ++i) sub[1 + i] = raw[i];
        for (size_t i = bpp; i < bytes; ++i) sub[1 + i] = uint8_t(raw[i] - raw[i - bpp]);
        const int s = cost(sub + 1, bytes);
        if (s < sum) best = sub, sum = s;
    }
    if (sum > 0) {
        for (size_t i = 0; i < head; ++i) paeth[1 + i] = uint8_t(raw[i] - prev[i]);
        for (size_t i = bpp; i < bytes; ++i) {
            const int16_t a = raw[i - bpp], b = prev[i], c = prev[i - bpp];
            const int16_t pa = int16_t(std::abs(b - c)), pb = int16_t(std::abs(a - c)),
                          pc = int16_t(std::abs(a + b - 2 * c));
            const int16_t predicted = (pa <= pb && pa <= pc) ? a : (pb <= pc) ? b : c;
            paeth[1 + i] = uint8_t(raw[i] - predicted);
        }
        const int s = cost(paeth + 1, bytes);
        if (s < sum) best = paeth, sum = s;
    }
    return best;
}

}  // namespace

std::vector<uint8_t> encode_png_rgb(const uint8_t* rgb, int width, int height, int level) {
    // a row's filter sums (int, as Pillow's) stay below 2^31: 128 * 3 * 2^22 = 1.6e9
    if (width < 1 || height < 1 || width > (1 << 22) || height > (1 << 24))
        throw Error("encode_png: width must be from 1 to 4194304 and height from 1 to 16777216");
    if (level < -1 || level > 9) throw Error("encode_png: the zlib level must be from -1 to 9");
    const size_t bytes = size_t(width) * kBytesPerPixel;
    // ImageFile._save's buffer: each encoder call returns it full (an IDAT chunk) or ends the image
    const size_t bufsize = std::max(kMaxBlock, size_t(width) * 4);

    std::vector<uint8_t> out;
    static const uint8_t signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    out.insert(out.end(), signature, signature + 8);
    uint8_t ihdr[13];
    for (int k = 0; k < 4; ++k) {
        ihdr[k] = uint8_t(uint32_t(width) >> (24 - 8 * k));
        ihdr[4 + k] = uint8_t(uint32_t(height) >> (24 - 8 * k));
    }
    ihdr[8] = 8;    // bits per sample
    ihdr[9] = 2;    // colour type: RGB
    ihdr[10] = ihdr[11] = ihdr[12] = 0;   // deflate, adaptive filtering, no interlace
    put_chunk(out, "IHDR", ihdr, sizeof ihdr);

    z_stream z{};
    if (deflateInit2(&z, level, Z_DEFLATED, 15, 9, Z_FILTERED) != Z_OK)
        throw Error("encode_png: zlib could not start (out of memory?)");
    std::vector<uint8_t> none(bytes + 1), up(bytes + 1), sub(bytes + 1), paeth(bytes + 1), zeros(bytes, 0);
    none[0] = kNone, up[0] = kUp, sub[0] = kSub, paeth[0] = kPaeth;
    std::vector<uint8_t> buffer(bufsize);
    z.next_out = buffer.data();
    z.avail_out = uInt(bufsize);
    auto flush_full = [&](bool last) {
        put_chunk(out, "IDAT", buffer.data(), bufsize - z.avail_out);
        if (!last) {
            z.next_out = buffer.data();
            z.avail_out = uInt(bufsize);
        }
    };
    int err = Z_OK;
    for (int y = 0; y < height && err >= 0; ++y) {
        const uint8_t* raw = rgb + size_t(y) * bytes;
        const uint8_t* prev = y ? raw - bytes : zeros.data();
        const uint8_t* line = filter_row(raw, prev, bytes, up.data(), sub.data(), paeth.data());
        if (!line) {
            std::memcpy(none.data() + 1, raw, bytes);
            line = none.data();
        }
        z.next_in = const_cast<Bytef*>(line);
        z.avail_in = uInt(bytes + 1);
        // as ZipEncode.c: a row's input left over when the buffer filled is deflated
        // (Z_NO_FLUSH) into the next buffer before the next row
        do {
            err = deflate(&z, Z_NO_FLUSH);
            if (err < 0) break;
            if (z.avail_out == 0) flush_full(false);
        } while (z.avail_in > 0);
    }
    while (err >= 0) {
        err = deflate(&z, Z_FINISH);
        if (err == Z_STREAM_END) {
            flush_full(true);
            break;
        }
        if (err >= 0 && z.avail_out == 0) flush_full(false);
    }
    deflateEnd(&z);
    if (err != Z_STREAM_END) throw std::runtime_error("encode_png: zlib failed (" + std::to_string(err) + ")");
    put_chunk(out, "IEND", nullptr, 0);
    return out;
}

std::vector<std::vector<uint8_t>> encode_pngs_rgb(const std::vector<RgbPicture>& pictures, int level, int threads) {
    std::vector<std::vector<uint8_t>> out(pictures.size());
    auto one = [&](size_t k) { out[k] = encode_png_rgb(pictures[k].rgb, pictures[k].width, pictures[k].height, level); };
    if (pictures.size() <= 1 || resolve_threads(threads) == 1) {
        for (size_t k = 0; k < pictures.size(); ++k) one(k);
        return out;
    }
    run_with_threads(threads, [&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, pictures.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t k = r.begin(); k != r.end(); ++k) one(k);
        });
    });
    return out;
}

}  // namespace gammart
