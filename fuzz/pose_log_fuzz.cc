// Robot pose logs (CSV time_s,x_m,y_m,z_m,qw,qx,qy,qz).
#include "fuzz_input.h"
#include "romunect/sensor/openni2/pose_log.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "poses.csv");
  romunect::fuzz::Expect([&] { romunect::openni2::PoseLog::Load(file); });
  return 0;
}
