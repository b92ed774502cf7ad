// `romunect dataset check`: reads a dataset as a BOP user would and checks every rule of
// jobs/dataset.h's CheckDataset. Every broken rule is a line in the summary, never an abort.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "bop_scene_source.h"
#include "dataset_scene.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/errors.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

// The model rendered at its ground-truth pose meets depth_gt within this (mm): the PNG's
// rounding (half of depth_scale, 0.05 mm) plus float rendering, far below any pose error.
constexpr double kDepthToleranceMm = 0.1;
// Depth steps in the model's render larger than this mark its edges (see OnEdge): three times
// the depth tolerance, far below the objects' millimetre-sized steps.
constexpr double kEdgeStepM = 0.3e-3;
// A lone disagreeing pixel needs this many agreeing neighbours to count as a crack (Isolated).
constexpr int kMinNeighbours = 5;
// visib_fract is written with full double precision.
constexpr double kFractionTolerance = 1e-9;
// Problems listed in full; the rest are counted.
constexpr size_t kMaxListed = 200;

class Problems {
 public:
  explicit Problems(std::vector<std::string>* out) : out_(out) {}
  void Add(const fs::path& file, const std::string& text) { out_->push_back(file.string() + ": " + text); }
  size_t count() const { return out_->size(); }

 private:
  std::vector<std::string>* out_;
};

std::optional<json> ReadJson(const fs::path& file, Problems* problems) {
  std::ifstream in(file);
  if (!in) {
    problems->Add(file, "missing");
    return std::nullopt;
  }
  json doc = json::parse(in, nullptr, false);
  if (doc.is_discarded() || !doc.is_object()) {
    problems->Add(file, "not a JSON object");
    return std::nullopt;
  }
  return doc;
}

// j[key] of a const object without its undefined behaviour: null when j is not an object or has
// no such key (a const json's operator[] reads freed memory for a missing key).
const json& At(const json& j, const std::string& key) {
  static const json kNull;
  if (!j.is_object()) return kNull;
  const auto it = j.find(key);
  return it == j.end() ? kNull : *it;
}

bool IsNumbers(const json& j, size_t n) {
  if (!j.is_array() || j.size() != n) return false;
  for (const auto& x : j) {
    if (!x.is_number()) return false;
  }
  return true;
}

bool IsInts(const json& j, size_t n) {
  if (!j.is_array() || j.size() != n) return false;
  for (const auto& x : j) {
    if (!x.is_number_integer()) return false;
  }
  return true;
}

// Reports `key` missing or of the wrong type; true when it is fine.
bool Expect(const json& entry, const std::string& key, bool ok, const std::string& what, const fs::path& file,
            const std::string& where, Problems* problems) {
  if (!entry.contains(key)) {
    problems->Add(file, where + ": " + key + " missing");
    return false;
  }
  if (!ok) problems->Add(file, where + ": " + key + " is not " + what);
  return ok;
}

// The models' meshes (metres) from their PLY files (ASCII: x y z first, faces of 3).
std::optional<TriangleMesh> ReadPly(const fs::path& file, Problems* problems) {
  std::ifstream in(file);
  std::string line;
  int vertices = -1, faces = -1;
  while (std::getline(in, line) && line != "end_header") {
    std::istringstream words(line);
    std::string a, b;
    int n = 0;
    if (words >> a >> b >> n && a == "element") (b == "vertex" ? vertices : faces) = n;
  }
  if (!in || vertices <= 0 || faces <= 0) {
    problems->Add(file, "not an ASCII PLY with vertices and faces");
    return std::nullopt;
  }
  TriangleMesh mesh;
  for (int i = 0; i < vertices && std::getline(in, line); ++i) {
    std::istringstream words(line);
    Eigen::Vector3f p_mm;
    words >> p_mm.x() >> p_mm.y() >> p_mm.z();
    mesh.vertices_O.push_back(p_mm * 1e-3f);
  }
  for (int i = 0; i < faces && std::getline(in, line); ++i) {
    std::istringstream words(line);
    int n = 0;
    Eigen::Vector3i t;
    words >> n >> t.x() >> t.y() >> t.z();
    if (n == 3) mesh.triangles.push_back(t);
  }
  if (!mesh.Problem().empty()) {
    problems->Add(file, "mesh: " + mesh.Problem());
    return std::nullopt;
  }
  return mesh;
}

