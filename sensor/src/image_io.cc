#include "romunect/sensor/image_io.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <memory>
#include <sstream>
#include <string>
#include <string_view>

#include <fcntl.h>
#include <unistd.h>

#include <Iex.h>
#include <ImfChannelList.h>
#include <ImfCompression.h>
#include <ImfDoubleAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfIO.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfVecAttribute.h>
#include <png.h>
#include <zlib.h>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/input_limits.h"

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

// A PNG chunk's length, type, data and CRC (over type and data), appended to *out.
void PutPngChunk(std::string* out, const char* type, const char* data, size_t size) {
  PutBe32(out, static_cast<uint32_t>(size));
  const size_t start = out->size();
  out->append(type, 4);
  out->append(data, size);
  const uInt length = static_cast<uInt>(out->size() - start);
  PutBe32(out, static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(out->data() + start), length)));
}

// A 16-bit greyscale PNG without compression into *png: rows with filter 0 (none) and big-endian
// samples, in stored deflate blocks of at most 65535 bytes, then zlib's Adler-32. The buffers are
// the caller's to reuse (a frame's images are ~0.6 MB: fresh ones cost page faults each time).
void EncodePng16Stored(const cv::Mat& image, std::string* raw, std::string* png) {
  const size_t row_bytes = 1 + 2 * static_cast<size_t>(image.cols);
  raw->resize(row_bytes * image.rows);
  for (int v = 0; v < image.rows; ++v) {
    const uint16_t* in = image.ptr<uint16_t>(v);
    unsigned char* row = reinterpret_cast<unsigned char*>(raw->data()) + v * row_bytes;
    row[0] = 0;  // filter type 0
    for (int u = 0; u < image.cols; ++u) {
      row[1 + 2 * u] = static_cast<unsigned char>(in[u] >> 8);
      row[2 + 2 * u] = static_cast<unsigned char>(in[u]);
    }
  }
  std::string header;
  PutBe32(&header, static_cast<uint32_t>(image.cols));
  PutBe32(&header, static_cast<uint32_t>(image.rows));
  header += {'\x10', '\x00', '\x00', '\x00', '\x00'};  // 16 bits, greyscale, deflate, filter set 0, no interlace
  png->assign("\x89PNG\r\n\x1a\n");
  PutPngChunk(png, "IHDR", header.data(), header.size());
  // IDAT: the zlib stream, written in place after its length and type.
  const size_t blocks = (raw->size() + 65534) / 65535;
  const size_t idat = 2 + raw->size() + 5 * blocks + 4;
  PutBe32(png, static_cast<uint32_t>(idat));
  const size_t type_at = png->size();
  png->append("IDAT\x78\x01", 6);  // deflate, 32 KB window, no dictionary (FCHECK: 0x7801 % 31 == 0)
  for (size_t at = 0; at < raw->size(); at += 65535) {
    const uint16_t len = static_cast<uint16_t>(std::min<size_t>(65535, raw->size() - at));
    const char stored[5] = {at + len >= raw->size() ? '\x01' : '\x00',  // BFINAL, BTYPE 00 (stored)
                            static_cast<char>(len & 0xFF), static_cast<char>(len >> 8), static_cast<char>(~len & 0xFF),
                            static_cast<char>((~len >> 8) & 0xFF)};
    png->append(stored, 5);
    png->append(*raw, at, len);
  }
  PutBe32(png, static_cast<uint32_t>(
                   adler32(1, reinterpret_cast<const Bytef*>(raw->data()), static_cast<uInt>(raw->size()))));
  PutBe32(png, static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(png->data() + type_at),
                                           static_cast<uInt>(png->size() - type_at))));
  PutPngChunk(png, "IEND", nullptr, 0);
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

