// The .oni container checks that run before libOpenNI2's file driver reads a recording.
#include <cstddef>
#include <cstdint>

#include "romunect/sensor/openni2/oni_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  (void)romunect::openni2::OniStructureProblem(data, size);  // never throws; a problem is a string
  return 0;
}