Pose PoseFrom(const json& R, const json& t_mm) {
  Eigen::Matrix3d rotation;
  for (int i = 0; i < 9; ++i) rotation(i / 3, i % 3) = R[i].get<double>();
  Pose T = Pose::Identity();
  T.linear() = rotation;
  T.translation() = 1e-3 * Eigen::Vector3d(t_mm[0].get<double>(), t_mm[1].get<double>(), t_mm[2].get<double>());
  return T;
}

cv::Mat ReadImage(const fs::path& file, int type, const CameraModel& camera, Problems* problems) {
  cv::Mat image = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
  if (image.empty()) {
    problems->Add(file, "missing or unreadable");
  } else if (image.type() != type || image.cols != camera.width || image.rows != camera.height) {
    problems->Add(file, Format("%d x %d of type %d; expected %d x %d of type %d", image.cols, image.rows, image.type(),
                               camera.width, camera.height, type));
    image.release();
  }
  return image;
}

struct Context {
  CameraModel camera;
  double depth_scale = 0.1;
  std::map<int, embree::RayScene> models;  // by obj_id, the mesh a moving part
  embree::GeometryRenderer renderer;
  embree::RenderOptions options;
  int isolated_pixels = 0;
};

// Whether a pixel lies on an edge of the model's render: a neighbour the model misses when this
// one is hit (or the other way round), or one more than kEdgeStepM deeper or shallower. There a
// grazing ray's fate turns on the model's vertices, rounded to the PLY's floats, and may differ
// from the scene's render of the same surface.
bool OnEdge(const cv::Mat& model_depth_m, int u, int v) {
  const float d = model_depth_m.at<float>(v, u);
  for (int dv = -1; dv <= 1; ++dv) {
    for (int du = -1; du <= 1; ++du) {
      const int uu = u + du, vv = v + dv;
      if (uu < 0 || vv < 0 || uu >= model_depth_m.cols || vv >= model_depth_m.rows) continue;
      const float n = model_depth_m.at<float>(vv, uu);
      if ((n > 0) != (d > 0) || (d > 0 && std::abs(n - d) > kEdgeStepM)) return true;
    }
  }
  return false;
}

// Whether a pixel that disagrees is alone: at least kMinNeighbours of its neighbours are
// compared and all of them agree. A ray that slips between two triangles of a mesh whose
// vertices were rounded (in the scene's render or the model's) misses one pixel, while a wrong
// pose, model or depth moves whole patches.
bool Isolated(const cv::Mat& status, int u, int v) {
  int compared = 0;
  for (int dv = -1; dv <= 1; ++dv) {
    for (int du = -1; du <= 1; ++du) {
      const int uu = u + du, vv = v + dv;
      if ((du == 0 && dv == 0) || uu < 0 || vv < 0 || uu >= status.cols || vv >= status.rows) continue;
      const int s = status.at<uint8_t>(vv, uu);
      if (s >= 2) return false;
      compared += s == 1;
    }
  }
  return compared >= kMinNeighbours;
}