// A single-part scanline OpenEXR with one float32 channel "Y" and no compression (one scanline
// per block): the header's required attributes, the block offsets, the blocks.
// The buffer is the caller's to reuse, as EncodePng16Stored's.
void EncodeExrUncompressed(const cv::Mat& depth, std::string* out) {
  const int width = depth.cols, height = depth.rows;
  std::string& exr = *out;
  exr.clear();
  PutLe32(&exr, 20000630);  // magic
  PutLe32(&exr, 2);         // version 2, single-part scanline
  std::string channels = "Y";
  channels.push_back('\0');
  PutLe32(&channels, 2);     // FLOAT
  channels.append(4, '\0');  // pLinear, reserved
  PutLe32(&channels, 1);     // x sampling
  PutLe32(&channels, 1);     // y sampling
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

namespace {
// Writes text to file (no temporary); errors name `path` and say why (a full disk: "No space left
// on device").
void WritePlain(const fs::path& file, const std::string& text, const fs::path& path) {
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw InputError(path.string(), "", std::string("cannot write file: ") + std::strerror(errno));
  const char* data = text.data();
  size_t left = text.size();
  int error = 0;
  while (left > 0 && error == 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      error = n < 0 ? errno : EIO;
    } else {
      data += n;
      left -= static_cast<size_t>(n);
    }
  }
  if (::close(fd) != 0 && error == 0) error = errno;
  if (error != 0) throw InputError(path.string(), "", std::string("cannot write file: ") + std::strerror(error));
}
}  // namespace

void WriteTextAtomically(const fs::path& path, const std::string& text) {
  WriteAtomically(path, [&](const fs::path& tmp) { WritePlain(tmp, text, path); });
}

namespace {

// Writes all of data to fd; false on an error (errno set).
bool WriteAll(int fd, const char* data, size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return false;
    if (n == 0) {  // no progress and no error: report one rather than a stale errno
      errno = EIO;
      return false;
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  return true;
}

// The bytes of a fast image file, atomically, with direct I/O where the filesystem takes it: a
// scan writes ~3.6 MB of frame files per 30 Hz frame, and copying them into fresh page-cache pages
// cost ~8 ms of kernel CPU per frame on the 2-core machine (perf: copy_folio_from_iter_atomic);
// O_DIRECT sends them from an aligned buffer (0.1 ms per 1.2 MB file). Elsewhere a plain write.
void WriteFrameFileAtomically(const fs::path& path, const std::string& bytes) {
  constexpr size_t kAlign = 4096;  // buffer, length and offset alignment of O_DIRECT
  WriteAtomically(path, [&](const fs::path& tmp) {
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_DIRECT, 0644);
    if (fd < 0) {
      if (errno != EINVAL)
        throw InputError(path.string(), "", std::string("cannot write file: ") + std::strerror(errno));
      WritePlain(tmp, bytes, path);  // no direct I/O on this filesystem (tmpfs, say)
      return;
    }
    struct Free {
      void operator()(void* p) const { std::free(p); }
    };
    thread_local std::unique_ptr<char, Free> buffer;
    thread_local size_t capacity = 0;
    const size_t padded = (bytes.size() + kAlign - 1) / kAlign * kAlign;
    if (capacity < padded) {
      buffer.reset(static_cast<char*>(std::aligned_alloc(kAlign, padded)));
      if (buffer == nullptr) throw std::bad_alloc();
      capacity = padded;
    }
    std::memcpy(buffer.get(), bytes.data(), bytes.size());
    std::memset(buffer.get() + bytes.size(), 0, padded - bytes.size());
    bool ok = WriteAll(fd, buffer.get(), padded);
    if (!ok && errno == EINVAL) {  // direct I/O refused after all: plain writes from the start
      ok = ::ftruncate(fd, 0) == 0 && ::lseek(fd, 0, SEEK_SET) == 0 && ::fcntl(fd, F_SETFL, 0) == 0 &&
           WriteAll(fd, bytes.data(), bytes.size());
    }
    ok = ok && ::ftruncate(fd, static_cast<off_t>(bytes.size())) == 0;  // drop the padding
    const int error = errno;
    if (::close(fd) != 0 || !ok) {
      throw InputError(path.string(), "", std::string("cannot write file: ") + std::strerror(ok ? errno : error));
    }
  });
}

}  // namespace

