#include "dataset_png.h"

#include <zlib.h>

#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect::jobs::dataset {
namespace {

void PutBe32(std::string* out, uint32_t v) {
  for (int shift = 24; shift >= 0; shift -= 8) out->push_back(static_cast<char>((v >> shift) & 0xff));
}

void PutChunk(std::string* out, const char* type, const std::string& data) {
  PutBe32(out, static_cast<uint32_t>(data.size()));
  const size_t start = out->size();
  out->append(type, 4);
  out->append(data);
  PutBe32(out, static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(out->data() + start),
                                           static_cast<uInt>(out->size() - start))));
}

// The rows as PNG scanlines: a filter byte, then the samples (16-bit ones big-endian).
std::vector<uint8_t> Scanlines(const cv::Mat& image, bool sub_filter) {
  const int bpp = static_cast<int>(image.elemSize());
  const size_t row_bytes = static_cast<size_t>(image.cols) * bpp;
  std::vector<uint8_t> out((row_bytes + 1) * image.rows);
  std::vector<uint8_t> row(row_bytes);
  for (int v = 0; v < image.rows; ++v) {
    if (bpp == 2) {
      const uint16_t* p = image.ptr<uint16_t>(v);
      for (int u = 0; u < image.cols; ++u) {
        row[2 * u] = static_cast<uint8_t>(p[u] >> 8);
        row[2 * u + 1] = static_cast<uint8_t>(p[u] & 0xff);
      }
    } else {
      const uint8_t* p = image.ptr<uint8_t>(v);
      std::copy(p, p + row_bytes, row.begin());
    }
    uint8_t* line = out.data() + v * (row_bytes + 1);
    line[0] = sub_filter ? 1 : 0;
    for (size_t i = 0; i < row_bytes; ++i) {
      // Sub: each byte minus the same byte of the pixel to its left (mod 256)
      line[1 + i] = sub_filter && i >= static_cast<size_t>(bpp) ? static_cast<uint8_t>(row[i] - row[i - bpp]) : row[i];
    }
  }
  return out;
}

}  // namespace

void WritePng(const std::filesystem::path& path, const cv::Mat& image, PngKind kind) {
  ROMUNECT_CHECK((kind == PngKind::kMask && image.type() == CV_8UC1) ||
                 (kind != PngKind::kMask && image.type() == CV_16UC1));
  const std::vector<uint8_t> lines = Scanlines(image, kind != PngKind::kMask);
  // zlib level 1: run-length for masks and depth; Huffman only for noise, where matches are rare
  // and searching for them cost most of the time
  z_stream z{};
  ROMUNECT_CHECK(deflateInit2(&z, 1, Z_DEFLATED, 15, 8, kind == PngKind::kNoisy ? Z_HUFFMAN_ONLY : Z_RLE) == Z_OK);
  std::string compressed(deflateBound(&z, lines.size()), '\0');
  z.next_in = const_cast<Bytef*>(lines.data());
  z.avail_in = static_cast<uInt>(lines.size());
  z.next_out = reinterpret_cast<Bytef*>(compressed.data());
  z.avail_out = static_cast<uInt>(compressed.size());
  ROMUNECT_CHECK(deflate(&z, Z_FINISH) == Z_STREAM_END);
  compressed.resize(z.total_out);
  deflateEnd(&z);

  std::string png("\x89PNG\r\n\x1a\n", 8);
  std::string header;
  PutBe32(&header, static_cast<uint32_t>(image.cols));
  PutBe32(&header, static_cast<uint32_t>(image.rows));
  header += static_cast<char>(image.elemSize() * 8);  // bit depth
  header.append("\0\0\0\0", 4);                       // grayscale, deflate, adaptive filtering, no interlace
  PutChunk(&png, "IHDR", header);
  PutChunk(&png, "IDAT", compressed);
  PutChunk(&png, "IEND", "");
  WriteAtomically(path, [&png, &path](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out.write(png.data(), static_cast<std::streamsize>(png.size()));
    out.close();
    if (!out) throw std::runtime_error(path.string() + ": cannot write file (disk full?)");
  });
}

}  // namespace romunect::jobs::dataset
