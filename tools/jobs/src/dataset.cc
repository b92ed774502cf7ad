#include "romunect/tools/jobs/dataset.h"

#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include "dataset_png.h"
#include "dataset_scene.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sim/sensor_imager.h"
#include "romunect/tools/jobs/output_folder.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using namespace dataset;

constexpr const char* kFormat = "romunect-dataset";
constexpr int kVersion = 1;

struct Shard {
  int index = 0, count = 1;
};

Shard ParseShard(const std::string& text) {
  Shard s;
  char rest = 0;
  if (std::sscanf(text.c_str(), "%d/%d%c", &s.index, &s.count, &rest) != 2 || s.count < 1 || s.index < 0 ||
      s.index >= s.count) {
    throw InputError("--shard", "", "'" + text + "': expected I/N with 0 <= I < N (shard I of N, from 0)");
  }
  return s;
}

// The option a settings key comes from, for messages.
std::string OptionOf(const std::string& key) {
  static const std::map<std::string, std::string> options = {{"seed", "--seed"},
                                                             {"rig", "--rig"},
                                                             {"kinds", "--kinds"},
                                                             {"objects", "--objects"},
                                                             {"variants", "--variants"},
                                                             {"views", "--views"},
                                                             {"views_per_scene", "--views-per-scene"},
                                                             {"every", "--every"}};
  const auto it = options.find(key);
  return it == options.end() ? key : it->second;
}

// A folder holding a dataset must hold one of the same settings; any other non-empty folder is
// refused. Nothing is written here.
void CheckExistingFolder(const fs::path& dir, const nlohmann::json& settings) {
  if (!fs::exists(dir)) return;
  if (!fs::is_directory(dir)) throw InputError(dir.string(), "", "is a file; OUT_DIR must be a folder");
  const fs::path file = dir / "dataset.json";
  if (!fs::exists(file)) {
    // Empty, or being created by another shard this moment (its files and temporaries only).
    for (const auto& entry : fs::directory_iterator(dir)) {
      const std::string name = entry.path().filename().string();
      const bool ours = name == kSplit || name == "models" || name == "camera.json" ||
                        (name[0] == '.' && name.find(".tmp-") != std::string::npos);
      if (!ours) throw InputError(dir.string(), "", "holds " + name + " but no dataset.json; choose another OUT_DIR");
    }
    return;
  }
  std::ifstream in(file);
  const nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
  if (!doc.is_object() || !doc.contains("format") || doc["format"] != kFormat ||
      !doc.contains("settings") || !doc["settings"].is_object()) {
    throw InputError(file.string(), "format", "expected a " + std::string(kFormat) + " file");
  }
  for (const auto& [key, value] : settings.items()) {
    if (!doc["settings"].contains(key) || doc["settings"][key] != value) {
      const std::string had = doc["settings"].contains(key) ? doc["settings"][key].dump() : "nothing";
      throw InputError(OptionOf(key), "",
                       value.dump() + " differs from the dataset in " + dir.string() + ", made with " + had +
                           "; rerun with its settings (dataset.json) or choose another OUT_DIR");
    }
  }
}

// {"0": ..., "1": ..., "10": ...}: keys in numeric order, one per line (BOP's files).
std::string NumberedJson(const std::map<int, nlohmann::json>& entries) {
  std::string text = "{";
  for (const auto& [id, value] : entries) {
    text += (text.size() > 1 ? ",\n  \"" : "\n  \"") + std::to_string(id) + "\": " + value.dump();
  }
  return text + "\n}\n";
}

uintmax_t FolderBytes(const fs::path& dir) {
  uintmax_t bytes = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) bytes += entry.file_size();
  }
  return bytes;
}

struct Shared {
  const Settings& settings;
  const std::vector<Model>& models;
  sim::SensorImager& imager;
  int threads = 1;
};

struct SceneCounts {
  int images = 0, annotations = 0;
  DatasetSummary::CpuSeconds cpu;
};

