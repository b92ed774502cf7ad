// frames.json of a frame directory (docs/frame-directory.md).
#include "fuzz_input.h"
#include "romunect/sensor/frame_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "frames.json");
  romunect::fuzz::Expect([&] { romunect::ReadFrameDirectoryManifest(file.parent_path()); });
  return 0;
}
