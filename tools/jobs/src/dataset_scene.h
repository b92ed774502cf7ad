// The parts of `romunect dataset` (jobs/dataset.h): its settings, the object models, a scene's
// random draws, its views and its rendering. Private to the jobs library.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/approach.h"
#include "romunect/sim/objects.h"
#include "romunect/sim/world.h"
#include "romunect/tools/jobs/dataset.h"

namespace romunect::jobs::dataset {

// Depth PNGs hold depth in units of 0.1 mm (BOP's depth_scale: value * depth_scale = mm): a
// 0.05 mm rounding step, under the check's 0.1 mm, and up to 6.5 m.
constexpr double kDepthScaleMm = 0.1;
// The split folder that holds the scenes (BOP: <split>/<scene>/).
constexpr const char* kSplit = "train";

// A 64-bit mix of a seed and an index (SplitMix64 finalizer): independent streams per scene,
// view and attempt, whatever else is drawn.
uint64_t Mix(uint64_t seed, uint64_t index);

// The options that decide the bytes, validated. ToJson() is dataset.json's "settings".
struct Settings {
  uint32_t seed = 1;
  std::string rig_name;  // the option's value
  Rig rig;
  std::vector<sim::ObjectKind> kinds;
  int objects_min = 1, objects_max = 1;
  int variants = 1;
  bool approach = true, random = true;
  int views_per_scene = 0;
  int every = 1;
  nlohmann::json ToJson() const;
};
// Throws InputError naming the option.
Settings ParseSettings(const DatasetOptions& options);

// One object model: obj_id = 1 + kind index (in ObjectKind order) * variants + variant, so
// an id means the same mesh in any dataset with the same variant count.
struct Model {
  int obj_id = 0;
  sim::ObjectKind kind = sim::ObjectKind::kPillBox;
  int variant = 0;
  std::vector<Eigen::Vector3d> vertices_O;  // metres, the rendered geometry in the object frame
  std::vector<Eigen::Vector3i> triangles;
};
int ObjId(sim::ObjectKind kind, int variant, int variants);
sim::ObjectSpec ModelSpec(sim::ObjectKind kind, int variant);
// The models of every (kind, variant) of the settings, as MuJoCo renders them; and the bin's
// capacity check of --objects (InputError naming it).
std::vector<Model> BuildModels(const Settings& settings);
// A file several shards may write at once with the same bytes (dataset.json, camera.json, the
// models): written under ".<name>.tmp-<host>-<pid>-<n>" and renamed, so readers see it whole.
void WriteShared(const std::filesystem::path& path, const std::string& text);
// Removes the temporaries of WriteShared in `dir` that a killed process on the local host left (its
// pid is gone); other hosts' are theirs to finish.
void RemoveStaleTemporaries(const std::filesystem::path& dir);

// models/obj_NNNNNN.ply (ASCII, mm, vertex normals) and models/models_info.json (WriteShared).
void WriteModels(const std::filesystem::path& models_dir, const std::vector<Model>& models);
// The symmetries the model's vertex set maps onto itself (BOP's symmetries_discrete: 4 x 4
// row-major, translation in mm), tried among half turns about the axes through the bounding
// box centre and n-fold turns about its z.
std::vector<std::vector<double>> DiscreteSymmetries(const Model& model);

// One camera view of a scene: the camera pose and the arm's joints that give it.
struct View {
  Pose T_W_C = Pose::Identity();
  sim::World::ArmVector q = sim::World::ArmVector::Zero();
  bool approach = false;  // from the approach trajectory (else a random view)
};
// The approach trajectory's executed camera poses at the rig's frame rate, every `every`-th.
// The one place the dataset drives the approach (the Scanner's motion), through sim's API.
std::vector<View> ApproachViews(sim::World* world, const Rig& rig, int every);
// `count` random views the arm reaches: looking at a point of the pile from up to 45 degrees
// off vertical, any roll, with that point in the rig's measurable range.
std::vector<View> RandomViews(const sim::World& world, const Rig& rig, int count, uint64_t seed,
                              const sim::World::ArmVector& q_seed);

// The box `romunect scan` fuses for this world and rig (sim::ScanRegionBox), m.
sim::ScanBox SceneRegion(const sim::World& world, const Rig& rig);

// What one scene holds, drawn from (settings, scene index) alone.
struct SceneDraw {
  uint64_t seed = 0;
  std::vector<int> model;             // index into the models, per object
  std::vector<std::string> material;  // "bright", "dark", "shiny", per object
  double ambient_scale = 1.0;         // of the rig's ambient IR
};
SceneDraw DrawScene(const Settings& settings, const std::vector<Model>& models, int scene);

// The world of a scene, settled (drops retried with new seeds when a pile does not settle).
std::unique_ptr<sim::World> BuildSceneWorld(const Settings& settings, const std::vector<Model>& models,
                                            const SceneDraw& draw);

// Renders a frozen scene: the whole world with the arm where it is, and each pile object
// alone (its full silhouette) in a camera cropped to its projection.
class SceneRenderer {
 public:
  SceneRenderer(const sim::World& world, int threads);
  // Renders the world as it is (the arm's geoms at their current poses) seen from T_W_C.
  void Render(const sim::World& world, const Rig& rig, const Pose& T_W_C, GeometryBuffer* out);
  // Object `object` alone: CV_8U, 255 on its silhouette, the camera's size.
  cv::Mat Silhouette(int object, const Rig& rig, const Pose& T_W_C);

 private:
  embree::RaySceneOptions scene_options_;
  embree::RayScene scene_;
  std::vector<int> handles_;  // per geom of the world: moving handle or -1
  std::vector<Pose> T_W_G_;
  std::vector<embree::RayScene> alone_;
  std::vector<std::vector<Eigen::Vector3d>> vertices_W_;  // per object
  embree::GeometryRenderer renderer_, alone_renderer_;
  embree::RenderOptions options_;
};

// Per image of a scene, what scene_gt_info.json says of one object instance, from its masks.
struct InstanceInfo {
  std::vector<int> bbox_obj{-1, -1, -1, -1}, bbox_visib{-1, -1, -1, -1};
  int px_count_all = 0, px_count_valid = 0, px_count_visib = 0;
  double visib_fract = 0.0;
  nlohmann::json ToJson() const;
};
InstanceInfo MeasureInstance(const cv::Mat& mask, const cv::Mat& mask_visib, const cv::Mat& depth);
// x, y, width, height of the nonzero pixels, or -1s when there are none.
std::vector<int> BoundingBox(const cv::Mat& mask);

// Depth (CV_32F metres) as BOP's uint16 depth image (kDepthScaleMm units, rounded; 0 stays 0,
// depths beyond the range become 0).
cv::Mat DepthToPng16(const cv::Mat& depth_m);
// A pose's rotation row-major and translation in mm, BOP's cam_R_* / cam_t_*.
nlohmann::json RotationRowMajor(const Pose& T);
nlohmann::json TranslationMm(const Pose& T);
// "000042"
std::string Id6(int id);

}  // namespace romunect::jobs::dataset