// One image: the files of every folder, and its entries of the scene's JSON files.
void WriteImage(const Shared& c, SceneRenderer& renderer, sim::World& world, const Rig& rig,
                const std::vector<int>& obj_ids, const View& view, uint64_t seed, int im, const fs::path& dir,
                std::map<int, nlohmann::json>* camera, std::map<int, nlohmann::json>* gt,
                std::map<int, nlohmann::json>* gt_info, SceneCounts* counts) {
  double cpu = ProcessCpuSeconds();
  auto lap = [&cpu](double* to) {
    const double now = ProcessCpuSeconds();
    *to += now - cpu;
    cpu = now;
  };
  world.SetArmQ(view.q);
  GeometryBuffer geometry;
  renderer.Render(world, rig, view.T_W_C, &geometry);
  Frame frame;
  frame.index = im;
  frame.gt_depth_m = embree::GroundTruthDepth(geometry);
  lap(&counts->cpu.render);
  c.imager.Image(rig, geometry, seed, &frame);
  lap(&counts->cpu.imaging);
  const std::string name = Id6(im);
  WritePng(dir / "gray" / (name + ".png"), frame.ir, PngKind::kNoisy);
  WritePng(dir / "depth" / (name + ".png"), DepthToPng16(frame.depth_m), PngKind::kDepth);
  WritePng(dir / "depth_gt" / (name + ".png"), DepthToPng16(frame.gt_depth_m), PngKind::kDepth);
  WritePng(dir / "raw" / (name + ".png"), frame.raw, PngKind::kDepth);
  lap(&counts->cpu.images);

  const Pose T_C_W = view.T_W_C.inverse();
  const cv::Matx33d K = rig.camera.CameraMatrix();
  (*camera)[im] = {{"cam_K", {K(0, 0), K(0, 1), K(0, 2), K(1, 0), K(1, 1), K(1, 2), K(2, 0), K(2, 1), K(2, 2)}},
                   {"cam_R_w2c", RotationRowMajor(T_C_W)},
                   {"cam_t_w2c", TranslationMm(T_C_W)},
                   {"depth_scale", kDepthScaleMm},
                   {"view", view.approach ? "approach" : "random"}};
  nlohmann::json gt_list = nlohmann::json::array(), info_list = nlohmann::json::array();
  const cv::Mat& ids = geometry.layers[0].object_id;
  for (int i = 0; i < world.num_objects(); ++i) {
    const cv::Mat mask = renderer.Silhouette(i, rig, view.T_W_C);
    lap(&counts->cpu.silhouettes);
    if (cv::countNonZero(mask) == 0) continue;  // not in the image: not annotated
    const cv::Mat visib = ids == i;             // 255 where the whole scene shows the object
    const std::string mask_name = name + "_" + Id6(static_cast<int>(gt_list.size())) + ".png";
    WritePng(dir / "mask" / mask_name, mask, PngKind::kMask);
    WritePng(dir / "mask_visib" / mask_name, visib, PngKind::kMask);
    const Pose T_C_O = T_C_W * world.T_W_O(i);
    gt_list.push_back(
        {{"cam_R_m2c", RotationRowMajor(T_C_O)}, {"cam_t_m2c", TranslationMm(T_C_O)}, {"obj_id", obj_ids[i]}});
    info_list.push_back(MeasureInstance(mask, visib, frame.depth_m).ToJson());
    lap(&counts->cpu.masks);
  }
  (*gt)[im] = gt_list;
  (*gt_info)[im] = info_list;
  counts->images += 1;
  counts->annotations += static_cast<int>(gt_list.size());
}

