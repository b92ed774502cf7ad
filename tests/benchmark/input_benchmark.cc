// Bounded input: what a hostile file costs before it is refused. A decompression bomb (a small
// PNG whose IHDR claims 16384 x 16384 16-bit pixels, 512 MB decoded; an EXR whose dataWindow
// claims 16384 x 16384 floats) must be refused in under 50 ms and 50 MB: the reader reads the
// header, not the pixels. Counters: peak_rss_growth_MB (the process's peak resident set after
// the run minus before it) and file_MB.
//   build/bin/input_benchmark
#include <sys/resource.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include <benchmark/benchmark.h>
#include <zlib.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

void PutBe32(std::string* out, uint32_t v) {
  for (int i = 3; i >= 0; --i) out->push_back(static_cast<char>(v >> (8 * i)));
}

void Chunk(std::string* png, const char* type, const std::string& data) {
  PutBe32(png, static_cast<uint32_t>(data.size()));
  const std::string body = std::string(type, 4) + data;
  png->append(body);
  PutBe32(png, static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(body.data()), body.size())));
}

// A valid 16-bit greyscale PNG of side x side zeros: ~0.5 MB of deflate for 512 MB of pixels.
std::string PngBomb(uint32_t side) {
  std::string header;
  PutBe32(&header, side);
  PutBe32(&header, side);
  header += std::string("\x10\x00\x00\x00\x00", 5);
  z_stream z{};
  deflateInit(&z, 9);
  const std::string row(1 + 2 * static_cast<size_t>(side), '\0');  // filter byte 0, then zeros
  std::string idat;
  char out[1 << 16];
  for (uint32_t y = 0; y <= side; ++y) {
    const bool last = y == side;
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(row.data()));
    z.avail_in = last ? 0 : static_cast<uInt>(row.size());
    do {
      z.next_out = reinterpret_cast<Bytef*>(out);
      z.avail_out = sizeof(out);
      deflate(&z, last ? Z_FINISH : Z_NO_FLUSH);
      idat.append(out, sizeof(out) - z.avail_out);
    } while (z.avail_out == 0);
  }
  deflateEnd(&z);
  std::string png = "\x89PNG\r\n\x1a\n";
  Chunk(&png, "IHDR", header);
  Chunk(&png, "IDAT", idat);
  Chunk(&png, "IEND", "");
  return png;
}

// A small EXR whose dataWindow is rewritten to claim side x side pixels.
std::string ExrBomb(const fs::path& dir, int32_t side) {
  WriteDepthExr(dir / "small.exr", cv::Mat(60, 80, CV_32F, cv::Scalar(0.5)));
  std::ifstream in(dir / "small.exr", std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), {});
  const size_t value = bytes.find("dataWindow") + std::strlen("dataWindow") + 1 + std::strlen("box2i") + 1 + 4;
  const int32_t max = side - 1;
  std::memcpy(&bytes[value + 8], &max, 4);
  std::memcpy(&bytes[value + 12], &max, 4);
  return bytes;
}

template <typename Read>
void Refuse(benchmark::State& state, const std::string& bytes, const fs::path& file, Read read) {
  std::ofstream(file, std::ios::binary) << bytes;
  const double before_mb = PeakRssMb();
  for (auto _ : state) {
    try {
      read(file);
      state.SkipWithError("the bomb was not refused");
    } catch (const InputError&) {
    }
  }
  state.counters["peak_rss_growth_MB"] = PeakRssMb() - before_mb;
  state.counters["file_MB"] = bytes.size() / 1e6;
  fs::remove(file);
}

void BM_RefusePngBomb(benchmark::State& state) {
  const fs::path dir = fs::temp_directory_path();
  Refuse(state, PngBomb(16384), dir / "romunect_png_bomb.png", [](const fs::path& f) { ReadPng16(f); });
}
BENCHMARK(BM_RefusePngBomb)->Unit(benchmark::kMillisecond);

// The same bomb where a frame directory reads it: against the camera's size.
void BM_RefusePngBombAgainstTheCamera(benchmark::State& state) {
  const fs::path dir = fs::temp_directory_path();
  Refuse(state, PngBomb(16384), dir / "romunect_png_bomb.png",
         [](const fs::path& f) { ReadPng16(f, cv::Size(640, 480)); });
}
BENCHMARK(BM_RefusePngBombAgainstTheCamera)->Unit(benchmark::kMillisecond);

void BM_RefuseExrBomb(benchmark::State& state) {
  const fs::path dir = fs::temp_directory_path();
  Refuse(state, ExrBomb(dir, 16384), dir / "romunect_exr_bomb.exr", [](const fs::path& f) { ReadDepthExr(f); });
}
BENCHMARK(BM_RefuseExrBomb)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace romunect

BENCHMARK_MAIN();