namespace {

// An OpenEXR input stream over bytes in memory; reading past the end throws as a short file does.
class MemoryIStream : public Imf::IStream {
 public:
  MemoryIStream(std::string_view bytes, const std::string& name) : Imf::IStream(name.c_str()), bytes_(bytes) {}
  bool read(char c[], int n) override {
    if (n < 0 || pos_ > bytes_.size() || static_cast<size_t>(n) > bytes_.size() - pos_) {
      throw Iex::InputExc("unexpected end of file");
    }
    std::memcpy(c, bytes_.data() + pos_, static_cast<size_t>(n));
    pos_ += static_cast<size_t>(n);
    return pos_ < bytes_.size();
  }
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override { pos_ = pos; }

 private:
  std::string_view bytes_;
  uint64_t pos_ = 0;
};

uint32_t Le32(std::string_view b, size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}
uint32_t Be32(std::string_view b, size_t at) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}
uint32_t Be16(std::string_view b, size_t at) {
  return static_cast<uint32_t>(static_cast<unsigned char>(b[at])) << 8 | static_cast<unsigned char>(b[at + 1]);
}

// The size a PNG, JPEG (its first SOFn frame header) or BMP header gives, or nullopt for other
// formats and headers not found.
std::optional<cv::Size2l> PictureHeaderSize(std::string_view b) {
  if (b.size() >= 24 && b.compare(0, 8, "\x89PNG\r\n\x1a\n") == 0) {
    return cv::Size2l(static_cast<int64_t>(Be32(b, 16)), static_cast<int64_t>(Be32(b, 20)));
  }
  if (b.size() >= 26 && b.compare(0, 2, "BM") == 0) {
    const int64_t width = static_cast<int32_t>(Le32(b, 18));
    const int64_t height = static_cast<int32_t>(Le32(b, 22));  // negative: rows stored top-down
    return cv::Size2l(width, height < 0 ? -height : height);
  }
  if (b.size() >= 4 && b.compare(0, 2, "\xff\xd8") == 0) {
    for (size_t at = 2; at + 9 <= b.size();) {
      if (static_cast<unsigned char>(b[at]) != 0xff) return std::nullopt;
      const unsigned marker = static_cast<unsigned char>(b[at + 1]);
      if (marker == 0xff) {  // a fill byte
        ++at;
        continue;
      }
      if (marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc) {
        return cv::Size2l(Be16(b, at + 7), Be16(b, at + 5));  // SOFn: length, precision, height, width
      }
      at += 2 + Be16(b, at + 2);
    }
  }
  return std::nullopt;
}

// OpenEXR reads an attribute of a known type by its content, not its declared size: a value whose
// content does not end where its size says would leave the reader elsewhere than this scan.
// Returns why a value does not match its type, or "".
std::string ExrAttributeProblem(std::string_view value, std::string_view type, size_t max_name) {
  static const std::pair<std::string_view, size_t> kFixed[] = {
      {"box2i", 16},      {"box2f", 16},   {"chromaticities", 32},
      {"compression", 1}, {"double", 8},   {"envmap", 1},
      {"float", 4},       {"int", 4},      {"keycode", 28},
      {"lineOrder", 1},   {"m33f", 36},    {"m33d", 72},
      {"m44f", 64},       {"m44d", 128},   {"rational", 8},
      {"tiledesc", 9},    {"timecode", 8}, {"v2i", 8},
      {"v2f", 8},         {"v2d", 16},     {"v3i", 12},
      {"v3f", 12},        {"v3d", 24},     {"deepImageState", 1}};
  for (const auto& [name, size] : kFixed) {
    if (type == name) return value.size() == size ? "" : "a " + std::string(type) + " of the wrong size";
  }
  if (type == "chlist") {  // names with 16 bytes each, then an empty name: exactly the value
    size_t at = 0;
    while (at < value.size() && value[at] != '\0') {
      const size_t end = value.find('\0', at);
      if (end == std::string_view::npos || end - at > max_name || value.size() - end - 1 < 16)
        return "bad channel list";
      at = end + 1 + 16;
    }
    return at + 1 == value.size() ? "" : "bad channel list";
  }
  if (type == "preview") {  // width, height, then 4 bytes per pixel
    if (value.size() < 8) return "bad preview";
    const uint64_t pixels = static_cast<uint64_t>(Le32(value, 0)) * Le32(value, 4);
    return value.size() - 8 == 4 * pixels ? "" : "bad preview";
  }
  return "";  // strings, vectors and unknown types are read by their size
}