// One scene, built in <scene>.incomplete/ and renamed when complete.
SceneCounts WriteScene(const Shared& c, int scene, const fs::path& split_dir) {
  const fs::path final_dir = split_dir / Id6(scene);
  const fs::path dir = split_dir / (Id6(scene) + ".incomplete");
  fs::remove_all(dir);  // a killed run's leftovers: the scene is redone from the start
  for (const char* sub : {"gray", "depth", "depth_gt", "raw", "mask", "mask_visib"}) fs::create_directories(dir / sub);

  const double cpu_setup = ProcessCpuSeconds();
  const SceneDraw draw = DrawScene(c.settings, c.models, scene);
  std::unique_ptr<sim::World> world = BuildSceneWorld(c.settings, c.models, draw);
  std::vector<View> views;
  if (c.settings.approach) views = ApproachViews(world.get(), c.settings.rig, c.settings.every);
  if (c.settings.random) {
    const std::vector<View> random = RandomViews(*world, c.settings.rig, c.settings.views_per_scene, draw.seed,
                                                 world->arm_q());
    views.insert(views.end(), random.begin(), random.end());
  }
  Rig rig = c.settings.rig;
  rig.optics.ambient_e_per_s *= draw.ambient_scale;
  std::vector<int> obj_ids;
  for (int m : draw.model) obj_ids.push_back(c.models[m].obj_id);

  SceneRenderer renderer(*world, c.threads);
  std::map<int, nlohmann::json> camera, gt, gt_info;
  SceneCounts counts;
  counts.cpu.scene = ProcessCpuSeconds() - cpu_setup;
  for (size_t k = 0; k < views.size(); ++k) {
    WriteImage(c, renderer, *world, rig, obj_ids, views[k], Mix(draw.seed, 7000 + k), static_cast<int>(k), dir, &camera,
               &gt, &gt_info, &counts);
  }
  WriteTextAtomically(dir / "scene_camera.json", NumberedJson(camera));
  WriteTextAtomically(dir / "scene_gt.json", NumberedJson(gt));
  WriteTextAtomically(dir / "scene_gt_info.json", NumberedJson(gt_info));
  // romunect's extras: what the scene drew, and the box a scan of it fuses (`romunect fuse`)
  const sim::ScanBox region = SceneRegion(*world, c.settings.rig);
  nlohmann::json objects = nlohmann::json::array();
  for (size_t i = 0; i < draw.model.size(); ++i) {
    const Model& m = c.models[draw.model[i]];
    objects.push_back({{"obj_id", m.obj_id},
                       {"kind", sim::ToString(m.kind)},
                       {"variant", m.variant},
                       {"material", draw.material[i]}});
  }
  const nlohmann::json info = {{"scene", scene},
                               {"seed", draw.seed},
                               {"objects", objects},
                               {"ambient_e_per_s", rig.optics.ambient_e_per_s},
                               {"region_W",
                                {{"min", {region.min_W.x(), region.min_W.y(), region.min_W.z()}},
                                 {"max", {region.max_W.x(), region.max_W.y(), region.max_W.z()}}}},
                               {"images", static_cast<int>(views.size())}};
  WriteTextAtomically(dir / "scene_info.json", info.dump(2) + "\n");
  fs::rename(dir, final_dir);
  return counts;
}

std::string Duration(double s) {
  const int t = static_cast<int>(s + 0.5);
  return t >= 3600 ? Format("%dh%02dm", t / 3600, t / 60 % 60) : Format("%dm%02ds", t / 60, t % 60);
}

// Everything checked before a file is written: the options, the folder, the models' fit.
struct Prepared {
  Settings settings;
  Shard shard;
  fs::path dir;
  nlohmann::json doc;
};

Prepared Prepare(const DatasetOptions& o) {
  Prepared p;
  if (o.scenes < 1 || o.scenes > 1000000)
    throw InputError("--scenes", "", std::to_string(o.scenes) + " is outside 1..1000000");
  if (o.first_scene < 0 || o.first_scene > 999999 - o.scenes + 1) {
    throw InputError("--first-scene", "", std::to_string(o.first_scene) + ": scene ids end at 999999");
  }
  if (o.threads < 1 || o.threads > 64)
    throw InputError("--threads", "", std::to_string(o.threads) + " is outside 1..64");
  p.shard = ParseShard(o.shard);
  p.dir = OutputFolder(o.out, "OUT_DIR");
  p.settings = ParseSettings(o);
  p.doc = {{"format", kFormat}, {"version", kVersion}, {"settings", p.settings.ToJson()}};
  CheckExistingFolder(p.dir, p.doc["settings"]);
  CheckFolderCanBeCreated(p.dir, "OUT_DIR");
  return p;
}

}  // namespace

