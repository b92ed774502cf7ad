// Rig JSON files (--rig).
#include "fuzz_input.h"
#include "romunect/sensor/rig.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "rig.json");
  romunect::fuzz::Expect([&] { romunect::LoadRig(file); });
  return 0;
}