// The data window's size from the header of an OpenEXR file, read by hand so that nothing is
// allocated by what the file claims: attributes are "name\0type\0" + int32 size + value. Every
// attribute must lie inside the file (OpenEXR allocates the size an unknown one claims). Only
// single-part scanline or tiled files are read, as romunect writes and OpenCV reads.
cv::Size2l ExrHeaderSize(std::string_view b, const std::string& source) {
  const auto fail = [&](const std::string& why) -> cv::Size2l {
    throw InputError(source, "", "not a readable OpenEXR file: " + why);
  };
  if (b.size() < 8 || Le32(b, 0) != 20000630) return fail("no OpenEXR magic number");
  if (Le32(b, 4) & (0x800 | 0x1000)) return fail("deep or multi-part files are not read");
  // Names and types as OpenEXR reads them: at most 31 characters, 255 with the long-names flag.
  const size_t max_name = (Le32(b, 4) & 0x400) ? 255 : 31;
  std::optional<cv::Size2l> size;
  size_t at = 8;
  while (true) {
    if (at >= b.size()) return fail("truncated header");
    if (b[at] == '\0') break;  // end of the header
    const size_t name_end = b.find('\0', at);
    const size_t type_end = name_end == std::string_view::npos ? name_end : b.find('\0', name_end + 1);
    if (type_end == std::string_view::npos || b.size() - type_end < 5) return fail("truncated header");
    if (name_end - at > max_name || type_end - name_end - 1 > max_name) return fail("an attribute name is too long");
    const std::string_view name = b.substr(at, name_end - at);
    const uint32_t length = Le32(b, type_end + 1);
    const size_t value = type_end + 5;
    if (length > b.size() - value) {
      return fail("attribute " + std::string(name) + " claims " + std::to_string(length) +
                  " bytes, past the file's end");
    }
    if (const std::string why = ExrAttributeProblem(b.substr(value, length),
                                                    b.substr(name_end + 1, type_end - name_end - 1), max_name);
        !why.empty()) {
      return fail("attribute " + std::string(name) + ": " + why);
    }
    if (name == "dataWindow") {
      if (length != 16) return fail("dataWindow is not a box2i");
      const auto at_i = [&](int k) { return static_cast<int64_t>(static_cast<int32_t>(Le32(b, value + 4 * k))); };
      size = cv::Size2l(at_i(2) - at_i(0) + 1, at_i(3) - at_i(1) + 1);
    }
    at = value + length;
  }
  if (!size) return fail("no dataWindow");
  return *size;
}

// Refuses an image whose header size is out of bounds or not the expected one, before decoding.
void CheckHeaderSize(cv::Size2l size, const std::optional<cv::Size>& expected, const std::string& source) {
  CheckImageDimensions(size.width, size.height, source);
  if (expected && (size.width != expected->width || size.height != expected->height)) {
    std::ostringstream s;
    s << "expected " << expected->width << " x " << expected->height << ", found " << size.width << " x "
      << size.height;
    throw InputError(source, "image size", s.str());
  }
}

}  // namespace

