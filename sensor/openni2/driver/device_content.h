// What a virtual device presents: its frames as a FrameSource, and what the device announces
// about them before the first frame (streams, length, rate, the chip's geometry).
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/frame_source.h"
#include "virtual_device_uri.h"

namespace romunect::openni2 {

struct DeviceContent {
  std::unique_ptr<FrameSource> source;
  bool has_depth = false, has_ir = false, has_raw = false;  // the images every frame holds
  std::optional<ColorCamera> color_camera;                  // when every frame holds a colour image
  int frame_count = 0;                                      // frames the source will deliver; 0 = endless
  double fps = 0.0;                                         // the source's own rate; 0 = unknown
  std::string extra_json;      // frames.json's unknown top-level keys (the chip's "ps1080")
  double time_origin_s = 0.0;  // the source time that becomes the device's timestamp 0
};

// Opens what a parsed URI names: a frame directory (looped with loop=1) or a feed library.
// Throws InputError (a bad or empty directory) or std::runtime_error (a feed that cannot open).
DeviceContent OpenDeviceContent(const ParsedVirtualDeviceUri& parsed);

}  // namespace romunect::openni2
