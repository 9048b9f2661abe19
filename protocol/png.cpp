#include "png.h"

#include <zlib.h>

#include <algorithm>
#include <cstdlib>
#include <stdexcept>
#include <vector>

namespace lf::protocol {

namespace {

// The predictor of PNG's filter 4 (Paeth 1991): whichever of left, above
// and upper-left is closest to left + above - upper-left.
uint8_t paeth(int left, int above, int upper_left) {
    const int p = left + above - upper_left;
    const int to_left = std::abs(p - left), to_above = std::abs(p - above), to_upper_left = std::abs(p - upper_left);
    if (to_left <= to_above && to_left <= to_upper_left) return uint8_t(left);
    return to_above <= to_upper_left ? uint8_t(above) : uint8_t(upper_left);
}

// One row as PNG stores it: the filter type, then each byte less its Paeth
// prediction (bytes before the row and above the first row are 0).
void filter_row(const uint8_t* row, const uint8_t* above, size_t bytes, int channels, uint8_t* out) {
    out[0] = 4;
    for (size_t i = 0; i < bytes; ++i) {
        const int left = i >= size_t(channels) ? row[i - size_t(channels)] : 0;
        const int up = above ? above[i] : 0;
        const int upper_left = above && i >= size_t(channels) ? above[i - size_t(channels)] : 0;
        out[1 + i] = uint8_t(row[i] - paeth(left, up, upper_left));
    }
}

// One strip's filtered rows, deflated (raw, no zlib header) and ended by a
// full flush, or by the stream's end for the last strip; with the Adler-32
// of its uncompressed bytes and their count, for the stream's checksum.
struct Strip {
    std::string deflated;
    uLong adler = 0;
    size_t bytes = 0;
};

Strip deflate_strip(const uint8_t* pixels, int width, int height, int channels, int first_row, bool last) {
    const size_t row_bytes = size_t(width) * size_t(channels);
    const int rows = std::min(kPngStripRows, height - first_row);
    std::vector<uint8_t> filtered(size_t(rows) * (row_bytes + 1));
    for (int r = 0; r < rows; ++r) {
        const uint8_t* row = pixels + size_t(first_row + r) * row_bytes;
        filter_row(row, first_row + r > 0 ? row - row_bytes : nullptr, row_bytes, channels,
                   filtered.data() + size_t(r) * (row_bytes + 1));
    }
    z_stream z{};
    if (deflateInit2(&z, 6, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK)
        throw std::runtime_error("PNG: zlib could not start a deflate stream");
    Strip strip;
    strip.deflated.resize(deflateBound(&z, uLong(filtered.size())) + 16);
    z.next_in = filtered.data();
    z.avail_in = uInt(filtered.size());
    z.next_out = reinterpret_cast<Bytef*>(strip.deflated.data());
    z.avail_out = uInt(strip.deflated.size());
    const int status = deflate(&z, last ? Z_FINISH : Z_FULL_FLUSH);
    strip.deflated.resize(strip.deflated.size() - z.avail_out);
    deflateEnd(&z);
    if (status != (last ? Z_STREAM_END : Z_OK) || z.avail_in != 0)
        throw std::runtime_error("PNG: zlib could not deflate rows " + std::to_string(first_row) + " to " +
                                 std::to_string(first_row + rows - 1));
    strip.adler = adler32(adler32(0L, Z_NULL, 0), filtered.data(), uInt(filtered.size()));
    strip.bytes = filtered.size();
    return strip;
}

void append_u32(std::string& out, uint32_t v) {
    for (int shift = 24; shift >= 0; shift -= 8) out.push_back(char((v >> shift) & 0xff));
}

// A chunk: length, type, data, CRC-32 of type and data.
void append_chunk(std::string& out, const char type[4], const std::string& data) {
    append_u32(out, uint32_t(data.size()));
    const size_t type_at = out.size();
    out.append(type, 4);
    out += data;
    const auto* crc_from = reinterpret_cast<const Bytef*>(out.data() + type_at);
    append_u32(out, uint32_t(crc32(crc32(0L, Z_NULL, 0), crc_from, uInt(4 + data.size()))));
}

}  // namespace

std::string encode_png(const uint8_t* pixels, int width, int height, int channels, const PngStripRunner& run) {
    if (width <= 0 || height <= 0 || (channels != 3 && channels != 4))
        throw std::invalid_argument("PNG: cannot encode a " + std::to_string(width) + "x" + std::to_string(height) +
                                    " image of " + std::to_string(channels) + " channels (3 or 4)");
    const size_t count = size_t((height + kPngStripRows - 1) / kPngStripRows);
    std::vector<Strip> strips(count);
    const auto strip = [&](size_t i) {
        strips[i] = deflate_strip(pixels, width, height, channels, int(i) * kPngStripRows, i + 1 == count);
    };
    if (run) run(count, strip);
    else
        for (size_t i = 0; i < count; ++i) strip(i);

    // The zlib stream (RFC 1950): header, the strips' deflate blocks, the
    // Adler-32 of all the filtered rows.
    std::string idat = {char(0x78), char(0x9c)};
    uLong adler = strips[0].adler;
    for (size_t i = 0; i < count; ++i) {
        idat += strips[i].deflated;
        if (i > 0) adler = adler32_combine(adler, strips[i].adler, z_off_t(strips[i].bytes));
    }
    append_u32(idat, uint32_t(adler));

    std::string header;
    append_u32(header, uint32_t(width));
    append_u32(header, uint32_t(height));
    header += {char(8), char(channels == 4 ? 6 : 2), char(0), char(0), char(0)};  // 8 bits, RGBA or RGB
    std::string png = "\x89PNG\r\n\x1a\n";
    append_chunk(png, "IHDR", header);
    append_chunk(png, "IDAT", idat);
    append_chunk(png, "IEND", "");
    return png;
}

}  // namespace lf::protocol