cv::Mat DecodeDepthExr(std::string_view bytes, const std::string& source, const std::optional<cv::Size>& expected) {
  CheckHeaderSize(ExrHeaderSize(bytes, source), expected, source);
  try {
    MemoryIStream stream(bytes, source);
    Imf::InputFile file(stream);
    const Imath::Box2i window = file.header().dataWindow();
    const int width = window.max.x - window.min.x + 1;
    const int height = window.max.y - window.min.y + 1;
    CheckHeaderSize({width, height}, expected, source);  // OpenEXR's own reading of the header agrees
    // Depth is the channel "Z", or the one channel "Y" (what romunect and OpenCV write for a
    // single-channel float image).
    std::string name = "Z";
    const Imf::ChannelList& channels = file.header().channels();
    const Imf::Channel* channel = channels.findChannel("Z");
    int count = 0;
    for (auto it = channels.begin(); it != channels.end(); ++it) ++count;
    if (channel == nullptr && count == 1 && std::string(channels.begin().name()) == "Y") {
      name = "Y";
      channel = &channels.begin().channel();
    }
    if (channel == nullptr) {
      std::string names;
      for (auto it = channels.begin(); it != channels.end(); ++it) {
        names += std::string(names.empty() ? "" : ", ") + it.name();
      }
      throw InputError(source, "channel Y",
                       "missing (expected a single float32 channel Y, as romunect and OpenCV write, or a channel Z; "
                       "found: " + names + ")");
    }
    if (channel->type != Imf::FLOAT) {
      throw InputError(source, "channel " + name, "must be float32 (found half or uint)");
    }
    cv::Mat depth(height, width, CV_32F);
    Imf::FrameBuffer buffer;
    // Slices address pixels by their data-window coordinates: shift the base accordingly.
    char* base = reinterpret_cast<char*>(depth.ptr<float>()) -
                 (static_cast<ptrdiff_t>(window.min.x) + static_cast<ptrdiff_t>(window.min.y) * width) *
                     static_cast<ptrdiff_t>(sizeof(float));
    buffer.insert(name, Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * width));
    file.setFrameBuffer(buffer);
    file.readPixels(window.min.y, window.max.y);
    return depth;
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    throw InputError(source, "", std::string("not a readable OpenEXR file: ") + e.what());
  }
}

cv::Mat ReadDepthExr(const fs::path& path, const std::optional<cv::Size>& expected) {
  return DecodeDepthExr(ReadInputFile(path, kMaxImageFileBytes, "OpenEXR file"), path.string(), expected);
}

namespace {

constexpr const char* kMinAttribute = "romunect.min_W";
constexpr const char* kVoxelAttribute = "romunect.voxel_m";

// The compact (ZIP) EXR of WriteDepthExr, with a height map's geometry when given.
void WriteCompactExr(const fs::path& path, const cv::Mat& depth, const HeightMapGeometry* geometry) {
  const cv::Mat continuous = depth.isContinuous() ? depth : depth.clone();
  WriteAtomically(path, [&](const fs::path& tmp) {
    try {
      Imf::Header header(continuous.cols, continuous.rows);
      if (geometry != nullptr) {
        header.insert(kMinAttribute,
                      Imf::V3dAttribute(Imath::V3d(geometry->min_x_m, geometry->min_y_m, geometry->min_z_m)));
        header.insert(kVoxelAttribute, Imf::DoubleAttribute(geometry->voxel_m));
      }
      // ZIP at level 1: on a scan's frames 15-40 % faster than the default level for a few
      // per cent more bytes; writing frames is a stage of the scan loop.
      header.compression() = Imf::ZIP_COMPRESSION;
      header.zipCompressionLevel() = 1;
      header.channels().insert("Y", Imf::Channel(Imf::FLOAT));
      Imf::OutputFile file(tmp.c_str(), header);
      Imf::FrameBuffer buffer;
      buffer.insert("Y", Imf::Slice(Imf::FLOAT, const_cast<char*>(continuous.ptr<char>()), sizeof(float),
                                    sizeof(float) * continuous.cols));
      file.setFrameBuffer(buffer);
      file.writePixels(continuous.rows);
    } catch (const std::exception& e) {
      throw InputError(path.string(), "", std::string("cannot write OpenEXR file: ") + e.what());
    }
  });
}

}  // namespace