// Checks the model at its pose against depth_gt on the visible pixels, in a camera cropped to
// the visible box (the same rays as the full image's pixels).
void CheckGeometry(Context& c, int obj_id, const Pose& T_C_O, const cv::Mat& visib, const cv::Mat& depth_gt,
                   const fs::path& file, Problems* problems) {
  std::vector<int> box = dataset::BoundingBox(visib);
  if (box[0] < 0 || !c.models.count(obj_id)) return;
  // one pixel more around the visible box, for the edge test
  const int x0 = std::max(0, box[0] - 1), y0 = std::max(0, box[1] - 1);
  box = {x0, y0, std::min(c.camera.width, box[0] + box[2] + 1) - x0,
         std::min(c.camera.height, box[1] + box[3] + 1) - y0};
  embree::RayScene& scene = c.models.at(obj_id);
  scene.SetPose(0, T_C_O);
  scene.Commit();
  CameraModel crop = c.camera;
  crop.width = box[2];
  crop.height = box[3];
  crop.cx -= box[0];
  crop.cy -= box[1];
  GeometryBuffer buffer;
  c.renderer.Render(scene, crop, Pose::Identity(), Pose::Identity(), c.options, &buffer);
  const cv::Mat model_depth_m = embree::GroundTruthDepth(buffer);
  // per pixel: 0 not visible (or on an edge of the model), 1 agrees, 2 off, 3 missed
  cv::Mat status(box[3], box[2], CV_8U, cv::Scalar(0));
  double worst_mm = 0.0;
  for (int v = 0; v < box[3]; ++v) {
    for (int u = 0; u < box[2]; ++u) {
      if (!visib.at<uint8_t>(v + box[1], u + box[0]) || OnEdge(model_depth_m, u, v)) continue;
      const double model_mm = 1e3 * model_depth_m.at<float>(v, u);
      const double gt_mm = depth_gt.at<uint16_t>(v + box[1], u + box[0]) * c.depth_scale;
      const bool off = std::abs(model_mm - gt_mm) > kDepthToleranceMm;
      status.at<uint8_t>(v, u) = model_mm <= 0 ? 3 : off ? 2 : 1;
      if (model_mm > 0 && off) worst_mm = std::max(worst_mm, std::abs(model_mm - gt_mm));
    }
  }
  int bad = 0, missed = 0;
  for (int v = 0; v < box[3]; ++v) {
    for (int u = 0; u < box[2]; ++u) {
      const int s = status.at<uint8_t>(v, u);
      if (s < 2) continue;
      if (Isolated(status, u, v)) {
        ++c.isolated_pixels;
      } else {
        (s == 2 ? bad : missed) += 1;
      }
    }
  }
  if (missed > 0 || bad > 0) {
    problems->Add(file, Format("obj_id %d: %d visible pixels off depth_gt by more than %.1f mm (worst %.3f mm), %d "
                               "where the model at its pose is not (off its edges)",
                               obj_id, bad, kDepthToleranceMm, worst_mm, missed));
  }
}

void CheckInstance(Context& c, const fs::path& dir, const std::string& image, int k, const json& gt, const json& info,
                   const cv::Mat& depth, const cv::Mat& depth_gt, Problems* problems) {
  const std::string name = image + "_" + dataset::Id6(k) + ".png";
  const cv::Mat mask = ReadImage(dir / "mask" / name, CV_8U, c.camera, problems);
  const cv::Mat visib = ReadImage(dir / "mask_visib" / name, CV_8U, c.camera, problems);
  if (mask.empty() || visib.empty()) return;
  const fs::path info_file = dir / "scene_gt_info.json";
  const std::string where = image + "[" + std::to_string(k) + "]";
  if (cv::countNonZero(visib & ~mask) > 0) {
    problems->Add(dir / "mask_visib" / name, Format("%d pixels outside mask", cv::countNonZero(visib & ~mask)));
  }
  const dataset::InstanceInfo measured = dataset::MeasureInstance(mask, visib, depth);
  const json expected = measured.ToJson();
  for (const char* key : {"bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib"}) {
    if (info[key] != expected[key]) {
      problems->Add(info_file,
                    where + ": " + key + " is " + info[key].dump() + "; the masks give " + expected[key].dump());
    }
  }
  const double all = info["px_count_all"].get<double>();
  const double fract = all > 0 ? info["px_count_visib"].get<double>() / all : 0.0;
  if (std::abs(info["visib_fract"].get<double>() - fract) > kFractionTolerance) {
    problems->Add(info_file, where + ": visib_fract " + info["visib_fract"].dump() +
                                 " is not px_count_visib / px_count_all = " + std::to_string(fract));
  }
  const Pose T_C_O = PoseFrom(gt["cam_R_m2c"], gt["cam_t_m2c"]);
  if (!RigidityProblem(T_C_O.matrix(), 1e-6).empty()) {
    problems->Add(dir / "scene_gt.json", where + ": cam_R_m2c is not a rotation");
    return;
  }
  if (!depth_gt.empty())
    CheckGeometry(c, gt["obj_id"].get<int>(), T_C_O, visib, depth_gt, dir / "mask_visib" / name, problems);
}

