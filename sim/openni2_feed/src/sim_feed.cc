#include "romunect/sim/openni2_feed/sim_feed.h"

#include <algorithm>
#include <cstdlib>
#include <sstream>

#include "romunect/sensor/errors.h"
#include "romunect/sim/sensor_imager.h"

namespace romunect::sim_feed {
namespace {

// A camera at 1/k of its resolution with the same field of view (pixel centres at integers).
void Downscale(CameraModel* c, int k) {
  c->width /= k;
  c->height /= k;
  c->fx /= k;
  c->fy /= k;
  c->cx = (c->cx + 0.5) / k - 0.5;
  c->cy = (c->cy + 0.5) / k - 0.5;
}

long long ParseInteger(const std::string& key, const std::string& value) {
  char* end = nullptr;
  const long long n = std::strtoll(value.c_str(), &end, 10);
  if (value.empty() || *end != '\0') throw InputError("sim feed", key, "'" + value + "' is not an integer");
  return n;
}

}  // namespace

std::string SimFeedOptions::Problem() const {
  auto bad = [](const std::string& field, const std::string& value, const std::string& rule) {
    return field + " = " + value + ": " + rule;
  };
  if (objects < 0 || objects > 200) return bad("objects", std::to_string(objects), "must be in [0, 200]");
  if (scale != 1 && scale != 2 && scale != 4) return bad("scale", std::to_string(scale), "must be 1, 2 or 4");
  if (frames < 0) return bad("frames", std::to_string(frames), "must be >= 0 (0 = the whole approach)");
  if (threads < 1 || threads > 64) return bad("threads", std::to_string(threads), "must be in [1, 64]");
  if (rig != "romunect" && rig != "kinect-v1") return bad("rig", rig, "must be romunect or kinect-v1");
  return "";
}

SimFeedOptions SimFeedOptions::Parse(const std::string& query) {
  SimFeedOptions o;
  std::stringstream items(query);
  std::string item;
  while (std::getline(items, item, '&')) {
    if (item.empty()) continue;
    const size_t eq = item.find('=');
    const std::string key = item.substr(0, eq);
    const std::string value = eq == std::string::npos ? "" : item.substr(eq + 1);
    if (key == "seed") {
      o.seed = static_cast<uint64_t>(ParseInteger(key, value));
    } else if (key == "objects") {
      o.objects = static_cast<int>(ParseInteger(key, value));
    } else if (key == "rig") {
      o.rig = value;
    } else if (key == "scale") {
      o.scale = static_cast<int>(ParseInteger(key, value));
    } else if (key == "depth" && (value == "sensor" || value == "ideal")) {
      o.ideal_depth = value == "ideal";
    } else if (key == "frames") {
      o.frames = static_cast<int>(ParseInteger(key, value));
    } else if (key == "threads") {
      o.threads = static_cast<int>(ParseInteger(key, value));
    } else if (key == "color" && (value == "1" || value == "0")) {
      o.color = value == "1";
    } else {
      throw InputError("sim feed", key,
                       "unknown or malformed key '" + item +
                           "' (expected seed, objects, rig, scale, depth=sensor|ideal, frames, threads, color=1|0)");
    }
  }
  if (const std::string p = o.Problem(); !p.empty()) throw InputError("sim feed", "", p);
  return o;
}

sim::ScanOptions ScanOptionsFor(const SimFeedOptions& options) {
  sim::ScanOptions scan;
  scan.rig = RigPreset(options.rig);
  Downscale(&scan.rig.camera, options.scale);
  Downscale(&scan.rig.depth_engine.chip.camera, options.scale);
  scan.pile.num_objects = options.objects;
  scan.pile.seed = static_cast<uint32_t>(options.seed);
  scan.seed = options.seed;
  scan.threads = options.threads;
  if (options.color) {
    ColorCamera rgb = StockColorCamera();
    rgb.camera = ScaledCamera(rgb.camera, rgb.camera.width / options.scale, rgb.camera.height / options.scale);
    scan.color_camera = rgb;
  }
  return scan;
}

SimFeed::SimFeed(const SimFeedOptions& options) : options_(options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError("sim feed", "", p);
  const sim::ScanOptions scan = ScanOptionsFor(options);
  rig_fps_ = scan.rig.frame_rate_hz;
  scanner_ = std::make_unique<sim::Scanner>(scan);
  if (!options.ideal_depth) {
    sim::SensorImagerOptions imager;
    imager.threads = std::max(1, options.threads - 1);  // on its own thread beside rendering, as in scan
    scanner_->SetImager(std::make_unique<sim::SensorImager>(scan.rig, imager));
  }
}

int SimFeed::frame_count() const {
  const int n = scanner_->frame_count();
  return options_.frames > 0 ? std::min(n, options_.frames) : n;
}

bool SimFeed::Next(Frame* frame) {
  if (delivered_ >= frame_count()) return false;
  std::string error;
  const FrameStatus status = scanner_->Next(frame, &error);
  if (status == FrameStatus::kEndOfStream) return false;
  if (status == FrameStatus::kBadFrame) throw InputError("sim feed", "frame " + std::to_string(delivered_), error);
  ++delivered_;
  return true;
}

}  // namespace romunect::sim_feed
