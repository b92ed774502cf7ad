#include "romunect/sensor/frame_io.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <set>
#include <sstream>
#include <utility>

#include "json_fields.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect {
namespace fs = std::filesystem;
using json_fields::Field;
using nlohmann::json;

namespace {

constexpr const char* kManifestName = "frames.json";

std::optional<Pose> ReadPose(const Field& entry, const std::string& key) {
  if (!entry.Has(key)) return std::nullopt;
  const Field field = entry[key];
  const std::array<double, 16> numbers = field.Numbers<16>();
  Eigen::Matrix4d m;
  for (int i = 0; i < 16; ++i) m(i / 4, i % 4) = numbers[i];
  if (const std::string problem = RigidityProblem(m); !problem.empty()) {
    field.Fail("not a rigid transform (row-major 4x4 expected): " + problem);
  }
  return PoseFromRowMajor(numbers);
}

std::optional<WorldBox> ReadRegion(const Field& root, const std::string& key) {
  if (!root.Has(key)) return std::nullopt;
  const Field field = root[key];
  const std::array<double, 6> v = field.Numbers<6>();
  const WorldBox box{{v[0], v[1], v[2]}, {v[3], v[4], v[5]}};
  if (const std::string problem = box.Problem(); !problem.empty()) {
    field.Fail(problem + " (expected [xmin, ymin, zmin, xmax, ymax, zmax] in metres)");
  }
  return box;
}

CameraModel ReadCamera(const Field& cam) {
  CameraModel camera;
  camera.width = cam["width"].Int();
  camera.height = cam["height"].Int();
  camera.fx = cam["fx"].Number();
  camera.fy = cam["fy"].Number();
  camera.cx = cam["cx"].Number();
  camera.cy = cam["cy"].Number();
  camera.distortion = cam["distortion"].Numbers<5>();
  if (const std::string problem = camera.Problem(); !problem.empty()) cam.Fail(problem);
  return camera;
}

std::optional<ColorCamera> ReadColorCamera(const Field& root, const std::string& key) {
  if (!root.Has(key)) return std::nullopt;
  const Field field = root[key];
  if (!field.value().is_object()) field.Fail("expected an object: the camera's keys and T_C_RGB");
  ColorCamera color;
  color.camera = ReadCamera(field);
  if (!field.Has("T_C_RGB")) field["T_C_RGB"];  // throws "missing (required)"
  color.T_C_RGB = *ReadPose(field, "T_C_RGB");
  return color;
}

json CameraJson(const CameraModel& c) {
  return {{"width", c.width}, {"height", c.height},        {"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx},
          {"cy", c.cy},       {"distortion", c.distortion}};
}

std::string ReadImagePath(const Field& entry, const std::string& key) {
  if (!entry.Has(key)) return "";
  const Field field = entry[key];
  const std::string path = field.String();
  if (path.empty()) field.Fail("expected a relative file path, found an empty string");
  const fs::path p(path);
  if (p.is_absolute()) field.Fail("expected a path relative to the frame directory, found " + path);
  for (const auto& part : p) {
    if (part == "..") field.Fail("must stay inside the frame directory (no '..'): " + path);
  }
  return path;
}

// Unknown keys of a JSON object, as the text of an object.
std::string ExtraKeys(const json& object, const std::set<std::string>& known) {
  json extra = json::object();
  for (const auto& [key, value] : object.items()) {
    if (!known.count(key)) extra[key] = value;
  }
  return extra.dump();
}

json Row(const Pose& T) {
  const auto numbers = PoseToRowMajor(T);
  return json(std::vector<double>(numbers.begin(), numbers.end()));
}

std::string Describe(const cv::Mat& m) {
  std::ostringstream s;
  s << m.cols << " x " << m.rows << " " << cv::typeToString(m.type());
  return s.str();
}

void CheckImage(const cv::Mat& image, const CameraModel& camera, int type, const fs::path& path) {
  if (image.cols != camera.width || image.rows != camera.height) {
    std::ostringstream s;
    s << "expected " << camera.width << " x " << camera.height << " (the camera in frames.json), found " << image.cols
      << " x " << image.rows;
    throw InputError(path.string(), "image size", s.str());
  }
  if (image.type() != type) {
    throw InputError(path.string(), "pixel type",
                     "expected " + cv::typeToString(type) + ", found " + cv::typeToString(image.type()));
  }
}

// Depth must be finite and non-negative (0 = no measurement).
void CheckDepthValues(cv::Mat* depth, const fs::path& path, InvalidDepthPolicy policy, size_t* skipped) {
  for (int v = 0; v < depth->rows; ++v) {
    float* row = depth->ptr<float>(v);
    for (int u = 0; u < depth->cols; ++u) {
      const float d = row[u];
      if (std::isfinite(d) && d >= 0.0f) continue;
      if (policy == InvalidDepthPolicy::kReject) {
        std::ostringstream s;
        s << "pixel (u=" << u << ", v=" << v << ") is " << d
          << "; expected a finite depth >= 0 in metres (0 = no measurement)";
        throw InputError(path.string(), "depth", s.str());
      }
      row[u] = 0.0f;
      if (skipped != nullptr) ++*skipped;
    }
  }
}

// Raw depth is the chip's 11-bit value (2047 = none, depth_engine.h). Larger values are another
// encoding (drivers that shift it left, say by 5 bits to fill 16): refused, not read as depths
// that then fuse nothing.
void CheckRawIs11Bits(const cv::Mat& raw, const std::filesystem::path& path) {
  double hi = 0.0;
  cv::Point at;
  cv::minMaxLoc(raw, nullptr, &hi, nullptr, &at);
  if (hi <= 2047) return;
  std::ostringstream s;
  s << "raw depth is 11 bits (0..2046, 2047 = no measurement), found " << hi << " at pixel (" << at.x << ", "
    << at.y << ")";
  const int bits = static_cast<int>(std::ceil(std::log2(hi + 1.0)));
  if (bits > 11) s << "; the values fill " << bits << " bits: scaled (by 2^" << bits - 11 << "?) raw must be divided back";
  throw InputError(path.string(), "raw", s.str());
}

}  // namespace

std::string FrameFile(const char* folder, int index, const char* extension) {
  char name[64];
  std::snprintf(name, sizeof(name), "%s/%06d.%s", folder, index, extension);
  return name;
}

FrameDirectoryManifest ReadFrameDirectoryManifest(const fs::path& dir) {
  const fs::path path = dir / kManifestName;
  if (!fs::is_directory(dir)) throw InputError(dir.string(), "", "not a directory");
  if (!fs::exists(path)) {
    throw InputError(path.string(), "", "file not found (a frame directory holds frames.json)");
  }
  const json document = json_fields::ParseFile(path);
  const Field root(document, path.string(), "");
  if (!document.is_object()) root.Fail("expected a JSON object at the top level");

  const std::string format = root["format"].String();
  if (format != kFrameDirectoryFormat) {
    root["format"].Fail("expected \"" + std::string(kFrameDirectoryFormat) + "\", found \"" + format + "\"");
  }
  const int version = root["version"].Int();
  if (version != kFrameDirectoryVersion) {
    root["version"].Fail("unknown format version " + std::to_string(version) + "; this build reads version " +
                         std::to_string(kFrameDirectoryVersion));
  }

  FrameDirectoryManifest manifest;
  manifest.camera = ReadCamera(root["camera"]);
  manifest.region_W = ReadRegion(root, "region_W");
  manifest.color_camera = ReadColorCamera(root, "color_camera");
  manifest.extra_json = ExtraKeys(document, {"format", "version", "camera", "frames", "region_W", "color_camera"});

  const Field frames = root["frames"];
  std::set<int> indices;
  for (size_t i = 0; i < frames.ArraySize(); ++i) {
    const Field entry = frames[i];
    if (!entry.value().is_object()) entry.Fail("expected an object per frame");
    FrameRecord record;
    record.index = entry["index"].Int();
    if (record.index < 0) entry["index"].Fail("expected an index >= 0");
    if (!indices.insert(record.index).second) {
      entry["index"].Fail("index " + std::to_string(record.index) + " appears twice");
    }
    record.time_s = entry["time_s"].Number();
    if (!manifest.frames.empty() && record.time_s < manifest.frames.back().time_s) {
      entry["time_s"].Fail("times must not decrease from frame to frame");
    }
    record.depth = ReadImagePath(entry, "depth");
    record.ir = ReadImagePath(entry, "ir");
    record.raw = ReadImagePath(entry, "raw");
    record.gt_depth = ReadImagePath(entry, "gt_depth");
    record.color = ReadImagePath(entry, "color");
    if (!record.color.empty() && !manifest.color_camera) {
      entry["color"].Fail("a colour image needs the top-level \"color_camera\" (its size, pinhole and T_C_RGB)");
    }
    if (record.depth.empty() && record.raw.empty()) {
      entry["depth"];  // throws "missing (required)" naming the field
    }
    record.T_W_C = ReadPose(entry, "T_W_C");
    record.T_B_H = ReadPose(entry, "T_B_H");
    record.extra_json = ExtraKeys(entry.value(),
                                  {"index", "time_s", "depth", "ir", "raw", "gt_depth", "color", "T_W_C", "T_B_H"});
    manifest.frames.push_back(std::move(record));
  }
  return manifest;
}

namespace {

// The image's path, refused when a symbolic link on the way leads out of the frame directory.
fs::path ImageInside(const fs::path& dir, const std::string& relative) {
  const fs::path path = dir / relative;
  std::error_code ec;
  const fs::path root = fs::weakly_canonical(dir, ec);
  const fs::path target = ec ? fs::path() : fs::weakly_canonical(path, ec);
  if (ec) throw InputError(path.string(), "", "cannot be resolved: " + ec.message());
  const auto [end, ignored] = std::mismatch(root.begin(), root.end(), target.begin(), target.end());
  if (end != root.end()) {
    throw InputError(path.string(), "",
                     "leads out of the frame directory through a symbolic link (to " + target.string() +
                         "); images must lie inside it");
  }
  return path;
}

}  // namespace

Frame LoadFrame(const fs::path& dir, const FrameDirectoryManifest& manifest, size_t i, InvalidDepthPolicy policy,
                size_t* skipped_pixels) {
  ROMUNECT_CHECK(i < manifest.frames.size());
  const FrameRecord& record = manifest.frames[i];
  Frame frame;
  frame.index = record.index;
  frame.time_s = record.time_s;
  frame.T_W_C = record.T_W_C;
  frame.T_B_H = record.T_B_H;
  const cv::Size size(manifest.camera.width, manifest.camera.height);  // refused from the header, before decoding
  if (!record.depth.empty()) {
    frame.depth_m = ReadDepthExr(ImageInside(dir, record.depth), size);
    CheckImage(frame.depth_m, manifest.camera, CV_32F, dir / record.depth);
    CheckDepthValues(&frame.depth_m, dir / record.depth, policy, skipped_pixels);
  }
  if (!record.gt_depth.empty()) {
    frame.gt_depth_m = ReadDepthExr(ImageInside(dir, record.gt_depth), size);
    CheckImage(frame.gt_depth_m, manifest.camera, CV_32F, dir / record.gt_depth);
    CheckDepthValues(&frame.gt_depth_m, dir / record.gt_depth, policy, skipped_pixels);
  }
  if (!record.ir.empty()) {
    frame.ir = ReadPng16(ImageInside(dir, record.ir), size);
    CheckImage(frame.ir, manifest.camera, CV_16U, dir / record.ir);
  }
  if (!record.raw.empty()) {
    frame.raw = ReadPng16(ImageInside(dir, record.raw), size);
    CheckImage(frame.raw, manifest.camera, CV_16U, dir / record.raw);
    CheckRawIs11Bits(frame.raw, dir / record.raw);
  }
  if (!record.color.empty()) {
    const CameraModel& color_camera = manifest.color_camera->camera;
    frame.color = ReadPngRgb8(ImageInside(dir, record.color), cv::Size(color_camera.width, color_camera.height));
    CheckImage(frame.color, color_camera, CV_8UC3, dir / record.color);
  }
  return frame;
}

void WriteFrameDirectoryManifest(const fs::path& dir, const FrameDirectoryManifest& manifest) {
  json document = json::parse(manifest.extra_json);
  document["format"] = kFrameDirectoryFormat;
  document["version"] = kFrameDirectoryVersion;
  document["camera"] = CameraJson(manifest.camera);
  if (const std::optional<ColorCamera>& color = manifest.color_camera) {
    json camera = CameraJson(color->camera);
    camera["T_C_RGB"] = Row(color->T_C_RGB);
    document["color_camera"] = std::move(camera);
  }
  if (const std::optional<WorldBox>& r = manifest.region_W) {
    document["region_W"] = {r->min_W.x(), r->min_W.y(), r->min_W.z(), r->max_W.x(), r->max_W.y(), r->max_W.z()};
  }
  json frames = json::array();
  for (const FrameRecord& r : manifest.frames) {
    json entry = json::parse(r.extra_json);
    entry["index"] = r.index;
    entry["time_s"] = r.time_s;
    if (!r.depth.empty()) entry["depth"] = r.depth;
    if (!r.ir.empty()) entry["ir"] = r.ir;
    if (!r.raw.empty()) entry["raw"] = r.raw;
    if (!r.gt_depth.empty()) entry["gt_depth"] = r.gt_depth;
    if (!r.color.empty()) entry["color"] = r.color;
    if (r.T_W_C) entry["T_W_C"] = Row(*r.T_W_C);
    if (r.T_B_H) entry["T_B_H"] = Row(*r.T_B_H);
    frames.push_back(std::move(entry));
  }
  document["frames"] = std::move(frames);
  WriteTextAtomically(dir / kManifestName, document.dump(1) + "\n");
}

void FrameDirectoryWriter::CheckCanWrite(const fs::path& dir) {
  if (fs::exists(dir / kManifestName)) {
    throw InputError((dir / kManifestName).string(), "",
                     "already exists; refusing to overwrite an earlier frame directory");
  }
}

FrameDirectoryWriter::FrameDirectoryWriter(const fs::path& dir, const CameraModel& camera, ImageCompression compression)
    : dir_(dir), compression_(compression) {
  ROMUNECT_CHECK(camera.Problem().empty());
  CheckCanWrite(dir);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw InputError(dir.string(), "", "cannot create directory: " + ec.message());
  manifest_.camera = camera;
}

void FrameDirectoryWriter::SetExtraJson(const std::string& extra_json) { manifest_.extra_json = extra_json; }

void FrameDirectoryWriter::SetRegion(const WorldBox& region_W) {
  ROMUNECT_CHECK_MSG(region_W.Problem().empty(), region_W.Problem().c_str());
  manifest_.region_W = region_W;
}

void FrameDirectoryWriter::SetColorCamera(const ColorCamera& color_camera) {
  ROMUNECT_CHECK_MSG(color_camera.Problem().empty(), color_camera.Problem().c_str());
  manifest_.color_camera = color_camera;
}

namespace {
// A frame's manifest entry without its image files.
FrameRecord RecordOf(const Frame& frame, const std::string& extra_json) {
  FrameRecord record;
  record.index = frame.index;
  record.time_s = frame.time_s;
  record.T_W_C = frame.T_W_C;
  record.T_B_H = frame.T_B_H;
  record.extra_json = extra_json;
  return record;
}
}  // namespace

void FrameDirectoryWriter::Add(const Frame& frame, const std::string& extra_json) {
  ROMUNECT_CHECK(!finished_);
  const CameraModel& c = manifest_.camera;
  auto check = [&](const cv::Mat& m, int type) {
    ROMUNECT_CHECK_MSG(m.empty() || (m.cols == c.width && m.rows == c.height && m.type() == type), Describe(m).c_str());
  };
  check(frame.ir, CV_16U);
  check(frame.raw, CV_16U);
  check(frame.depth_m, CV_32F);
  check(frame.gt_depth_m, CV_32F);
  ROMUNECT_CHECK(!frame.depth_m.empty() || !frame.raw.empty());
  if (!frame.color.empty()) {
    ROMUNECT_CHECK_MSG(manifest_.color_camera.has_value(), "a colour image needs SetColorCamera first");
    const CameraModel& cc = manifest_.color_camera->camera;
    ROMUNECT_CHECK_MSG(frame.color.cols == cc.width && frame.color.rows == cc.height && frame.color.type() == CV_8UC3,
                       Describe(frame.color).c_str());
  }

  FrameRecord record = RecordOf(frame, extra_json);
  auto write = [&](const cv::Mat& image, const char* folder, const char* extension, std::string* field) {
    if (image.empty()) return;
    *field = FrameFile(folder, frame.index, extension);
    fs::create_directories(dir_ / folder);
    if (image.type() == CV_32F) {
      WriteDepthExr(dir_ / *field, image, compression_);
    } else {
      WritePng16(dir_ / *field, image, compression_);
    }
  };
  write(frame.depth_m, "depth", "exr", &record.depth);
  write(frame.ir, "ir", "png", &record.ir);
  write(frame.raw, "raw", "png", &record.raw);
  write(frame.gt_depth_m, "gt_depth", "exr", &record.gt_depth);
  if (!frame.color.empty()) {
    record.color = FrameFile("color", frame.index, "png");
    fs::create_directories(dir_ / "color");
    WritePngRgb8(dir_ / record.color, frame.color);
  }
  manifest_.frames.push_back(std::move(record));
}

bool FrameDirectoryWriter::AddIfWritten(const Frame& frame, const std::string& extra_json) {
  ROMUNECT_CHECK(!finished_);
  const cv::Size size(manifest_.camera.width, manifest_.camera.height);
  // Written images read back bit-exactly (EXR holds the float depth, PNG the 16-bit values).
  auto same = [&](const cv::Mat& image, const char* folder, const char* extension) {
    if (image.empty()) return true;
    const fs::path path = dir_ / FrameFile(folder, frame.index, extension);
    if (std::error_code ec; !fs::is_regular_file(path, ec)) return false;
    try {
      const cv::Mat read = image.type() == CV_32F   ? ReadDepthExr(path, size)
                           : image.type() == CV_16U ? ReadPng16(path, size)
                                                    : ReadPngRgb8(path, image.size());
      return read.size() == image.size() && read.type() == image.type() &&
             std::memcmp(read.data, image.data, image.total() * image.elemSize()) == 0;  // both continuous
    } catch (const InputError&) {
      return false;
    }
  };
  const cv::Mat images[] = {frame.depth_m.isContinuous() ? frame.depth_m : frame.depth_m.clone(),
                            frame.ir.isContinuous() ? frame.ir : frame.ir.clone(),
                            frame.raw.isContinuous() ? frame.raw : frame.raw.clone(),
                            frame.gt_depth_m.isContinuous() ? frame.gt_depth_m : frame.gt_depth_m.clone(),
                            frame.color.isContinuous() ? frame.color : frame.color.clone()};
  if (!same(images[0], "depth", "exr") || !same(images[1], "ir", "png") || !same(images[2], "raw", "png") ||
      !same(images[3], "gt_depth", "exr") || !same(images[4], "color", "png")) {
    return false;
  }
  FrameRecord record = RecordOf(frame, extra_json);
  if (!frame.depth_m.empty()) record.depth = FrameFile("depth", frame.index, "exr");
  if (!frame.ir.empty()) record.ir = FrameFile("ir", frame.index, "png");
  if (!frame.raw.empty()) record.raw = FrameFile("raw", frame.index, "png");
  if (!frame.gt_depth_m.empty()) record.gt_depth = FrameFile("gt_depth", frame.index, "exr");
  if (!frame.color.empty()) record.color = FrameFile("color", frame.index, "png");
  manifest_.frames.push_back(std::move(record));
  return true;
}

void FrameDirectoryWriter::Finish() {
  ROMUNECT_CHECK(!finished_);
  WriteFrameDirectoryManifest(dir_, manifest_);
  finished_ = true;
}

FrameDirectorySource::FrameDirectorySource(const fs::path& dir, InvalidDepthPolicy policy)
    : dir_(dir), manifest_(ReadFrameDirectoryManifest(dir)), policy_(policy) {}

FrameDirectorySource::FrameDirectorySource(const fs::path& dir, FrameDirectoryManifest manifest,
                                           InvalidDepthPolicy policy)
    : dir_(dir), manifest_(std::move(manifest)), policy_(policy) {}

std::string FrameDirectorySource::Describe() const {
  return "frame directory " + dir_.string() + ", " + std::to_string(manifest_.frames.size()) + " frames";
}

FrameStatus FrameDirectorySource::Next(Frame* frame, std::string* error) {
  ROMUNECT_CHECK(frame != nullptr && error != nullptr);
  if (next_ >= manifest_.frames.size()) return FrameStatus::kEndOfStream;
  const size_t i = next_++;
  try {
    *frame = LoadFrame(dir_, manifest_, i, policy_, &skipped_pixels_);
  } catch (const InputError& e) {
    *error = e.what();
    return FrameStatus::kBadFrame;
  }
  return FrameStatus::kOk;
}

}  // namespace romunect
