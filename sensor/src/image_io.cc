#include "romunect/sensor/image_io.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <string>

#include <unistd.h>

#include <ImfChannelList.h>
#include <ImfCompression.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect {
namespace fs = std::filesystem;

namespace {

// Little- and big-endian appends to a byte buffer.
void PutLe32(std::string* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>(v >> (8 * i)));
}
void PutLe64(std::string* out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out->push_back(static_cast<char>(v >> (8 * i)));
}
void PutBe32(std::string* out, uint32_t v) {
  for (int i = 3; i >= 0; --i) out->push_back(static_cast<char>(v >> (8 * i)));
}

// CRC-32 of PNG (ISO 3309, reflected polynomial 0xEDB88320), eight bytes a step (slicing-by-8).
struct Crc32Tables {
  uint32_t t[8][256];
  Crc32Tables() {
    for (uint32_t n = 0; n < 256; ++n) {
      uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[0][n] = c;
    }
    for (uint32_t n = 0; n < 256; ++n) {
      for (int k = 1; k < 8; ++k) t[k][n] = (t[k - 1][n] >> 8) ^ t[0][t[k - 1][n] & 0xFF];
    }
  }
};

uint32_t Crc32(const unsigned char* p, size_t n, uint32_t crc = 0) {
  static const Crc32Tables tables;
  const auto& t = tables.t;
  crc = ~crc;
  for (; n >= 8; n -= 8, p += 8) {
    const uint32_t lo = crc ^ (p[0] | p[1] << 8 | p[2] << 16 | static_cast<uint32_t>(p[3]) << 24);
    crc = t[7][lo & 0xFF] ^ t[6][(lo >> 8) & 0xFF] ^ t[5][(lo >> 16) & 0xFF] ^ t[4][lo >> 24] ^ t[3][p[4]] ^
          t[2][p[5]] ^ t[1][p[6]] ^ t[0][p[7]];
  }
  for (; n > 0; --n) crc = t[0][(crc ^ *p++) & 0xFF] ^ (crc >> 8);
  return ~crc;
}

// Adler-32 of zlib: the sums stay below 2^32 for 5552 bytes between reductions.
uint32_t Adler32(const unsigned char* p, size_t n) {
  uint32_t a = 1, b = 0;
  while (n > 0) {
    const size_t block = std::min<size_t>(n, 5552);
    for (size_t i = 0; i < block; ++i) {
      a += p[i];
      b += a;
    }
    a %= 65521;
    b %= 65521;
    p += block;
    n -= block;
  }
  return b << 16 | a;
}

// A PNG chunk: length, type, data, CRC over type and data.
void PutPngChunk(std::string* out, const char* type, const std::string& data) {
  PutBe32(out, static_cast<uint32_t>(data.size()));
  const size_t start = out->size();
  out->append(type, 4);
  out->append(data);
  PutBe32(out, Crc32(reinterpret_cast<const unsigned char*>(out->data() + start), out->size() - start));
}

// A 16-bit greyscale PNG without compression: rows with filter 0 (none), big-endian samples, in
// stored deflate blocks of at most 65535 bytes, then the Adler-32 of zlib.
std::string EncodePng16Stored(const cv::Mat& image) {
  const size_t row_bytes = 1 + 2 * static_cast<size_t>(image.cols);
  std::string raw(row_bytes * image.rows, '\0');
  for (int v = 0; v < image.rows; ++v) {
    const uint16_t* in = image.ptr<uint16_t>(v);
    unsigned char* row = reinterpret_cast<unsigned char*>(raw.data()) + v * row_bytes + 1;  // [0]: filter 0
    for (int u = 0; u < image.cols; ++u) {
      row[2 * u] = static_cast<unsigned char>(in[u] >> 8);
      row[2 * u + 1] = static_cast<unsigned char>(in[u]);
    }
  }
  std::string zlib = {'\x78', '\x01'};  // deflate, 32 KB window, no dictionary (FCHECK: 0x7801 % 31 == 0)
  zlib.reserve(raw.size() + 5 * (raw.size() / 65535 + 1) + 6);
  for (size_t at = 0; at < raw.size(); at += 65535) {
    const uint16_t len = static_cast<uint16_t>(std::min<size_t>(65535, raw.size() - at));
    zlib.push_back(at + len >= raw.size() ? '\x01' : '\x00');  // BFINAL, BTYPE 00 (stored)
    zlib.push_back(static_cast<char>(len & 0xFF));
    zlib.push_back(static_cast<char>(len >> 8));
    zlib.push_back(static_cast<char>(~len & 0xFF));
    zlib.push_back(static_cast<char>((~len >> 8) & 0xFF));
    zlib.append(raw, at, len);
  }
  PutBe32(&zlib, Adler32(reinterpret_cast<const unsigned char*>(raw.data()), raw.size()));
  std::string header;
  PutBe32(&header, static_cast<uint32_t>(image.cols));
  PutBe32(&header, static_cast<uint32_t>(image.rows));
  header += {'\x10', '\x00', '\x00', '\x00', '\x00'};  // 16 bits, greyscale, deflate, filter set 0, no interlace
  std::string png = "\x89PNG\r\n\x1a\n";
  png.reserve(zlib.size() + 64);
  PutPngChunk(&png, "IHDR", header);
  PutPngChunk(&png, "IDAT", zlib);
  PutPngChunk(&png, "IEND", "");
  return png;
}

