// A feed library (romunect/sensor/openni2/feed_abi.h, e.g. the live simulator's libRomunectSimFeed.so)
// as a FrameSource: the driver plug-in dlopens it and presents its frames as a device.
#pragma once

#include <optional>
#include <string>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/openni2/feed_abi.h"

namespace romunect::openni2 {

class FeedLibrarySource : public FrameSource {
 public:
  // Loads `library` (empty: the simulator's, libRomunectSimFeed.so beside the backend, two
  // folders above the driver folder) and creates its feed from `query`. Throws std::runtime_error naming the library
  // when it does not load, lacks the ABI's functions, refuses the query or announces an unusable feed.
  FeedLibrarySource(const std::string& library, const std::string& query);
  ~FeedLibrarySource() override;
  FeedLibrarySource(const FeedLibrarySource&) = delete;
  FeedLibrarySource& operator=(const FeedLibrarySource&) = delete;

  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override;
  // Frames hold depth_m and/or ir (copied: the feed's buffers live only until its next call),
  // time_s as the feed gives it, index counting the feed's frames from 0 (a failed one too).
  FrameStatus Next(Frame* frame, std::string* error) override;

  const RomunectFeedInfo& info() const { return info_; }
  // The feed's colour camera (ABI version 2), when its frames carry colour images.
  const std::optional<ColorCamera>& color_camera() const { return color_camera_; }

 private:
  void LoadLibrary(const std::string& path);
  void CreateFeed(const std::string& query);

  std::string path_;
  void* handle_ = nullptr;
  RomunectFeedCreateFn create_ = nullptr;
  RomunectFeedNextFn next_ = nullptr;
  RomunectFeedDestroyFn destroy_ = nullptr;
  void* feed_ = nullptr;
  RomunectFeedInfo info_{};
  CameraModel camera_;
  std::optional<ColorCamera> color_camera_;
  int produced_ = 0;  // Next calls that produced a frame or a failure
  bool ended_ = false;
};

}  // namespace romunect::openni2
