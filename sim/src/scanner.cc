#include "romunect/sim/scanner.h"

#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sim/coverage.h"

namespace romunect::sim {
namespace {

// Object ids in the rendered GeometryLayer: pile objects by index, then these.
constexpr int kStaticObjectId = 1000;
constexpr int kArmObjectId = 2000;
// The ground-truth height map is traced from this high up: rays 30 m long are parallel to
// within 0.12 mm over a 15 cm box for surfaces 5 cm high, and float hits keep 2 um there.
constexpr double kTruthCameraHeightM = 30.0;

TriangleMesh ToTriangleMesh(const Mesh& mesh) {
  TriangleMesh out;
  out.vertices_O.reserve(mesh.vertices.size());
  for (const auto& v : mesh.vertices) out.vertices_O.push_back(v.cast<float>());
  out.triangles = mesh.triangles;
  return out;
}

int ObjectId(const GeomInfo& g) { return g.object >= 0 ? g.object : (g.arm ? kArmObjectId : kStaticObjectId); }

// The world's visible geoms as a RayScene: fixed ones static, the rest instances. handles[i]
// is the moving handle of geom i (-1 when static or left out). While the pile is frozen its
// objects are fixed too: in the static BVH they cost no instance traversal (most rays of a scan
// end on them) and no pose update per frame.
embree::RayScene MirrorWorld(const World& world, bool with_arm, std::vector<int>* handles) {
  embree::RayScene scene;
  std::vector<Pose> T_W_G;
  world.GeomPoses(&T_W_G);
  const auto& geoms = world.Geoms();
  handles->assign(geoms.size(), -1);
  for (size_t i = 0; i < geoms.size(); ++i) {
    const GeomInfo& g = geoms[i];
    if (g.arm && !with_arm) continue;
    const TriangleMesh mesh = ToTriangleMesh(g.mesh_G);
    if (!mesh.Problem().empty()) continue;  // degenerate geoms are not drawn
    if (g.moving && !(g.object >= 0 && world.pile_frozen())) {
      (*handles)[i] = scene.AddMoving(mesh, T_W_G[i], g.material, ObjectId(g));
    } else {
      scene.AddStatic(mesh, T_W_G[i], g.material, ObjectId(g));
    }
  }
  scene.Commit();
  return scene;
}

void UpdatePoses(const World& world, const std::vector<int>& handles, std::vector<Pose>* T_W_G,
                 embree::RayScene* scene) {
  world.GeomPoses(T_W_G);
  for (size_t i = 0; i < handles.size(); ++i) {
    if (handles[i] >= 0) scene->SetPose(handles[i], (*T_W_G)[i]);
  }
  scene->Commit();
}

Pose LookAt(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W, const Eigen::Vector3d& up_W) {
  const Eigen::Vector3d z = (target_W - eye_W).normalized();
  const Eigen::Vector3d x = z.cross(up_W).normalized();  // right = forward x up
  const Eigen::Vector3d y = z.cross(x);                  // down
  Eigen::Matrix3d R;
  R << x, y, z;
  return MakePose(R, eye_W);
}

}  // namespace

std::string ScanOptions::Problem() const {
  if (const std::string p = pile.Problem(); !p.empty()) return "pile." + p;
  if (const std::string p = approach.Problem(); !p.empty()) return "approach." + p;
  if (const std::string p = ik.Problem(); !p.empty()) return "ik." + p;
  if (const std::string p = rig.Problem(); !p.empty()) return "rig." + p;
  if (samples_per_pixel != 1 && samples_per_pixel != 4) {
    return "samples_per_pixel = " + std::to_string(samples_per_pixel) + ": must be 1 or 4";
  }
  if (threads < 1) return "threads = " + std::to_string(threads) + ": must be >= 1";
  if (color_camera) {
    if (const std::string p = color_camera->Problem(); !p.empty()) return "color_camera." + p;
  }
  return "";
}

std::string ScanStats::BriefReport() const {
  char s[400];
  const double n = std::max(1, frames);
  std::snprintf(s, sizeof s,
                "%d frames over %.2f s simulated; per frame: physics %.1f ms, render %.1f ms, imaging %.1f ms; "
                "tracking max %.2f mm, rms %.2f mm; setup %.2f s",
                frames, simulated_s, 1e3 * physics_s / n, 1e3 * render_s / n, 1e3 * imaging_s / n,
                1e3 * tracking.max_position_error_m, 1e3 * tracking.rms_position_error_m, setup_s);
  return std::string(s) + "; " + settle.BriefReport();
}

namespace {

// The shift (px, depth_engine.h) the chip finds at the camera's centre pixel for a
// fronto-parallel plane at depth_m: the pattern pixel the projector casts there (through
// H_P_rec), then where the chip's reference image holds that pattern pixel.
double CentreShiftPx(const Rig& rig, double depth_m) {
  const ChipGeometry& chip = rig.depth_engine.chip;
  const Eigen::Vector3d p_C(0.0, 0.0, depth_m);  // the centre pixel's ray (cx, cy)
  const Eigen::Vector3d p_P = rig.T_C_P.inverse() * p_C;
  const Eigen::Vector3d q(rig.projector.fx * p_P.x() / p_P.z() + rig.projector.cx,
                          rig.projector.fy * p_P.y() / p_P.z() + rig.projector.cy, 1.0);
  const Eigen::Vector3d x = rig.H_P_rec.inverse() * q;
  const double x_px = x.x() / x.z();
  // Pattern pixel -> the stock camera's pixel on the reference plane (rig.cc, IdealPrewarp).
  const double u_ref = chip.camera.fx / chip.projector.fx * (x_px - chip.projector.cx) + chip.camera.cx +
                       chip.FocalTimesBaseline() / chip.reference_distance_m;
  return rig.camera.cx - u_ref;
}

}  // namespace

DepthRange MeasurableDepthRange(const Rig& rig, double usable_fraction) {
  ROMUNECT_CHECK(usable_fraction > 0 && usable_fraction <= 1);
  // The shift is affine in 1/Z (exactly so with the projector centre on the camera's x axis):
  // s = a + c / Z, from two planes.
  const double z1 = rig.optics.focus_distance_m, z2 = 2.0 * rig.optics.focus_distance_m;
  const double s1 = CentreShiftPx(rig, z1), s2 = CentreShiftPx(rig, z2);
  const double c = (s1 - s2) / (1.0 / z1 - 1.0 / z2), a = s1 - c / z1;
  ROMUNECT_CHECK(std::isfinite(c) && std::abs(c) > 1e-9);
  // The usable part of the search window [min_shift, min_shift + range), about its centre.
  const DepthEngineOptions& e = rig.depth_engine;
  const double centre = e.min_shift_px + 0.5 * (e.search_range_px - 1);
  const double half = 0.5 * usable_fraction * e.search_range_px;
  const double inv_a = (centre - half - a) / c, inv_b = (centre + half - a) / c;
  const double inv_near = std::max(inv_a, inv_b), inv_far = std::min(inv_a, inv_b);
  ROMUNECT_CHECK(inv_near > 0);
  DepthRange range;
  range.near_m = 1.0 / inv_near;
  // A window that reaches zero disparity measures out to infinity: cap it.
  range.far_m = inv_far > 0.1 / rig.optics.focus_distance_m ? 1.0 / inv_far : 10.0 * rig.optics.focus_distance_m;
  return range;
}

struct Scanner::Impl {
  ScanOptions options;
  std::unique_ptr<World> world;
  ApproachPlan plan;
  std::unique_ptr<ApproachExecutor> executor;
  embree::RayScene scene;
  std::vector<int> handles;
  std::vector<Pose> T_W_G;
  embree::GeometryRenderer renderer;
  embree::RenderOptions render_options;
  GeometryBuffer color_geometry;  // ScanOptions::color_camera's, reused frame to frame
  std::unique_ptr<FrameImager> imager;
  ScanStats stats;
  int next = 0;
  int count = 0;
  // Sweep::kCoverage: the descent's frames are measured (by the stage that computes depth), and
  // the frame after the descent waits for them, then plans the coverage leg from the pile's top.
  int descent_frames = 0;
  bool coverage_pending = false;
  std::unique_ptr<PileHeightMeter> meter;
  std::mutex measure_mutex;
  std::condition_variable measured_cv;
  int measured = 0;
  std::optional<double> pile_top_m;