// The entries of one image in the three scene files; false when they cannot be read further.
bool CheckEntries(const fs::path& dir, const std::string& id, const json& cam, const json& gt, const json& info,
                  const std::set<int>& obj_ids, Problems* problems) {
  const fs::path cam_file = dir / "scene_camera.json", gt_file = dir / "scene_gt.json",
                 info_file = dir / "scene_gt_info.json";
  bool ok = Expect(cam, "cam_K", IsNumbers(At(cam, "cam_K"), 9), "9 numbers", cam_file, id, problems);
  ok &= Expect(cam, "cam_R_w2c", IsNumbers(At(cam, "cam_R_w2c"), 9), "9 numbers", cam_file, id, problems);
  ok &= Expect(cam, "cam_t_w2c", IsNumbers(At(cam, "cam_t_w2c"), 3), "3 numbers", cam_file, id, problems);
  ok &= Expect(cam, "depth_scale", At(cam, "depth_scale").is_number(), "a number", cam_file, id, problems);
  if (!gt.is_array() || !info.is_array() || gt.size() != info.size()) {
    problems->Add(info_file, id + ": not a list as long as scene_gt.json's");
    return false;
  }
  for (size_t k = 0; k < gt.size(); ++k) {
    const std::string where = id + "[" + std::to_string(k) + "]";
    ok &= Expect(gt[k], "obj_id", At(gt[k], "obj_id").is_number_integer() && obj_ids.count(At(gt[k], "obj_id").get<int>()),
                 "an obj_id of models_info.json", gt_file, where, problems);
    ok &= Expect(gt[k], "cam_R_m2c", IsNumbers(At(gt[k], "cam_R_m2c"), 9), "9 numbers", gt_file, where, problems);
    ok &= Expect(gt[k], "cam_t_m2c", IsNumbers(At(gt[k], "cam_t_m2c"), 3), "3 numbers", gt_file, where, problems);
    for (const char* key : {"bbox_obj", "bbox_visib"}) {
      ok &= Expect(info[k], key, IsInts(At(info[k], key), 4), "4 integers", info_file, where, problems);
    }
    for (const char* key : {"px_count_all", "px_count_valid", "px_count_visib"}) {
      ok &= Expect(info[k], key, At(info[k], key).is_number_integer(), "an integer", info_file, where, problems);
    }
    ok &= Expect(info[k], "visib_fract", At(info[k], "visib_fract").is_number(), "a number", info_file, where, problems);
  }
  return ok;
}

void CheckScene(Context& c, const fs::path& dir, const std::set<int>& obj_ids, DatasetCheckSummary* summary,
                Problems* problems) {
  const auto cam = ReadJson(dir / "scene_camera.json", problems);
  const auto gt = ReadJson(dir / "scene_gt.json", problems);
  const auto info = ReadJson(dir / "scene_gt_info.json", problems);
  if (!cam || !gt || !info) return;
  for (const auto& [id, camera_entry] : cam->items()) {
    if (!gt->contains(id) || !info->contains(id)) {
      problems->Add(dir / "scene_gt.json",
                    "image " + id + " of scene_camera.json missing here or in scene_gt_info.json");
      continue;
    }
    ++summary->images;
    if (!CheckEntries(dir, id, camera_entry, (*gt)[id], (*info)[id], obj_ids, problems)) continue;
    const std::string image = dataset::Id6(std::stoi(id));
    ReadImage(dir / "gray" / (image + ".png"), CV_16U, c.camera, problems);
    ReadImage(dir / "raw" / (image + ".png"), CV_16U, c.camera, problems);
    const cv::Mat depth = ReadImage(dir / "depth" / (image + ".png"), CV_16U, c.camera, problems);
    const cv::Mat depth_gt = ReadImage(dir / "depth_gt" / (image + ".png"), CV_16U, c.camera, problems);
    if (depth.empty()) continue;
    for (size_t k = 0; k < (*gt)[id].size(); ++k) {
      ++summary->annotations;
      CheckInstance(c, dir, image, static_cast<int>(k), (*gt)[id][k], (*info)[id][k], depth, depth_gt, problems);
    }
  }
}

}  // namespace