// An OpenEXR attribute: name, type, size, value.
void PutExrAttribute(std::string* out, const char* name, const char* type, const std::string& value) {
  out->append(name);
  out->push_back('\0');
  out->append(type);
  out->push_back('\0');
  PutLe32(out, static_cast<uint32_t>(value.size()));
  out->append(value);
}

// A single-part scanline OpenEXR with one float32 channel "Z" and no compression (one scanline
// per block): the header's required attributes, the block offsets, the blocks.
std::string EncodeExrUncompressed(const cv::Mat& depth) {
  const int width = depth.cols, height = depth.rows;
  std::string exr;
  PutLe32(&exr, 20000630);  // magic
  PutLe32(&exr, 2);         // version 2, single-part scanline
  std::string channels = "Z";
  channels.push_back('\0');
  PutLe32(&channels, 2);  // FLOAT
  channels.append(4, '\0');  // pLinear, reserved
  PutLe32(&channels, 1);  // x sampling
  PutLe32(&channels, 1);  // y sampling
  channels.push_back('\0');
  std::string window;
  for (const int v : {0, 0, width - 1, height - 1}) PutLe32(&window, static_cast<uint32_t>(v));
  auto float_bytes = [](float f) {
    uint32_t bits;
    std::memcpy(&bits, &f, 4);
    std::string s;
    PutLe32(&s, bits);
    return s;
  };
  PutExrAttribute(&exr, "channels", "chlist", channels);
  PutExrAttribute(&exr, "compression", "compression", std::string(1, '\0'));  // NO_COMPRESSION
  PutExrAttribute(&exr, "dataWindow", "box2i", window);
  PutExrAttribute(&exr, "displayWindow", "box2i", window);
  PutExrAttribute(&exr, "lineOrder", "lineOrder", std::string(1, '\0'));  // INCREASING_Y
  PutExrAttribute(&exr, "pixelAspectRatio", "float", float_bytes(1.0f));
  PutExrAttribute(&exr, "screenWindowCenter", "v2f", float_bytes(0.0f) + float_bytes(0.0f));
  PutExrAttribute(&exr, "screenWindowWidth", "float", float_bytes(1.0f));
  exr.push_back('\0');  // end of header
  const size_t row_bytes = 4 * static_cast<size_t>(width);
  const size_t first_block = exr.size() + 8 * static_cast<size_t>(height);
  exr.reserve(first_block + height * (8 + row_bytes));
  for (int y = 0; y < height; ++y) PutLe64(&exr, first_block + y * (8 + row_bytes));
  for (int y = 0; y < height; ++y) {
    PutLe32(&exr, static_cast<uint32_t>(y));
    PutLe32(&exr, static_cast<uint32_t>(row_bytes));
    exr.append(reinterpret_cast<const char*>(depth.ptr<float>(y)), row_bytes);  // little-endian floats
  }
  return exr;
}

}  // namespace

void WriteAtomically(const fs::path& path, const std::function<void(const fs::path& tmp)>& write) {
  static std::atomic<int> counter{0};
  // The temporary keeps the real extension: OpenCV and cv::FileStorage pick formats by it.
  std::string name = ".";
  name += path.stem().string();
  name += ".tmp-" + std::to_string(getpid()) + "-" + std::to_string(counter++);
  name += path.extension().string();
  const fs::path tmp = path.parent_path() / name;
  try {
    write(tmp);
    fs::rename(tmp, path);
  } catch (...) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw;
  }
}

void WriteTextAtomically(const fs::path& path, const std::string& text) {
  WriteAtomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    out.close();
    if (!out) throw InputError(path.string(), "", "cannot write file");
  });
}