void WriteDepthExr(const fs::path& path, const cv::Mat& depth, ImageCompression compression) {
  ROMUNECT_CHECK(depth.type() == CV_32F && !depth.empty());
  static_assert(std::endian::native == std::endian::little, "EXR floats are written as they lie in memory");
  if (compression == ImageCompression::kFast) {
    thread_local std::string exr;
    EncodeExrUncompressed(depth, &exr);
    WriteFrameFileAtomically(path, exr);
    return;
  }
  WriteCompactExr(path, depth, nullptr);
}

void WriteHeightMapExr(const fs::path& path, const cv::Mat& height_m, const HeightMapGeometry& geometry) {
  ROMUNECT_CHECK(height_m.type() == CV_32F && !height_m.empty());
  ROMUNECT_CHECK(height_m.cols == geometry.nx && height_m.rows == geometry.ny && geometry.voxel_m > 0.0);
  WriteCompactExr(path, height_m, &geometry);
}

std::optional<HeightMapGeometry> ReadHeightMapGeometry(const fs::path& path) {
  const std::string source = path.string();
  const std::string bytes = ReadInputFile(path, kMaxImageFileBytes, "OpenEXR file");
  CheckHeaderSize(ExrHeaderSize(bytes, source), std::nullopt, source);
  try {
    MemoryIStream stream(bytes, source);
    Imf::InputFile file(stream);
    const Imf::Header& header = file.header();
    const auto* min = header.findTypedAttribute<Imf::V3dAttribute>(kMinAttribute);
    const auto* voxel = header.findTypedAttribute<Imf::DoubleAttribute>(kVoxelAttribute);
    if (min == nullptr || voxel == nullptr) return std::nullopt;
    const Imath::Box2i window = header.dataWindow();
    HeightMapGeometry g;
    g.min_x_m = min->value().x;
    g.min_y_m = min->value().y;
    g.min_z_m = min->value().z;
    g.voxel_m = voxel->value();
    g.nx = window.max.x - window.min.x + 1;
    g.ny = window.max.y - window.min.y + 1;
    return g;
  } catch (const std::exception& e) {
    throw InputError(source, "", std::string("not a readable OpenEXR file: ") + e.what());
  }
}

namespace {
// What a PNG reader accepts and how libpng hands its samples over.
struct PngLayout {
  int bit_depth;
  std::initializer_list<int> colour_types;  // IHDR colour types accepted
  const char* expected;                     // for the error: what was expected
  png_uint_32 format;                       // libpng's simplified-API output format
  int cv_type;
};

cv::Mat DecodePng(std::string_view bytes, const std::string& source, const std::optional<cv::Size>& expected,
                  const PngLayout& layout) {
  // The signature, then IHDR first (the PNG standard's order): width, height, bit depth, colour type.
  static constexpr char kSignature[] = "\x89PNG\r\n\x1a\n";
  if (bytes.size() < 33 || bytes.compare(0, 8, kSignature) != 0 || bytes.compare(12, 4, "IHDR") != 0) {
    throw InputError(source, "", "not a readable PNG image (no PNG signature and header)");
  }
  CheckHeaderSize({static_cast<int64_t>(Be32(bytes, 16)), static_cast<int64_t>(Be32(bytes, 20))}, expected, source);
  const int bit_depth = static_cast<unsigned char>(bytes[24]);
  const int colour_type = static_cast<unsigned char>(bytes[25]);
  if (bit_depth != layout.bit_depth || std::find(layout.colour_types.begin(), layout.colour_types.end(),
                                                 colour_type) == layout.colour_types.end()) {
    throw InputError(source, "pixel type",
                     std::string("expected ") + layout.expected + ", found bit depth " + std::to_string(bit_depth) +
                         " and colour type " + std::to_string(colour_type));
  }
  // libpng's simplified API: no longjmp through our frames. A 16-bit file without gamma chunks
  // reads as linear, so the samples come through unchanged (in native byte order).
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  if (png_image_begin_read_from_memory(&png, bytes.data(), bytes.size()) == 0) {
    const std::string why = png.message;
    png_image_free(&png);
    throw InputError(source, "", "not a readable PNG image (" + why + ")");
  }
  png.format = layout.format;
  cv::Mat image(static_cast<int>(png.height), static_cast<int>(png.width), layout.cv_type);
  // Row strides are in components (16-bit samples for 16-bit images), not bytes.
  if (png_image_finish_read(&png, nullptr, image.data, static_cast<png_int_32>(image.step[0] / image.elemSize1()),
                            nullptr) == 0) {
    const std::string why = png.message;
    png_image_free(&png);
    throw InputError(source, "", "cannot be decoded: " + why);
  }
  return image;
}
}  // namespace

