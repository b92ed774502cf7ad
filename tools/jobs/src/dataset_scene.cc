#include "dataset_scene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sim/approach.h"
#include "romunect/sim/coverage.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/pile.h"
#include "romunect/sim/scanner.h"

namespace romunect::jobs::dataset {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Random views look at the pile from at most this far off vertical: steeper views show the
// pile's sides, flatter ones mostly the bin's walls (and strain the arm's wrist).
constexpr double kMaxTiltRad = 45.0 * kPi / 180.0;
// Tries per random view before the scene is given up as out of the arm's reach.
constexpr int kViewAttempts = 200;
// Piles that do not settle are dropped again with a new seed this many times.
constexpr int kSettleAttempts = 4;
// Silhouettes are rendered in a camera cropped to the projected model plus this margin (px):
// lens distortion bends the edges between projected vertices by far less.
constexpr int kCropMarginPx = 3;

// Uniform in [0, 1) from a mixed 64-bit value.
double Unit(uint64_t bits) { return (bits >> 11) * (1.0 / 9007199254740992.0); }

TriangleMesh ToTriangleMesh(const sim::Mesh& mesh) {
  TriangleMesh out;
  for (const auto& v : mesh.vertices) out.vertices_O.push_back(v.cast<float>());
  out.triangles = mesh.triangles;
  return out;
}

Pose LookAt(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W, double roll_rad) {
  const Eigen::Vector3d z = (target_W - eye_W).normalized();
  Eigen::Vector3d helper = std::abs(z.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d x0 = helper.cross(z).normalized();
  const Eigen::Vector3d y0 = z.cross(x0);
  const Eigen::Vector3d x = std::cos(roll_rad) * x0 + std::sin(roll_rad) * y0;
  Eigen::Matrix3d R;
  R << x, z.cross(x), z;
  return MakePose(R, eye_W);
}

}  // namespace

uint64_t Mix(uint64_t seed, uint64_t index) {
  uint64_t z = seed * 0x9E3779B97F4A7C15ULL + (index + 1) * 0xD1B54A32D192ED03ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

std::string Id6(int id) {
  char s[16];
  std::snprintf(s, sizeof s, "%06d", id);
  return s;
}

int ObjId(sim::ObjectKind kind, int variant, int variants) { return 1 + static_cast<int>(kind) * variants + variant; }

sim::ObjectSpec ModelSpec(sim::ObjectKind kind, int variant) {
  return sim::MakeObject(kind, 1000u * (static_cast<uint32_t>(kind) + 1) + static_cast<uint32_t>(variant));
}

namespace {

// The approach as `romunect scan` plans it: stand-off levels in the rig's measurable range.
sim::ApproachOptions ScanApproach(const Rig& rig) {
  sim::ApproachOptions approach;
  const sim::DepthRange range = sim::MeasurableDepthRange(rig);
  approach.focused_near_m = range.near_m;
  approach.focused_far_m = range.far_m;
  return approach;
}

// The views the settings ask for, tried once in the world without a pile before any file is
// written: an approach the arm cannot fly or a rig whose range it cannot reach is refused.
void CheckViewsReachable(const sim::World& world, const Settings& settings) {
  if (settings.approach) {
    try {
      sim::PlanApproach(world, settings.rig.camera, ScanApproach(settings.rig));
    } catch (const InputError& e) {
      throw InputError("--views", "",
                       "approach: the arm cannot fly it with the rig " + settings.rig_name + ": " + e.what() +
                           "; use --views random");
    }
  }
  if (settings.random) RandomViews(world, settings.rig, 1, settings.seed, world.arm_q());
}

}  // namespace

std::vector<Model> BuildModels(const Settings& settings) {
  // One world holds every model once: each object's rendered geoms, moved into its frame O.
  sim::WorldOptions w;
  std::vector<Model> models;
  for (sim::ObjectKind kind : settings.kinds) {
    for (int v = 0; v < settings.variants; ++v) {
      Model m;
      m.kind = kind;
      m.variant = v;
      m.obj_id = ObjId(kind, v, settings.variants);
      models.push_back(m);
      w.objects.push_back(ModelSpec(kind, v));
    }
  }
  w.T_C_P = settings.rig.T_C_P;
  const sim::World world(w);
  std::vector<Pose> T_W_G;
  world.GeomPoses(&T_W_G);
  const auto& geoms = world.Geoms();
  for (size_t i = 0; i < geoms.size(); ++i) {
    const sim::GeomInfo& g = geoms[i];
    if (g.object < 0) continue;
    Model& m = models[g.object];
    const Pose T_O_G = world.T_W_O(g.object).inverse() * T_W_G[i];
    const int base = static_cast<int>(m.vertices_O.size());
    for (const auto& p_G : g.mesh_G.vertices) m.vertices_O.push_back(T_O_G * p_G);
    for (const auto& t : g.mesh_G.triangles) m.triangles.push_back(t + Eigen::Vector3i::Constant(base));
  }
  // --objects must fit the bin: its inner volume over the kinds' mean bounding-box volume.
  double mean_volume = 0.0;
  for (const Model& m : models) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
    for (const auto& p : m.vertices_O) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
    mean_volume += (hi - lo).prod() / models.size();
  }
  const Eigen::Vector3d inner = world.bin_inner_size_m();
  const int capacity = std::min(60, static_cast<int>(inner.prod() / mean_volume));
  if (settings.objects_max > capacity) {
    char s[200];
    std::snprintf(s, sizeof s, "at most %d objects of these kinds fit the bin (inner %.0f x %.0f x %.0f mm)", capacity,
                  inner.x() * 1e3, inner.y() * 1e3, inner.z() * 1e3);
    throw InputError("--objects", "",
                     std::to_string(settings.objects_min) + "-" + std::to_string(settings.objects_max) + ": " + s);
  }
  CheckViewsReachable(world, settings);
  return models;
}

SceneDraw DrawScene(const Settings& settings, const std::vector<Model>& models, int scene) {
  SceneDraw draw;
  draw.seed = Mix(settings.seed, static_cast<uint64_t>(scene));
  uint64_t k = 0;
  const int n = settings.objects_min +
                static_cast<int>(Mix(draw.seed, k++) % (settings.objects_max - settings.objects_min + 1));
  for (int i = 0; i < n; ++i) {
    draw.model.push_back(static_cast<int>(Mix(draw.seed, k++) % models.size()));
    // Bright plastic mostly; dark and shiny parts are the hard cases of the paper.
    const double u = Unit(Mix(draw.seed, k++));
    draw.material.push_back(u < 0.6 ? "bright" : u < 0.8 ? "dark" : "shiny");
  }
  draw.ambient_scale = std::exp(std::log(0.25) + Unit(Mix(draw.seed, k++)) * std::log(16.0));  // 0.25 .. 4
  return draw;
}

std::unique_ptr<sim::World> BuildSceneWorld(const Settings& settings, const std::vector<Model>& models,
                                            const SceneDraw& draw) {
  sim::WorldOptions w;
  for (size_t i = 0; i < draw.model.size(); ++i) {
    const Model& m = models[draw.model[i]];
    sim::ObjectSpec spec = ModelSpec(m.kind, m.variant);
    spec.material = draw.material[i] == "dark"    ? sim::DarkMaterial()
                    : draw.material[i] == "shiny" ? sim::ShinyMaterial()
                                                  : sim::BrightMaterial();
    w.objects.push_back(spec);
  }
  w.T_C_P = settings.rig.T_C_P;
  sim::SettleSummary settle;
  for (int attempt = 0; attempt < kSettleAttempts; ++attempt) {
    auto world = std::make_unique<sim::World>(w);
    sim::PileOptions pile;
    pile.num_objects = static_cast<int>(w.objects.size());
    pile.seed = static_cast<uint32_t>(Mix(draw.seed, 1000 + attempt));
    settle = sim::DropAndSettle(world.get(), pile);
    if (settle.converged) {
      world->SetPileFrozen(true);
      return world;
    }
  }
  throw std::runtime_error("scene seed " + std::to_string(draw.seed) + ": the pile did not settle in " +
                           std::to_string(kSettleAttempts) + " drops: " + settle.BriefReport());
}

sim::ScanBox SceneRegion(const sim::World& world, const Rig& rig) {
  return sim::ScanRegionBox(world, ScanApproach(rig));
}

std::vector<View> ApproachViews(sim::World* world, const Rig& rig, int every) {
  const sim::ApproachOptions approach = ScanApproach(rig);
  sim::ApproachPlan plan = sim::PlanApproach(*world, rig.camera, approach);
  if (approach.sweep == sim::ApproachOptions::Sweep::kCoverage && approach.focused_far_m > 0) {
    // The scan plans its coverage leg from the pile its descent measured; the views here are
    // chosen before any image is rendered, so the leg is planned for a bin filled to its rim.
    plan.Append(sim::PlanCoverage(*world, rig.camera, approach, world->bin_inner_size_m().z(), plan));
  }
  sim::ApproachExecutor executor(world, plan, approach);
  executor.MoveToStart();
  const int count = static_cast<int>(std::floor(plan.duration_s() * rig.frame_rate_hz + 1e-9)) + 1;
  std::vector<View> views;
  for (int k = 0; k < count; k += every) {
    executor.AdvanceTo(k / rig.frame_rate_hz);
    views.push_back({world->T_W_C(), world->arm_q(), true});
  }
  return views;
}

std::vector<View> RandomViews(const sim::World& world, const Rig& rig, int count, uint64_t seed,
                              const sim::World::ArmVector& q_seed) {
  const sim::DepthRange range = sim::MeasurableDepthRange(rig);
  const Pose T_W_Bin = world.T_W_Bin();
  const Eigen::Vector3d inner = world.bin_inner_size_m();
  std::vector<View> views;
  for (int j = 0; j < count; ++j) {
    bool found = false;
    for (int a = 0; a < kViewAttempts && !found; ++a) {
      const uint64_t s = Mix(Mix(seed, 5000 + j), a);
      auto u = [&](int i) { return Unit(Mix(s, i)); };
      // a point of the pile (the inner 70 % of the floor, 10 mm up), seen from above at a tilt
      const Eigen::Vector3d target_Bin((u(0) - 0.5) * 0.7 * inner.x(), (u(1) - 0.5) * 0.7 * inner.y(), 0.01);
      const double tilt = std::acos(1.0 - u(2) * (1.0 - std::cos(kMaxTiltRad)));  // uniform on the cap
      const double azimuth = 2 * kPi * u(3);
      const double distance = range.near_m + (0.3 + 0.4 * u(4)) * std::min(range.far_m - range.near_m, 0.2);
      const Eigen::Vector3d dir_Bin(std::sin(tilt) * std::cos(azimuth), std::sin(tilt) * std::sin(azimuth),
                                    std::cos(tilt));
      const Eigen::Vector3d target_W = T_W_Bin * target_Bin;
      const Eigen::Vector3d eye_W = T_W_Bin * (target_Bin + distance * dir_Bin);
      const Pose T_W_C = LookAt(eye_W, target_W, 2 * kPi * u(5));
      const sim::IkResult ik = sim::SolveIk(world, sim::ArmSite::kCamera, T_W_C, q_seed);
      if (!ik.converged) continue;
      views.push_back({world.ForwardKinematics(ik.q, sim::ArmSite::kCamera), ik.q, false});
      found = true;
    }
    if (!found) {
      throw InputError("--rig", rig.name,
                       "no random view within the measurable range reaches the bin in " +
                           std::to_string(kViewAttempts) + " tries");
    }
  }
  return views;
}

SceneRenderer::SceneRenderer(const sim::World& world, int threads) {
  world.GeomPoses(&T_W_G_);
  const auto& geoms = world.Geoms();
  handles_.assign(geoms.size(), -1);
  alone_.resize(world.num_objects());
  vertices_W_.resize(world.num_objects());
  for (size_t i = 0; i < geoms.size(); ++i) {
    const sim::GeomInfo& g = geoms[i];
    const TriangleMesh mesh = ToTriangleMesh(g.mesh_G);
    if (!mesh.Problem().empty()) continue;  // degenerate geoms are not drawn
    // The same object ids as the Scanner's: pile objects by index, the rest above them.
    const int id = g.object >= 0 ? g.object : (g.arm ? 2000 : 1000);
    if (g.arm) {
      handles_[i] = scene_.AddMoving(mesh, T_W_G_[i], g.material, id);
    } else {
      scene_.AddStatic(mesh, T_W_G_[i], g.material, id);  // the pile is frozen
    }
    if (g.object >= 0) {
      alone_[g.object].AddStatic(mesh, T_W_G_[i], g.material, id);
      for (const auto& p : g.mesh_G.vertices) vertices_W_[g.object].push_back(T_W_G_[i] * p);
    }
  }
  scene_.Commit();
  for (auto& alone : alone_) alone.Commit();
  options_.threads = threads;
}

void SceneRenderer::Render(const sim::World& world, const Rig& rig, const Pose& T_W_C, GeometryBuffer* out) {
  world.GeomPoses(&T_W_G_);
  for (size_t i = 0; i < handles_.size(); ++i) {
    if (handles_[i] >= 0) scene_.SetPose(handles_[i], T_W_G_[i]);
  }
  scene_.Commit();
  options_.focus_distance_m = rig.optics.focus_distance_m;
  renderer_.Render(scene_, rig.camera, T_W_C, rig.T_C_P, options_, out);
}

cv::Mat SceneRenderer::Silhouette(int object, const Rig& rig, const Pose& T_W_C) {
  const CameraModel& camera = rig.camera;
  cv::Mat mask(camera.height, camera.width, CV_8U, cv::Scalar(0));
  // the crop: the projected vertices' box (the whole image when a vertex is behind the camera)
  const Pose T_C_W = T_W_C.inverse();
  double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
  bool whole = false;
  for (const auto& p_W : vertices_W_[object]) {
    const auto u = camera.Project(T_C_W * p_W);
    if (!u) {
      whole = true;
      break;
    }
    u0 = std::min(u0, u->x()), v0 = std::min(v0, u->y()), u1 = std::max(u1, u->x()), v1 = std::max(v1, u->y());
  }
  int x0 = 0, y0 = 0, x1 = camera.width, y1 = camera.height;  // [x0, x1) x [y0, y1)
  if (!whole) {
    x0 = std::max(0, static_cast<int>(std::floor(u0)) - kCropMarginPx);
    y0 = std::max(0, static_cast<int>(std::floor(v0)) - kCropMarginPx);
    x1 = std::min(camera.width, static_cast<int>(std::ceil(u1)) + kCropMarginPx + 1);
    y1 = std::min(camera.height, static_cast<int>(std::ceil(v1)) + kCropMarginPx + 1);
  }
  if (x1 <= x0 || y1 <= y0) return mask;
  // the same rays as the full camera's pixels: only the principal point moves with the crop
  CameraModel crop = camera;
  crop.width = x1 - x0;
  crop.height = y1 - y0;
  crop.cx = camera.cx - x0;
  crop.cy = camera.cy - y0;
  GeometryBuffer buffer;
  alone_renderer_.Render(alone_[object], crop, T_W_C, rig.T_C_P, options_, &buffer);
  const cv::Mat& ids = buffer.layers[0].object_id;
  cv::Mat roi = mask(cv::Rect(x0, y0, crop.width, crop.height));
  roi.setTo(255, ids == object);
  return mask;
}

std::vector<int> BoundingBox(const cv::Mat& mask) {
  if (cv::countNonZero(mask) == 0) return {-1, -1, -1, -1};
  const cv::Rect r = cv::boundingRect(mask);
  return {r.x, r.y, r.width, r.height};
}

InstanceInfo MeasureInstance(const cv::Mat& mask, const cv::Mat& mask_visib, const cv::Mat& depth) {
  InstanceInfo info;
  info.bbox_obj = BoundingBox(mask);
  info.bbox_visib = BoundingBox(mask_visib);
  info.px_count_all = cv::countNonZero(mask);
  info.px_count_visib = cv::countNonZero(mask_visib);
  info.px_count_valid = cv::countNonZero(mask & (depth > 0));
  info.visib_fract = info.px_count_all > 0 ? static_cast<double>(info.px_count_visib) / info.px_count_all : 0.0;
  return info;
}

nlohmann::json InstanceInfo::ToJson() const {
  return {{"bbox_obj", bbox_obj},
          {"bbox_visib", bbox_visib},
          {"px_count_all", px_count_all},
          {"px_count_valid", px_count_valid},
          {"px_count_visib", px_count_visib},
          {"visib_fract", visib_fract}};
}

cv::Mat DepthToPng16(const cv::Mat& depth_m) {
  cv::Mat out(depth_m.size(), CV_16U);
  const double per_unit = 1e3 / kDepthScaleMm;
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* d = depth_m.ptr<float>(v);
    uint16_t* o = out.ptr<uint16_t>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      const double units = std::round(static_cast<double>(d[u]) * per_unit);
      o[u] = (std::isfinite(units) && units > 0 && units <= 65535) ? static_cast<uint16_t>(units) : 0;
    }
  }
  return out;
}

nlohmann::json RotationRowMajor(const Pose& T) {
  nlohmann::json r = nlohmann::json::array();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r.push_back(T.linear()(i, j));
  }
  return r;
}

nlohmann::json TranslationMm(const Pose& T) {
  return {T.translation().x() * 1e3, T.translation().y() * 1e3, T.translation().z() * 1e3};
}

}  // namespace romunect::jobs::dataset
