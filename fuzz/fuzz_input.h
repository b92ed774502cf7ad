// Shared by the fuzz targets: the input as a file, for readers that take a path. The file lives
// in $TMPDIR (or /tmp), one per process, rewritten for every input.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "romunect/sensor/errors.h"

namespace romunect::fuzz {

// A folder of this process's own, removed at exit.
inline const std::filesystem::path& ScratchFolder() {
  static const std::filesystem::path dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::filesystem::path d = std::filesystem::path(tmp != nullptr ? tmp : "/tmp") /
                              ("romunect_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(ScratchFolder(), ec);
    });
    return d;
  }();
  return dir;
}

// Writes the input to `name` in the scratch folder and returns its path.
inline std::filesystem::path AsFile(const uint8_t* data, size_t size, const std::string& name) {
  const std::filesystem::path path = ScratchFolder() / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

// Runs a reader: InputError is the expected answer to bad input; anything else escapes and
// libFuzzer reports it (as it does crashes, leaks and sanitizer findings).
template <typename F>
void Expect(F f) {
  try {
    f();
  } catch (const InputError&) {
  }
}

}  // namespace romunect::fuzz
