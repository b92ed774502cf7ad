// Camera files (cv::FileStorage YAML) as --camera reads them.
#include "fuzz_input.h"
#include "romunect/sensor/camera_model.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "camera.yaml");
  romunect::fuzz::Expect([&] { romunect::CameraModel::Load(file); });
  return 0;
}