  void Measure(const Frame& frame) {
    if (!coverage_pending || frame.index >= descent_frames) return;
    std::lock_guard<std::mutex> lock(measure_mutex);
    meter->Add(frame, options.rig.camera);
    ++measured;
    measured_cv.notify_all();
  }
  void PlanCoverageLeg();
  // Geometry buffers rendered into and read by SynthesizeIr: in a pipeline a few frames hold one
  // at a time (one per frame between the two stages); reused, not reallocated per frame.
  std::mutex geometry_mutex;
  std::vector<std::shared_ptr<GeometryBuffer>> free_geometry;

  std::shared_ptr<GeometryBuffer> TakeGeometry() {
    std::lock_guard<std::mutex> lock(geometry_mutex);
    if (free_geometry.empty()) return std::make_shared<GeometryBuffer>();
    std::shared_ptr<GeometryBuffer> buffer = std::move(free_geometry.back());
    free_geometry.pop_back();
    return buffer;
  }
  void GiveBack(std::shared_ptr<GeometryBuffer> buffer) {
    std::lock_guard<std::mutex> lock(geometry_mutex);
    free_geometry.push_back(std::move(buffer));
  }
};

Scanner::Scanner(const ScanOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  if (const std::string p = options.Problem(); !p.empty()) throw InputError("scan options", "", p);
  s.options = options;
  const Stopwatch setup;
  double settle_wall_s = 0.0;
  if (!options.saved_scene.empty()) {
    s.world = std::make_unique<World>(LoadSettledScene(options.saved_scene));
    s.stats.settle.converged = true;
    s.stats.settle.loaded_from = options.saved_scene.string();
    s.stats.settle.objects_in_bin = 0;
    for (int i = 0; i < s.world->num_objects(); ++i) s.stats.settle.objects_in_bin += ObjectInBin(*s.world, i);
  } else {
    WorldOptions w;
    w.scene_file = options.scene_file;
    w.objects = MakePileObjects(options.pile);
    w.objects.insert(w.objects.end(), options.extra_objects.begin(), options.extra_objects.end());
    w.T_H_C = options.T_H_C;
    w.T_C_P = options.rig.T_C_P;
    s.world = std::make_unique<World>(w);
    s.stats.settle = DropAndSettle(s.world.get(), options.pile);
    settle_wall_s = s.stats.settle.wall_s;
    if (!s.stats.settle.converged) {
      throw InputError(s.world->options().scene_file.string(), "pile",
                       "the pile did not settle (kinetic energy above " +
                           std::to_string(options.pile.kinetic_energy_threshold_j) +
                           " J): " + s.stats.settle.BriefReport());
    }
  }
  World& world = *s.world;
  world.SetPileFrozen(true);  // scanning is kinematic for the pile
  if (options.levels_from_rig && s.options.approach.focused_far_m == 0) {
    const DepthRange range = MeasurableDepthRange(options.rig);
    s.options.approach.focused_near_m = range.near_m;
    s.options.approach.focused_far_m = range.far_m;
  }
  if (s.options.approach.frame_period_s == 0) s.options.approach.frame_period_s = 1.0 / options.rig.frame_rate_hz;
  s.plan = PlanApproach(world, options.rig.camera, s.options.approach, options.ik);
  s.executor = std::make_unique<ApproachExecutor>(&world, s.plan, s.options.approach);
  s.stats.move_to_start_s = s.executor->MoveToStart();
  s.count = static_cast<int>(std::floor(s.plan.duration_s() * options.rig.frame_rate_hz + 1e-9)) + 1;
  if (s.options.approach.sweep == ApproachOptions::Sweep::kCoverage && s.options.approach.focused_far_m > 0) {
    s.coverage_pending = true;
    s.descent_frames = s.count;
    s.meter = std::make_unique<PileHeightMeter>(world.T_W_Bin(), world.bin_inner_size_m());
  }
  s.scene = MirrorWorld(world, /*with_arm=*/true, &s.handles);
  s.render_options.samples_per_pixel = options.samples_per_pixel;
  s.render_options.threads = options.threads;
  s.render_options.focus_distance_m = options.rig.optics.focus_distance_m;
  s.render_options.aperture_radius_m = options.samples_per_pixel > 1 ? options.rig.optics.aperture_m / 2 : 0.0;
  s.stats.setup_s = setup.seconds() - settle_wall_s;
}

Scanner::~Scanner() = default;

void Scanner::SetImager(std::unique_ptr<FrameImager> imager) { impl_->imager = std::move(imager); }
const CameraModel& Scanner::camera() const { return impl_->options.rig.camera; }
int Scanner::frame_count() const { return impl_->count; }
int Scanner::descent_frames() const { return impl_->descent_frames; }
std::optional<double> Scanner::measured_pile_top_m() const {
  std::lock_guard<std::mutex> lock(impl_->measure_mutex);
  return impl_->pile_top_m;
}
const ScanOptions& Scanner::options() const { return impl_->options; }
const ScanStats& Scanner::stats() const { return impl_->stats; }
const ApproachPlan& Scanner::plan() const { return impl_->plan; }
World& Scanner::world() { return *impl_->world; }
const World& Scanner::world() const { return *impl_->world; }

std::string Scanner::Describe() const {
  const Impl& s = *impl_;
  char text[300];
  std::snprintf(text, sizeof text, "simulated scan of %s: %d objects, %d frames at %.0f Hz, %d x %d passes, rig %s",
                s.world->options().scene_file.string().c_str(), s.world->num_objects(), s.count,
                s.options.rig.frame_rate_hz, s.plan.passes_x, s.plan.passes_y, s.options.rig.name.c_str());
  return text;
}

FrameStatus Scanner::Next(Frame* frame, std::string* error) {
  ROMUNECT_CHECK(frame != nullptr && error != nullptr);
  ScanWork work;
  if (!Render(&work)) return FrameStatus::kEndOfStream;
  SynthesizeIr(&work);
  ComputeDepth(&work);
  *frame = std::move(work.frame);
  return FrameStatus::kOk;
}

void Scanner::Impl::PlanCoverageLeg() {
  {
    // every descent frame measured: the same plan whatever the threads' timing
    std::unique_lock<std::mutex> lock(measure_mutex);
    measured_cv.wait(lock, [this] { return measured >= descent_frames; });
    pile_top_m = meter->TopM();
  }
  const double top = std::max(0.0, pile_top_m.value_or(0.0));
  const ApproachPlan leg = PlanCoverage(*world, options.rig.camera, options.approach, top, plan, options.ik);
  plan.Append(leg);
  // the fusion box follows the measured pile (ScanRegionBox)
  options.approach.surface_height_m = std::max(world->bin_inner_size_m().z(), top) + options.approach.above_rim_m;
  count = static_cast<int>(std::floor(plan.duration_s() * options.rig.frame_rate_hz + 1e-9)) + 1;
  coverage_pending = false;
}

bool Scanner::Render(ScanWork* work) {
  ROMUNECT_CHECK(work != nullptr);
  Impl& s = *impl_;
  if (s.next >= s.count && s.coverage_pending) s.PlanCoverageLeg();
  if (s.next >= s.count) return false;
  const int k = s.next;
  const double t = k / s.options.rig.frame_rate_hz;

  const Stopwatch physics;
  s.executor->AdvanceTo(t);
  s.stats.physics_s += physics.seconds();

  const Stopwatch render;
  World& world = *s.world;
  UpdatePoses(world, s.handles, &s.T_W_G, &s.scene);
  const Pose T_W_C = world.T_W_C();
  Frame& frame = work->frame;
  frame.index = k;
  frame.time_s = t;
  frame.T_W_C = T_W_C;
  frame.T_B_H = world.T_B_H();
  work->seed = s.options.seed * 1000003ULL + k;
  work->replayed = s.imager && !s.options.color_camera && s.imager->Replay(s.options.rig, &frame);
  if (!work->replayed) {
    work->geometry = s.TakeGeometry();
    // The rig is the optics' truth (a saved scene may carry another projector site).
    s.renderer.Render(s.scene, s.options.rig.camera, T_W_C, s.options.rig.T_C_P, s.render_options,
                      work->geometry.get());
    frame.gt_depth_m = embree::GroundTruthDepth(*work->geometry);
  }
  if (const std::optional<ColorCamera>& rgb = s.options.color_camera) {
    embree::RenderOptions pinhole;  // a plain shading: one ray a pixel, no defocus
    pinhole.threads = s.render_options.threads;
    s.renderer.Render(s.scene, rgb->camera, T_W_C * rgb->T_C_RGB, rgb->T_C_RGB.inverse() * s.options.rig.T_C_P, pinhole,
                      &s.color_geometry);
    frame.color = ShadeColorImage(s.color_geometry, s.options.rig.optics.focus_distance_m);
  }
  s.stats.render_s += render.seconds();
  s.stats.tracking = s.executor->tracking();
  s.stats.simulated_s = t;
  ++s.stats.frames;
  ++s.next;

  if (!s.imager) {
    frame.depth_m = frame.gt_depth_m.clone();  // an ideal sensor
    s.GiveBack(std::move(work->geometry));
    s.Measure(frame);
  }
  return true;
}

void Scanner::SynthesizeIr(ScanWork* work) {
  ROMUNECT_CHECK(work != nullptr);
  Impl& s = *impl_;
  if (!s.imager || work->replayed) return;
  ROMUNECT_CHECK_MSG(work->geometry != nullptr, "Scanner::SynthesizeIr without a rendered frame");
  const Stopwatch ir;
  s.imager->SynthesizeIr(s.options.rig, *work->geometry, work->seed, &work->frame);
  work->ir_s = ir.seconds();
  s.GiveBack(std::move(work->geometry));
}

void Scanner::ComputeDepth(ScanWork* work) {
  ROMUNECT_CHECK(work != nullptr);
  Impl& s = *impl_;
  if (!s.imager) return;
  const Stopwatch depth;
  if (!work->replayed) s.imager->ComputeDepth(s.options.rig, &work->frame);
  s.Measure(work->frame);
  // Only this stage writes imaging_s (Render writes the other stats): no two threads share one.
  s.stats.imaging_s += work->ir_s + depth.seconds();
}

void AddScanStages(Scanner* scanner, FramePipeline<ScanWork>* pipeline, int queue_depth) {
  ROMUNECT_CHECK(scanner != nullptr && pipeline != nullptr && queue_depth >= 1);
  pipeline->SetSource({"render"}, [scanner](ScanWork* work) { return scanner->Render(work); });
  pipeline->AddStage({"ir", queue_depth}, [scanner](ScanWork* work) { scanner->SynthesizeIr(work); });
  pipeline->AddStage({"depth", queue_depth}, [scanner](ScanWork* work) { scanner->ComputeDepth(work); });
}

cv::Mat GroundTruthHeightMap(const World& world, const HeightMapGeometry& geometry) {
  ROMUNECT_CHECK(geometry.nx > 0 && geometry.ny > 0 && geometry.voxel_m > 0);
  std::vector<int> handles;
  const embree::RayScene scene = MirrorWorld(world, /*with_arm=*/false, &handles);
  // A camera high above the map's centre looking straight down, one pixel per cell: x_C
  // along W's x, y_C along W's -y (so image row 0 is the largest y; flipped below).
  CameraModel camera;
  camera.width = geometry.nx;
  camera.height = geometry.ny;
  camera.fx = camera.fy = kTruthCameraHeightM / geometry.voxel_m;
  camera.cx = (geometry.nx - 1) / 2.0;
  camera.cy = (geometry.ny - 1) / 2.0;
  const Eigen::Vector3d centre(geometry.min_x_m + geometry.size_x_m() / 2, geometry.min_y_m + geometry.size_y_m() / 2,
                               kTruthCameraHeightM);
  Eigen::Matrix3d R;
  R << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  const Pose T_W_C = MakePose(R, centre);
  embree::GeometryRenderer renderer;
  GeometryBuffer buffer;
  embree::RenderOptions options;
  renderer.Render(scene, camera, T_W_C, Pose::Identity(), options, &buffer);
  cv::Mat height(geometry.ny, geometry.nx, CV_32F);
  const cv::Mat& p_C = buffer.layers[0].p_C;
  for (int v = 0; v < geometry.ny; ++v) {
    for (int u = 0; u < geometry.nx; ++u) {
      const cv::Vec3f p = p_C.at<cv::Vec3f>(v, u);
      height.at<float>(geometry.ny - 1 - v, u) = std::isnan(p[2]) ? std::numeric_limits<float>::quiet_NaN()
                                                                  : static_cast<float>(kTruthCameraHeightM - p[2]);
    }
  }
  return height;
}

cv::Mat OverviewPicture(const World& world, int width_px, int height_px) {
  ROMUNECT_CHECK(width_px > 0 && height_px > 0);
  std::vector<int> handles;
  const embree::RayScene scene = MirrorWorld(world, /*with_arm=*/true, &handles);
  // Frames the whole arm and the bin: aimed between base and bin, 30 cm up, seen from the
  // front right and above.
  const Eigen::Vector3d bin = world.T_W_Bin().translation();
  const Eigen::Vector3d target = 0.5 * (bin + world.T_W_B().translation()) + Eigen::Vector3d(0.05, 0, 0.3);
  const Eigen::Vector3d eye = target + Eigen::Vector3d(0.9, -1.3, 0.55);
  const Pose T_W_C = LookAt(eye, target, Eigen::Vector3d::UnitZ());
  CameraModel camera;
  camera.width = width_px;
  camera.height = height_px;
  camera.fx = camera.fy = 1.0 * width_px;
  camera.cx = (width_px - 1) / 2.0;
  camera.cy = (height_px - 1) / 2.0;
  embree::GeometryRenderer renderer;
  GeometryBuffer buffer;
  embree::RenderOptions options;
  options.threads = 2;
  // Light from above and behind the viewer; shadows from a "projector" there.
  const Eigen::Vector3d light_W = eye + Eigen::Vector3d(0.0, 0.0, 1.0);
  const Pose T_C_L = MakePose(Eigen::Matrix3d::Identity(), T_W_C.inverse() * light_W);
  renderer.Render(scene, camera, T_W_C, T_C_L, options, &buffer);
  const GeometryLayer& layer = buffer.layers[0];
  cv::Mat picture(height_px, width_px, CV_8UC3, cv::Scalar(235, 225, 215));
  for (int v = 0; v < height_px; ++v) {
    for (int u = 0; u < width_px; ++u) {
      const int id = layer.object_id.at<int>(v, u);
      if (id < 0) continue;
      const cv::Vec3f p = layer.p_C.at<cv::Vec3f>(v, u), n = layer.normal_C.at<cv::Vec3f>(v, u);
      const Eigen::Vector3d to_light = (T_C_L.translation() - Eigen::Vector3d(p[0], p[1], p[2])).normalized();
      const double lambert = std::max(0.0, to_light.dot(Eigen::Vector3d(n[0], n[1], n[2])));
      const double shade = 0.35 + 0.65 * lambert * (layer.lit.at<uint8_t>(v, u) ? 1.0 : 0.4);
      const float albedo = buffer.materials[layer.material.at<int>(v, u)].albedo;
      cv::Vec3d bgr;  // colours by kind: arm orange, static parts by albedo (blue-grey), objects warm
      if (id == kArmObjectId) {
        bgr = cv::Vec3d(40, 130, 240) * (0.5 + albedo);
      } else if (id == kStaticObjectId) {
        bgr = cv::Vec3d(200, 170, 150) * (0.3 + albedo);
      } else {
        const double hue = std::fmod(id * 0.61803398875, 1.0);
        bgr = cv::Vec3d(90 + 120 * hue, 200 - 80 * hue, 120 + 100 * (1 - hue)) * (0.4 + albedo);
      }
      for (int c = 0; c < 3; ++c) picture.at<cv::Vec3b>(v, u)[c] = cv::saturate_cast<uint8_t>(bgr[c] * shade);
    }
  }
  return picture;
}

}  // namespace romunect::sim
