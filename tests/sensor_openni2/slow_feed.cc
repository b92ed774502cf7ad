// A feed library (feed_abi.h) slower than real time, for the virtual device's frame dropping: a
// plane 1 m away at 64 x 48, announced at 30 Hz, each frame taking delay_ms to produce.
// Query: delay_ms=N&frames=N.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "romunect/sensor/openni2/feed_abi.h"

namespace {

struct SlowFeed {
  int delay_ms = 70;
  int frames = 12;
  int next = 0;
  std::vector<float> depth_m = std::vector<float>(64 * 48, 1.0f);
};

int Value(const std::string& query, const std::string& key, int fallback) {
  const size_t at = query.find(key + "=");
  return at == std::string::npos ? fallback : std::atoi(query.c_str() + at + key.size() + 1);
}

}  // namespace

extern "C" __attribute__((visibility("default"))) void* romunect_feed_create(const char* query, RomunectFeedInfo* info,
                                                                             char* error, int error_size) {
  auto* feed = new SlowFeed;
  feed->delay_ms = Value(query, "delay_ms", feed->delay_ms);
  feed->frames = Value(query, "frames", feed->frames);
  if (feed->delay_ms < 0 || feed->frames <= 0) {
    std::snprintf(error, static_cast<size_t>(error_size), "delay_ms must be >= 0 and frames > 0");
    delete feed;
    return nullptr;
  }
  *info = RomunectFeedInfo{};
  info->abi_version = ROMUNECT_FEED_ABI_VERSION;
  info->width = 64;
  info->height = 48;
  info->fx = info->fy = 58.0;
  info->cx = 31.5;
  info->cy = 23.5;
  info->fps = 30.0;
  info->frame_count = feed->frames;
  info->has_depth = 1;
  return feed;
}

extern "C" __attribute__((visibility("default"))) int romunect_feed_next(void* handle, RomunectFeedFrame* frame,
                                                                         char* /*error*/, int /*error_size*/) {
  auto* feed = static_cast<SlowFeed*>(handle);
  if (feed->next >= feed->frames) return 0;
  std::this_thread::sleep_for(std::chrono::milliseconds(feed->delay_ms));
  frame->depth_m = feed->depth_m.data();
  frame->ir = nullptr;
  frame->time_s = feed->next / 30.0;
  ++feed->next;
  return 1;
}

extern "C" __attribute__((visibility("default"))) void romunect_feed_destroy(void* handle) {
  delete static_cast<SlowFeed*>(handle);
}
