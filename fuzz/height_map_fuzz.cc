// The height-map geometry an EXR records (romunect.min_W, romunect.voxel_m).
#include "fuzz_input.h"
#include "romunect/sensor/image_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "map.exr");
  romunect::fuzz::Expect([&] { romunect::ReadHeightMapGeometry(file); });
  return 0;
}
