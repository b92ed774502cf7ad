// Meshes as --mesh reads them: the first byte picks STL or OBJ, the rest is the file.
#include "fuzz_input.h"
#include "romunect/sensor/mesh.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::filesystem::path file = romunect::fuzz::AsFile(data + 1, size - 1,
                                                            data[0] % 2 == 0 ? "mesh.stl" : "mesh.obj");
  romunect::fuzz::Expect([&] { romunect::LoadMesh(file); });
  return 0;
}
