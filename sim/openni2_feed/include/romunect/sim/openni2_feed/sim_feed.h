// The live twin as an OpenNI2 device: a frame feed (romunect/sensor/openni2/feed_abi.h) over the
// simulator's Scanner, so the virtual device's driver plug-in presents simulated frames live as
// they are rendered (URI romunect-sim:?key=value&...; docs/hardware.md). This folder sits above
// sim/ and sensor/openni2/: the driver loads libRomunectSimFeed.so with dlopen and sees only
// the C ABI, so sensor/openni2 never depends on the simulator.
//
// Query keys (all optional):
//   seed=N         pile and imaging seed (default 1)
//   objects=N      objects in the pile (default 10)
//   rig=NAME       romunect | kinect-v1 (default romunect)
//   scale=K        image size divided by K = 1, 2 or 4, same field of view (default 1)
//   depth=sensor   IR synthesis + depth engine + the rig's ground-truth correction (default);
//   depth=ideal    ground-truth depth, no IR (fast)
//   frames=N       stop after N frames (default 0: the whole approach)
//   threads=N      renderer and imaging threads (default 2)
//   color=1|0      also render the stock colour camera (StockColorCamera, scaled as the images),
//                  as a PS1080's colour stream (default 1)
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "romunect/sensor/frame.h"
#include "romunect/sim/scanner.h"

namespace romunect::sim_feed {

struct SimFeedOptions {
  uint64_t seed = 1;
  int objects = 10;
  std::string rig = "romunect";
  int scale = 1;
  bool ideal_depth = false;
  int frames = 0;
  int threads = 2;
  bool color = true;

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
  // Reads a query; throws InputError("sim feed", key, problem) for unknown keys or bad values.
  static SimFeedOptions Parse(const std::string& query);
};

// The Scanner's options for a feed (what the feed renders, for tests to reproduce).
sim::ScanOptions ScanOptionsFor(const SimFeedOptions& options);

// The feed: a Scanner (with the sensor imager unless ideal_depth) and a frame cap.
class SimFeed {
 public:
  explicit SimFeed(const SimFeedOptions& options);  // throws InputError like Scanner
  const CameraModel& camera() const { return scanner_->camera(); }
  double fps() const { return rig_fps_; }
  int frame_count() const;  // frames it will deliver
  bool has_ir() const { return !options_.ideal_depth; }
  const std::optional<ColorCamera>& color_camera() const { return scanner_->options().color_camera; }
  // The next frame; false at the end. Throws InputError where the Scanner does.
  bool Next(Frame* frame);

 private:
  SimFeedOptions options_;
  std::unique_ptr<sim::Scanner> scanner_;
  double rig_fps_ = 30.0;
  int delivered_ = 0;
};

}  // namespace romunect::sim_feed