cv::Mat DecodePng16(std::string_view bytes, const std::string& source, const std::optional<cv::Size>& expected) {
  return DecodePng(bytes, source, expected,
                   {16, {0}, "a 16-bit single-channel PNG", PNG_FORMAT_LINEAR_Y, CV_16UC1});
}

cv::Mat ReadPng16(const fs::path& path, const std::optional<cv::Size>& expected) {
  return DecodePng16(ReadInputFile(path, kMaxImageFileBytes, "PNG file"), path.string(), expected);
}

cv::Mat DecodePngRgb8(std::string_view bytes, const std::string& source, const std::optional<cv::Size>& expected) {
  // An alpha channel is dropped (composited on black).
  return DecodePng(bytes, source, expected,
                   {8, {2, 6}, "an 8-bit RGB (or RGBA) PNG", PNG_FORMAT_RGB, CV_8UC3});
}

cv::Mat ReadPngRgb8(const fs::path& path, const std::optional<cv::Size>& expected) {
  return DecodePngRgb8(ReadInputFile(path, kMaxImageFileBytes, "PNG file"), path.string(), expected);
}

void CheckPictureHeader(std::string_view bytes, const std::string& source) {
  if (const std::optional<cv::Size2l> size = PictureHeaderSize(bytes)) {
    CheckImageDimensions(size->width, size->height, source);
  }
}

namespace {
// 16-bit grey, 8-bit grey or 8-bit BGR (RGB with rgb) through libpng's simplified writer, in its fast setting
// (no filters, a low zlib level): frame files are written at frame rate.
void WritePng(const fs::path& path, const cv::Mat& image, bool rgb = false) {
  WriteAtomically(path, [&](const fs::path& tmp) {
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    png.width = static_cast<png_uint_32>(image.cols);
    png.height = static_cast<png_uint_32>(image.rows);
    png.format = image.type() == CV_16UC1  ? PNG_FORMAT_LINEAR_Y
                 : image.type() == CV_8UC3 ? (rgb ? PNG_FORMAT_RGB : PNG_FORMAT_BGR)
                                           : PNG_FORMAT_GRAY;
    png.flags = PNG_IMAGE_FLAG_FAST;
    // Row strides are in components (samples), not bytes.
    const int ok = png_image_write_to_file(&png, tmp.c_str(), 0, image.data,
                                           static_cast<png_int_32>(image.step[0] / image.elemSize1()), nullptr);
    if (ok == 0) throw InputError(path.string(), "", std::string("cannot write PNG: ") + png.message);
  });
}
}  // namespace

void WritePng16(const fs::path& path, const cv::Mat& image, ImageCompression compression) {
  ROMUNECT_CHECK(image.type() == CV_16UC1 && !image.empty());
  if (compression == ImageCompression::kFast) {
    thread_local std::string raw, png;
    EncodePng16Stored(image, &raw, &png);
    WriteFrameFileAtomically(path, png);
    return;
  }
  WritePng(path, image);
}

void WritePngRgb8(const fs::path& path, const cv::Mat& image) {
  ROMUNECT_CHECK(image.type() == CV_8UC3 && !image.empty());
  WritePng(path, image, true);
}

void WritePicture(const fs::path& path, const cv::Mat& image) {
  ROMUNECT_CHECK((image.type() == CV_8UC1 || image.type() == CV_8UC3) && !image.empty());
  WritePng(path, image);
}

}  // namespace romunect