cv::Mat ReadDepthExr(const fs::path& path) {
  if (!fs::exists(path)) throw InputError(path.string(), "", "file not found");
  try {
    Imf::InputFile file(path.c_str());
    const Imath::Box2i window = file.header().dataWindow();
    const int width = window.max.x - window.min.x + 1;
    const int height = window.max.y - window.min.y + 1;
    const Imf::Channel* channel = file.header().channels().findChannel("Z");
    if (channel == nullptr) {
      std::string names;
      for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it) {
        names += std::string(names.empty() ? "" : ", ") + it.name();
      }
      throw InputError(path.string(), "channel Z",
                       "missing (expected one float32 channel named Z; found: " + names + ")");
    }
    if (channel->type != Imf::FLOAT) {
      throw InputError(path.string(), "channel Z", "must be float32 (found half or uint)");
    }
    cv::Mat depth(height, width, CV_32F);
    Imf::FrameBuffer buffer;
    // Slices address pixels by their data-window coordinates: shift the base accordingly.
    char* base = reinterpret_cast<char*>(depth.ptr<float>()) -
                 (static_cast<ptrdiff_t>(window.min.x) + static_cast<ptrdiff_t>(window.min.y) * width) *
                     static_cast<ptrdiff_t>(sizeof(float));
    buffer.insert("Z", Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * width));
    file.setFrameBuffer(buffer);
    file.readPixels(window.min.y, window.max.y);
    return depth;
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    throw InputError(path.string(), "", std::string("not a readable OpenEXR file: ") + e.what());
  }
}

void WriteDepthExr(const fs::path& path, const cv::Mat& depth, ImageCompression compression) {
  ROMUNECT_CHECK(depth.type() == CV_32F && !depth.empty());
  static_assert(std::endian::native == std::endian::little, "EXR floats are written as they lie in memory");
  if (compression == ImageCompression::kFast) {
    WriteTextAtomically(path, EncodeExrUncompressed(depth));
    return;
  }
  const cv::Mat continuous = depth.isContinuous() ? depth : depth.clone();
  WriteAtomically(path, [&](const fs::path& tmp) {
    try {
      Imf::Header header(continuous.cols, continuous.rows);
      // ZIP at level 1: on a scan's frames 15-40 % faster than the default level for a few
      // per cent more bytes; writing frames is a stage of the scan loop.
      header.compression() = Imf::ZIP_COMPRESSION;
      header.zipCompressionLevel() = 1;
      header.channels().insert("Z", Imf::Channel(Imf::FLOAT));
      Imf::OutputFile file(tmp.c_str(), header);
      Imf::FrameBuffer buffer;
      buffer.insert("Z", Imf::Slice(Imf::FLOAT, const_cast<char*>(continuous.ptr<char>()),
                                    sizeof(float), sizeof(float) * continuous.cols));
      file.setFrameBuffer(buffer);
      file.writePixels(continuous.rows);
    } catch (const std::exception& e) {
      throw InputError(path.string(), "", std::string("cannot write OpenEXR file: ") + e.what());
    }
  });
}

cv::Mat ReadPng16(const fs::path& path) {
  if (!fs::exists(path)) throw InputError(path.string(), "", "file not found");
  cv::Mat image;
  try {
    image = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw InputError(path.string(), "", std::string("cannot be decoded: ") + e.what());
  }
  if (image.empty()) throw InputError(path.string(), "", "not a readable PNG image");
  if (image.type() != CV_16UC1) {
    throw InputError(path.string(), "pixel type",
                     "expected a 16-bit single-channel PNG, found " + cv::typeToString(image.type()));
  }
  return image;
}

namespace {
void WritePng(const fs::path& path, const cv::Mat& image) {
  WriteAtomically(path, [&](const fs::path& tmp) {
    bool ok = false;
    try {
      // Level 1: half the time of level 3 on IR frames for 4 % more bytes (measured on a scan).
      ok = cv::imwrite(tmp.string(), image, {cv::IMWRITE_PNG_COMPRESSION, 1});
    } catch (const cv::Exception& e) {
      throw InputError(path.string(), "", std::string("cannot write PNG: ") + e.what());
    }
    if (!ok) throw InputError(path.string(), "", "cannot write PNG");
  });
}
}  // namespace

void WritePng16(const fs::path& path, const cv::Mat& image, ImageCompression compression) {
  ROMUNECT_CHECK(image.type() == CV_16UC1 && !image.empty());
  if (compression == ImageCompression::kFast) {
    WriteTextAtomically(path, EncodePng16Stored(image));
    return;
  }
  WritePng(path, image);
}

void WritePicture(const fs::path& path, const cv::Mat& image) {
  ROMUNECT_CHECK((image.type() == CV_8UC1 || image.type() == CV_8UC3) && !image.empty());
  WritePng(path, image);
}

}  // namespace romunect
