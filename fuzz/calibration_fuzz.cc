// Calibration files (cv::FileStorage YAML) as --calibration reads them.
#include "fuzz_input.h"
#include "romunect/calib/calibration_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "calibration.yaml");
  romunect::fuzz::Expect([&] { romunect::calib::LoadCalibration(file); });
  return 0;
}