std::string DatasetSummary::Text() const {
  const double n = std::max(1, images);
  return Format(
      "dataset %s: %d scenes written, %d already complete; %d images, %d object instances, %d models; %.1f MB "
      "written (%.2f MB per image); %.1f s (%.0f ms CPU per image: scene set-up %.0f, render %.0f, imaging %.0f, "
      "image files %.0f, silhouettes %.0f, masks %.0f; %.0f images per hour)\n",
      dir.string().c_str(), scenes_written, scenes_skipped, images, annotations, models, mb_written, mb_written / n,
      wall_s, 1e3 * image_cpu_s / n, 1e3 * cpu.scene / n, 1e3 * cpu.render / n, 1e3 * cpu.imaging / n,
      1e3 * cpu.images / n, 1e3 * cpu.silhouettes / n, 1e3 * cpu.masks / n,
      wall_s > 0 ? 3600.0 * images / wall_s : 0.0);
}

DatasetSummary RunDataset(const DatasetOptions& o) {
  const Stopwatch wall;
  const double cpu0 = ProcessCpuSeconds();
  const Prepared p = Prepare(o);
  const std::vector<Model> models = BuildModels(p.settings);  // refuses an --objects range that does not fit

  // The shared files: every shard writes the same bytes under a temporary name and renames.
  fs::create_directories(p.dir);
  WriteShared(p.dir / "dataset.json", p.doc.dump(2) + "\n");  // first: the folder is a dataset
  fs::create_directories(p.dir / kSplit);
  const CameraModel& cam = p.settings.rig.camera;
  const nlohmann::json camera = {
      {"cx", cam.cx}, {"cy", cam.cy},         {"depth_scale", kDepthScaleMm}, {"fx", cam.fx},
      {"fy", cam.fy}, {"height", cam.height}, {"width", cam.width},           {"distortion", cam.distortion}};
  WriteShared(p.dir / "camera.json", camera.dump(2) + "\n");
  RemoveStaleTemporaries(p.dir);
  RemoveStaleTemporaries(p.dir / "models");
  WriteModels(p.dir / "models", models);

  DatasetSummary summary;
  summary.dir = p.dir;
  summary.models = static_cast<int>(models.size());
  std::vector<int> todo;
  for (int s = o.first_scene; s < o.first_scene + o.scenes; ++s) {
    if (s % p.shard.count != p.shard.index) continue;
    if (fs::is_directory(p.dir / kSplit / Id6(s))) {
      ++summary.scenes_skipped;
    } else {
      todo.push_back(s);
    }
  }
  if (!o.quiet) {
    std::fprintf(stderr, "dataset: %zu scenes to write into %s (shard %d/%d, %d complete already)\n", todo.size(),
                 p.dir.string().c_str(), p.shard.index, p.shard.count, summary.scenes_skipped);
  }
  sim::SensorImagerOptions imager_options;
  imager_options.threads = o.threads;
  sim::SensorImager imager(p.settings.rig, imager_options);
  const Shared shared{p.settings, models, imager, o.threads};
  const Stopwatch loop;
  const double cpu_loop = ProcessCpuSeconds();
  for (size_t n = 0; n < todo.size(); ++n) {
    const Stopwatch scene_time;
    const SceneCounts counts = WriteScene(shared, todo[n], p.dir / kSplit);
    summary.scenes_written += 1;
    summary.images += counts.images;
    summary.annotations += counts.annotations;
    summary.cpu.Add(counts.cpu);
    summary.mb_written += FolderBytes(p.dir / kSplit / Id6(todo[n])) / 1e6;
    if (!o.quiet) {
      const double eta = loop.seconds() / (n + 1) * (todo.size() - n - 1);
      std::fprintf(stderr, "dataset: scene %s (%zu/%zu): %d images, %d instances, %.2f images/s, ETA %s\n",
                   Id6(todo[n]).c_str(), n + 1, todo.size(), counts.images, counts.annotations,
                   counts.images / scene_time.seconds(), Duration(eta).c_str());
    }
  }
  summary.image_cpu_s = ProcessCpuSeconds() - cpu_loop;
  summary.wall_s = wall.seconds();
  summary.cpu_s = ProcessCpuSeconds() - cpu0;
  return summary;
}

}  // namespace romunect::jobs
