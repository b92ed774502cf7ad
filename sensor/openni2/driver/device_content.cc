#include "device_content.h"

#include <algorithm>
#include <utility>
#include <vector>

#include "feed_library_source.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/looping_source.h"

namespace romunect::openni2 {
namespace {

// The rate of the median frame interval; 0 without one.
double MedianFps(const std::vector<FrameRecord>& frames) {
  if (frames.size() < 2) return 0.0;
  std::vector<double> dt;
  for (size_t i = 1; i < frames.size(); ++i) dt.push_back(frames[i].time_s - frames[i - 1].time_s);
  std::nth_element(dt.begin(), dt.begin() + dt.size() / 2, dt.end());
  return dt[dt.size() / 2] > 0.0 ? 1.0 / dt[dt.size() / 2] : 0.0;
}

template <typename Field>
bool EveryFrameHas(const std::vector<FrameRecord>& frames, Field field) {
  return std::all_of(frames.begin(), frames.end(), [field](const FrameRecord& r) { return !(r.*field).empty(); });
}

DeviceContent OpenFrameDirectory(const std::filesystem::path& dir, bool loop) {
  FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir);  // throws InputError
  for (FrameRecord& r : manifest.frames) r.gt_depth.clear();          // no device sends ground truth
  const std::vector<FrameRecord>& frames = manifest.frames;
  // A device without frames would open with no sensor at all and be reported as one lacking a
  // depth sensor.
  if (frames.empty()) {
    throw InputError((dir / "frames.json").string(), "frames", "is empty: a virtual device needs at least one frame");
  }
  DeviceContent content;
  content.has_depth = EveryFrameHas(frames, &FrameRecord::depth);
  content.has_ir = EveryFrameHas(frames, &FrameRecord::ir);
  content.has_raw = EveryFrameHas(frames, &FrameRecord::raw);
  if (EveryFrameHas(frames, &FrameRecord::color)) content.color_camera = manifest.color_camera;
  content.frame_count = loop ? 0 : static_cast<int>(frames.size());
  content.fps = MedianFps(frames);
  content.extra_json = manifest.extra_json;
  content.time_origin_s = frames.front().time_s;
  if (!loop) {
    content.source = std::make_unique<FrameDirectorySource>(dir, std::move(manifest));
    return content;
  }
  // Each pass replays the manifest read here; a pass starts one frame interval after the last.
  const double gap_s = 1.0 / (content.fps > 0.0 ? content.fps : 30.0);
  content.source = std::make_unique<LoopingSource>(
      [dir, manifest = std::move(manifest)] { return std::make_unique<FrameDirectorySource>(dir, manifest); }, gap_s);
  return content;
}

DeviceContent OpenFeedLibrary(const std::string& library, const std::string& query) {
  auto feed = std::make_unique<FeedLibrarySource>(library, query);
  const RomunectFeedInfo& info = feed->info();
  DeviceContent content;
  content.has_depth = info.has_depth != 0;
  content.has_ir = info.has_ir != 0;
  content.color_camera = feed->color_camera();
  content.frame_count = info.frame_count;
  content.fps = info.fps;
  content.source = std::move(feed);  // times count from the feed's first frame already
  return content;
}

}  // namespace

DeviceContent OpenDeviceContent(const ParsedVirtualDeviceUri& parsed) {
  if (parsed.feed) return OpenFeedLibrary(parsed.feed_library, parsed.feed_query);
  return OpenFrameDirectory(parsed.dir, parsed.options.loop);
}

}  // namespace romunect::openni2
