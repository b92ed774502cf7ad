// libRomunectSimFeed.so's C ABI (romunect/sensor/openni2/feed_abi.h) over SimFeed. No exception
// crosses it: each becomes a message in the caller's buffer.
#include <algorithm>
#include <array>
#include <cstdio>
#include <exception>
#include <memory>
#include <optional>

#include "romunect/sensor/openni2/feed_abi.h"
#include "romunect/sim/openni2_feed/sim_feed.h"

namespace {

struct Feed {
  std::unique_ptr<romunect::sim_feed::SimFeed> sim;
  romunect::Frame frame;  // the buffers handed out until the next call
};

void Say(const char* what, char* error, int error_size) {
  if (error != nullptr && error_size > 0) std::snprintf(error, static_cast<size_t>(error_size), "%s", what);
}

}  // namespace

extern "C" {

__attribute__((visibility("default"))) void* romunect_feed_create(const char* query, RomunectFeedInfo* info,
                                                                  char* error, int error_size) {
  try {
    auto feed = std::make_unique<Feed>();
    feed->sim = std::make_unique<romunect::sim_feed::SimFeed>(
        romunect::sim_feed::SimFeedOptions::Parse(query != nullptr ? query : ""));
    const romunect::CameraModel& c = feed->sim->camera();
    *info = RomunectFeedInfo{};
    info->abi_version = ROMUNECT_FEED_ABI_VERSION;
    info->width = c.width;
    info->height = c.height;
    info->fx = c.fx;
    info->fy = c.fy;
    info->cx = c.cx;
    info->cy = c.cy;
    info->fps = feed->sim->fps();
    info->frame_count = feed->sim->frame_count();
    info->has_depth = 1;
    info->has_ir = feed->sim->has_ir() ? 1 : 0;
    if (const std::optional<romunect::ColorCamera>& rgb = feed->sim->color_camera()) {
      info->has_color = 1;
      info->color_width = rgb->camera.width;
      info->color_height = rgb->camera.height;
      info->color_fx = rgb->camera.fx;
      info->color_fy = rgb->camera.fy;
      info->color_cx = rgb->camera.cx;
      info->color_cy = rgb->camera.cy;
      const std::array<double, 16> T = romunect::PoseToRowMajor(rgb->T_C_RGB);
      std::copy(T.begin(), T.end(), info->T_C_RGB);
    }
    return feed.release();
  } catch (const std::exception& e) {
    Say(e.what(), error, error_size);
    return nullptr;
  }
}

__attribute__((visibility("default"))) int romunect_feed_next(void* handle, RomunectFeedFrame* frame, char* error,
                                                              int error_size) {
  auto* feed = static_cast<Feed*>(handle);
  try {
    if (!feed->sim->Next(&feed->frame)) return 0;
  } catch (const std::exception& e) {
    Say(e.what(), error, error_size);
    return -1;
  }
  *frame = RomunectFeedFrame{};
  // Continuous CV_32F / CV_16U Mats of the camera's size (the Scanner's frames).
  frame->depth_m = feed->frame.depth_m.empty() ? nullptr : feed->frame.depth_m.ptr<float>();
  frame->ir = feed->frame.ir.empty() ? nullptr : feed->frame.ir.ptr<uint16_t>();
  frame->time_s = feed->frame.time_s;
  frame->color_rgb = feed->frame.color.empty() ? nullptr : feed->frame.color.ptr<uint8_t>();
  return 1;
}

__attribute__((visibility("default"))) void romunect_feed_destroy(void* handle) { delete static_cast<Feed*>(handle); }

}  // extern "C"
