// Saved scenes (a run folder's scene.json, `scan --saved-scene`): the JSON, the objects it names
// and the world it rebuilds.
#include "fuzz_input.h"
#include "romunect/sim/pile.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::filesystem::path file = romunect::fuzz::AsFile(data, size, "scene.json");
  romunect::fuzz::Expect([&] { romunect::sim::LoadSettledScene(file); });
  return 0;
}
