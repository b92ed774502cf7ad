// OpenNI2Source: a FrameSource over libOpenNI2, for a real PS1080/Kinect-class device, the
// virtual device (virtual_device.h) or an .oni recording played back by OpenNI2's file driver.
// It opens a device by URI, starts depth and IR (640 x 480 at 30 Hz when offered), turns
// mirroring off, leaves depth in the IR camera's geometry (registration off: the PS1080 computes
// depth in that camera), and reads the chip's geometry (zero plane, baseline) for calibration.
//
// Frames: depth_m CV_32F metres from the wire's 1 mm or 100 um counts (depth_units.h) (or,
// with `raw`, raw CV_16U: the chip's 11-bit shifts as sent), ir
// CV_16U as sent (GRAY16), index = device frame number - first one (or - 1 for sources that
// announce their length, which number frames from 1; gaps = dropped frames),
// time_s = (device timestamp - first timestamp), exact to OpenNI2's microsecond. No poses: wrap
// the source in a PoseLogSource (pose_log.h) for T_B_H.
// A stream that sends nothing for `timeout_s` (device unplugged or stalled) makes Next() throw
// InputError naming the URI and the last frame; frames delivered before stay valid.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/openni2/depth_units.h"

namespace romunect::openni2 {

struct OpenNI2SourceOptions {
  std::string uri;  // "" = the first device OpenNI2 finds; an .oni path plays a recording
  // Video mode of both streams. 0 = 640 x 480 at 30 Hz when the device offers it, else the
  // device's current mode. Recordings play in their recorded mode (a different request fails).
  int width = 0, height = 0, fps = 0;
  bool depth = true;  // open the depth stream
  bool ir = true;     // open the IR stream (GRAY16, same size as depth)
  // Read the depth stream in the PS1080's raw shift format (ONI_PIXEL_FORMAT_SHIFT_9_2: the
  // chip's 11-bit values, 2047 = none) into Frame::raw instead of metric depth_m, for the
  // calibration's exact depth model. Recordings play in the format they hold.
  bool raw = false;
  // Wire unit of depth; nullopt = 100 um when offered, else 1 mm.
  std::optional<DepthUnit> depth_unit;
  double timeout_s = 2.0;  // longest wait for a frame before the device counts as gone
  int max_frames = 0;      // stop after this many frames; 0 = until the stream ends
  // The camera of the frames; nullopt = a pinhole from the device's fields of view.
  std::optional<CameraModel> camera;
  // Also record the streams, lossless, to this .oni file through OpenNI2's recorder.
  std::filesystem::path record_oni;

  // Why the options are unusable ("field = value: rule"), or "" when they are valid.
  std::string Problem() const;
};

// The PS1080 chip's hard-coded geometry as the device reports it (SI units); absent when the
// device does not answer (calibration needs these to undo the chip's depth formula).
struct PS1080Properties {
  std::optional<double> zero_plane_distance_m;        // ZPD: reference-pattern distance
  std::optional<double> zero_plane_pixel_size_m;      // ZPPS: pixel size at the zero plane
  std::optional<double> emitter_camera_distance_m;    // LDDIS: projector-camera baseline
  std::optional<double> depth_rgb_camera_distance_m;  // DCRCDIS
  std::optional<long long> const_shift, param_coeff, shift_scale, max_shift, pixel_size_factor;
  std::string Describe() const;
};

struct OpenNI2SourceStats {
  int frames = 0;          // frames delivered (kOk)
  int dropped_frames = 0;  // gaps in the device's frame numbers
  int unpaired_ir = 0;     // IR frames without a depth frame of the same number, and vice versa
};

class OpenNI2Source : public FrameSource {
 public:
  // Opens and starts the device. Throws InputError on invalid options, an unknown URI, an
  // unreadable recording, or a video mode the device does not offer (the message lists them).
  explicit OpenNI2Source(const OpenNI2SourceOptions& options);
  ~OpenNI2Source() override;
  OpenNI2Source(const OpenNI2Source&) = delete;
  OpenNI2Source& operator=(const OpenNI2Source&) = delete;

  const CameraModel& camera() const override;
  std::string Describe() const override;
  // kEndOfStream at a recording's end, after max_frames, or when a finite (virtual) device has
  // sent all it announced. Throws InputError when the stream stalls past the timeout.
  FrameStatus Next(Frame* frame, std::string* error) override;

  const PS1080Properties& chip() const;
  DepthUnit depth_unit() const;
  bool is_recording_playback() const;  // an .oni file rather than a live device
  const OpenNI2SourceStats& stats() const;
  // Stops the recorder (if any) and waits until the .oni file is complete. Idempotent; the
  // destructor calls it too.
  void FinishRecording();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

struct DeviceListing {
  std::string uri, vendor, name;
};
// The devices OpenNI2 finds now (real ones, and the virtual device named by
// ROMUNECT_VIRTUAL_DEVICE). Throws InputError if OpenNI2 cannot start.
std::vector<DeviceListing> ListDevices();

// "depth 640x480 @30 Hz 100um" lines for every mode the device at `uri` offers.
std::vector<std::string> ListVideoModes(const std::string& uri);

// The folder this build's libOpenNI2 loads drivers from (empty if unknown).
std::filesystem::path DriverDirectory();

}  // namespace romunect::openni2
