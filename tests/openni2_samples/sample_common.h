// Shared by the SDK-style samples: each is a plain OpenNI2 program, as an outside user writes
// one, that opens the first device (the virtual device named by ROMUNECT_VIRTUAL_DEVICE) and
// exits non-zero with a message when OpenNI2 or the device does not behave as a PS1080 does.
#pragma once

#include <cstdio>
#include <cstdlib>

#include <OpenNI.h>

namespace samples {

inline int Fail(const char* what) {
  std::fprintf(stderr, "%s: %s\n", what, openni::OpenNI::getExtendedError());
  return 1;
}

// A plane 1 m in front of the sensor (the test renders one) read in the PS1080's default depth
// unit, millimetres: its centre lies within the stock sensor's error of 1000.
inline bool CentreNear1m(const openni::VideoFrameRef& frame) {
  const auto* depth = static_cast<const openni::DepthPixel*>(frame.getData());
  const int centre = (frame.getHeight() / 2) * (frame.getStrideInBytes() / 2) + frame.getWidth() / 2;
  std::printf("frame %d: %dx%d, centre %d mm\n", frame.getFrameIndex(), frame.getWidth(), frame.getHeight(),
              depth[centre]);
  return std::abs(depth[centre] - 1000) <= 20;  // a few raw steps of 3 mm at 1 m
}

}  // namespace samples
