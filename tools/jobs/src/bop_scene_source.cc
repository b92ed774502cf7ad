#include "bop_scene_source.h"

#include <cstdio>
#include <fstream>
#include <map>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/errors.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

json ReadJsonFile(const fs::path& file) {
  std::ifstream in(file);
  if (!in) throw InputError(file.string(), "", "missing");
  json doc = json::parse(in, nullptr, false);
  if (doc.is_discarded() || !doc.is_object()) throw InputError(file.string(), "", "not a JSON object");
  return doc;
}

double Number(const json& j, const std::string& key, const fs::path& file, const std::string& where) {
  if (!j.contains(key) || !j[key].is_number()) throw InputError(file.string(), where + key, "missing or not a number");
  return j[key].get<double>();
}

int ImageSide(const json& j, const std::string& key, const fs::path& file) {
  if (!j.contains(key) || !IsImageSide(j[key])) {
    throw InputError(file.string(), key, "expected a whole number of pixels in [1, 65536]");
  }
  return j[key].get<int>();
}

std::vector<double> Numbers(const json& j, const std::string& key, size_t n, const fs::path& file,
                            const std::string& where) {
  if (!j.contains(key) || !j[key].is_array() || j[key].size() != n) {
    throw InputError(file.string(), where + key, "expected " + std::to_string(n) + " numbers");
  }
  std::vector<double> out;
  for (const auto& x : j[key]) {
    if (!x.is_number()) throw InputError(file.string(), where + key, "expected numbers");
    out.push_back(x.get<double>());
  }
  return out;
}

struct Image {
  int id = 0;
  Pose T_W_C = Pose::Identity();
  double depth_scale_mm = 1.0;
};

class BopSceneSource : public FrameSource {
 public:
  explicit BopSceneSource(const fs::path& dir) : dir_(dir) {
    const fs::path camera_file = dir / ".." / ".." / "camera.json";
    const json cam = ReadJsonFile(camera_file);
    camera_.width = ImageSide(cam, "width", camera_file);
    camera_.height = ImageSide(cam, "height", camera_file);
    camera_.fx = Number(cam, "fx", camera_file, "");
    camera_.fy = Number(cam, "fy", camera_file, "");
    camera_.cx = Number(cam, "cx", camera_file, "");
    camera_.cy = Number(cam, "cy", camera_file, "");
    if (cam.contains("distortion")) {
      const auto d = Numbers(cam, "distortion", 5, camera_file, "");
      for (int i = 0; i < 5; ++i) camera_.distortion[i] = d[i];
    }
    if (const std::string problem = camera_.Problem(); !problem.empty()) {
      throw InputError(camera_file.string(), "", problem);
    }
    const fs::path scene_file = dir / "scene_camera.json";
    std::map<int, Image> images;  // in id order
    const json scene = ReadJsonFile(scene_file);
    for (const auto& [key, entry] : scene.items()) {
      Image image;
      image.id = std::atoi(key.c_str());
      const std::string where = key + ".";
      const auto R = Numbers(entry, "cam_R_w2c", 9, scene_file, where);
      const auto t = Numbers(entry, "cam_t_w2c", 3, scene_file, where);
      Eigen::Matrix4d T_C_W = Eigen::Matrix4d::Identity();
      for (int i = 0; i < 9; ++i) T_C_W(i / 3, i % 3) = R[i];
      for (int i = 0; i < 3; ++i) T_C_W(i, 3) = 1e-3 * t[i];
      if (const std::string problem = RigidityProblem(T_C_W); !problem.empty()) {
        throw InputError(scene_file.string(), where + "cam_R_w2c", problem);
      }
      image.T_W_C = Pose(T_C_W).inverse();
      image.depth_scale_mm = Number(entry, "depth_scale", scene_file, where);
      images[image.id] = image;
    }
    for (const auto& [id, image] : images) images_.push_back(image);
  }

  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override {
    return "BOP scene " + dir_.string() + ", " + std::to_string(images_.size()) + " images";
  }

  FrameStatus Next(Frame* frame, std::string* error) override {
    if (next_ >= images_.size()) return FrameStatus::kEndOfStream;
    const Image& image = images_[next_];
    char name[32];
    std::snprintf(name, sizeof name, "%06d.png", image.id);
    const fs::path file = dir_ / "depth" / name;
    const cv::Mat depth = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
    *frame = Frame();
    frame->index = static_cast<int>(next_++);
    frame->time_s = frame->index / 30.0;
    if (depth.type() != CV_16UC1 || depth.cols != camera_.width || depth.rows != camera_.height) {
      *error = file.string() + ": missing, or not a 16-bit image of the camera's size";
      return FrameStatus::kBadFrame;
    }
    depth.convertTo(frame->depth_m, CV_32F, image.depth_scale_mm * 1e-3);  // 0 stays "no measurement"
    frame->T_W_C = image.T_W_C;
    return FrameStatus::kOk;
  }

 private:
  fs::path dir_;
  CameraModel camera_;
  std::vector<Image> images_;
  size_t next_ = 0;
};

}  // namespace

bool IsImageSide(const json& value) {
  return value.is_number_integer() && value.get<int64_t>() >= 1 && value.get<int64_t>() <= 1 << 16;
}

bool IsBopScene(const fs::path& dir) {
  return fs::is_regular_file(dir / "scene_camera.json") && fs::is_directory(dir / "depth");
}

std::optional<WorldBox> BopSceneRegion(const fs::path& dir) {
  const fs::path file = dir / "scene_info.json";
  if (!fs::exists(file)) return std::nullopt;
  const json info = ReadJsonFile(file);
  if (!info.contains("region_W")) return std::nullopt;
  const json& region = info["region_W"];
  const auto lo = Numbers(region, "min", 3, file, "region_W."), hi = Numbers(region, "max", 3, file, "region_W.");
  WorldBox box;
  box.min_W = Eigen::Vector3d(lo[0], lo[1], lo[2]);
  box.max_W = Eigen::Vector3d(hi[0], hi[1], hi[2]);
  return box;
}

std::unique_ptr<FrameSource> OpenBopScene(const fs::path& dir) { return std::make_unique<BopSceneSource>(dir); }

}  // namespace romunect::jobs
