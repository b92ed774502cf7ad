// 16-bit PNG from memory, with and without an expected size.
#include <string_view>

#include "fuzz_input.h"
#include "romunect/sensor/image_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  romunect::fuzz::Expect([&] { romunect::DecodePng16(bytes, "input.png"); });
  romunect::fuzz::Expect([&] { romunect::DecodePng16(bytes, "input.png", cv::Size(80, 60)); });
  return 0;
}
