// The interface every frame producer implements: the simulator (sim/), the OpenNI2 device
// (sensor/openni2/) and a frame directory on disk (frame_io.h). Consumers (calib, fusion,
// the CLI) call Next() until kEndOfStream and cannot tell which source they have.
#pragma once

#include <string>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame.h"

namespace romunect {

enum class FrameStatus {
  kOk,           // *frame holds the next frame
  kBadFrame,     // this frame could not be delivered (*error says why); the stream goes on
  kEndOfStream,  // no more frames
};

const char* ToString(FrameStatus status);

class FrameSource {
 public:
  virtual ~FrameSource() = default;

  // The camera that all frames of this source share.
  virtual const CameraModel& camera() const = 0;

  // A one-line description for logs and reports ("frame directory /data/scan1, 50 frames").
  virtual std::string Describe() const = 0;

  // Delivers the next frame into *frame. On kBadFrame, *error (never null) says why.
  // A source that can no longer deliver at all (a device gone, a stream stalled past its
  // timeout) throws InputError naming the device.
  virtual FrameStatus Next(Frame* frame, std::string* error) = 0;
};

}  // namespace romunect