std::string DatasetCheckSummary::Text() const {
  std::string text;
  for (size_t i = 0; i < problems.size() && i < kMaxListed; ++i) text += problems[i] + "\n";
  if (problems.size() > kMaxListed) text += Format("... and %zu more\n", problems.size() - kMaxListed);
  if (incomplete_scenes > 0) text += Format("%d incomplete scenes (.incomplete) not checked\n", incomplete_scenes);
  return text + Format("dataset check: %d scenes, %d images, %d object instances (%d lone pixels through cracks "
                       "between triangles): %s\n",
                       scenes, images, annotations, isolated_pixels,
                       problems.empty() ? "all rules hold" : (std::to_string(problems.size()) + " problems").c_str());
}

DatasetCheckSummary CheckDataset(const std::string& dir_name, int threads) {
  const fs::path dir(dir_name);
  if (!fs::is_directory(dir) || !fs::exists(dir / "dataset.json")) {
    throw InputError(dir.string(), "", "holds no dataset (dataset.json)");
  }
  DatasetCheckSummary summary;
  Problems problems(&summary.problems);
  Context c;
  c.options.threads = std::max(1, threads);
  const auto camera = ReadJson(dir / "camera.json", &problems);
  const auto models_info = ReadJson(dir / "models" / "models_info.json", &problems);
  if (!camera || !models_info) return summary;
  for (const char* key : {"cx", "cy", "depth_scale", "fx", "fy"}) {
    if (!(*camera)[key].is_number()) problems.Add(dir / "camera.json", std::string(key) + " missing or not a number");
  }
  for (const char* key : {"height", "width"}) {
    if (!IsImageSide((*camera)[key])) {
      problems.Add(dir / "camera.json", std::string(key) + " missing or not a whole number of pixels in [1, 65536]");
    }
  }
  if (problems.count() > 0) return summary;
  c.camera.width = (*camera)["width"].get<int>();
  c.camera.height = (*camera)["height"].get<int>();
  c.camera.fx = (*camera)["fx"].get<double>();
  c.camera.fy = (*camera)["fy"].get<double>();
  c.camera.cx = (*camera)["cx"].get<double>();
  c.camera.cy = (*camera)["cy"].get<double>();
  if (IsNumbers((*camera)["distortion"], 5)) {
    for (int i = 0; i < 5; ++i) c.camera.distortion[i] = (*camera)["distortion"][i].get<double>();
  }
  c.depth_scale = (*camera)["depth_scale"].get<double>();
  std::set<int> obj_ids;
  for (const auto& [key, model] : models_info->items()) {
    const fs::path info_file = dir / "models" / "models_info.json";
    for (const char* field : {"diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z"}) {
      Expect(model, field, model[field].is_number(), "a number", info_file, key, &problems);
    }
    const int id = std::atoi(key.c_str());
    obj_ids.insert(id);
    if (const auto mesh = ReadPly(dir / "models" / ("obj_" + dataset::Id6(id) + ".ply"), &problems)) {
      c.models[id].AddMoving(*mesh, Pose::Identity(), IrMaterial{}, id);
    }
  }
  std::vector<fs::path> scenes;
  for (const auto& entry : fs::directory_iterator(dir / dataset::kSplit)) {
    if (!entry.is_directory()) continue;
    if (entry.path().extension().empty()) {
      scenes.push_back(entry.path());
    } else if (entry.path().extension() == ".incomplete") {
      ++summary.incomplete_scenes;  // being written, or left by a killed run: a rerun completes it
    }
  }
  std::sort(scenes.begin(), scenes.end());
  for (const fs::path& scene : scenes) {
    ++summary.scenes;
    CheckScene(c, scene, obj_ids, &summary, &problems);
  }
  summary.isolated_pixels = c.isolated_pixels;
  return summary;
}

}  // namespace romunect::jobs
