#include "romunect/sim/scanner.h"

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <exception>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/mesh.h"

namespace romunect::sim {
namespace {

// Object ids in the rendered GeometryLayer: pile objects by index, then these.
constexpr int kStaticObjectId = 1000;
constexpr int kArmObjectId = 2000;
// The ground-truth height map is traced from this high up: rays 30 m long are parallel to
// within 0.12 mm over a 15 cm box for surfaces 5 cm high, and float hits keep 2 um there.
constexpr double kTruthCameraHeightM = 30.0;

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

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

DepthRange MeasurableDepthRange(const Rig& rig, double usable_fraction) {
  ROMUNECT_CHECK(usable_fraction > 0 && usable_fraction <= 1);
  const double fb = rig.camera.fx * std::abs(rig.T_C_P.translation().x());  // px m
  ROMUNECT_CHECK(fb > 0 && rig.optics.focus_distance_m > 0);
  const double half = 0.5 * usable_fraction * rig.depth_engine.search_range_px / fb;  // 1/m
  const double inv_focus = 1.0 / rig.optics.focus_distance_m;
  DepthRange range;
  range.near_m = 1.0 / (inv_focus + half);
  range.far_m = half < inv_focus ? 1.0 / (inv_focus - half) : 10.0 * rig.optics.focus_distance_m;
  return range;
}

// One imaging stage on its own thread, a frame at a time (Scanner::Next): frame k's IR is
// synthesized from its own geometry buffer while frame k + 1 is rendered into the other, and
// frame k - 1's depth is computed meanwhile on a second such thread.
class ImagingThread {
 public:
  ImagingThread() : thread_([this] { Run(); }) {}
  ~ImagingThread() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    thread_.join();
  }
  // Starts job(); the previous one must have been waited for.
  void Start(std::function<void()> job) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      job_ = std::move(job);
      busy_ = true;
    }
    changed_.notify_all();
  }
  // Waits for the started job (if any); rethrows what it threw.
  void Wait() {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [this] { return !busy_; });
    if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
  }

 private:
  void Run() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      changed_.wait(lock, [this] { return stop_ || busy_; });
      if (stop_) return;
      std::function<void()> job = std::move(job_);
      lock.unlock();
      std::exception_ptr failure;
      try {
        job();
      } catch (...) {
        failure = std::current_exception();
      }
      lock.lock();
      failure_ = failure;
      busy_ = false;
      changed_.notify_all();
    }
  }

  std::mutex mutex_;
  std::condition_variable changed_;
  std::function<void()> job_;
  bool busy_ = false, stop_ = false;
  std::exception_ptr failure_;
  std::thread thread_;  // last: starts after the rest is constructed
};

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
  GeometryBuffer geometry[2];  // frame k renders into geometry[k % 2]
  std::unique_ptr<FrameImager> imager;
  ScanStats stats;
  int next = 0;
  int count = 0;
  // With an imager and options.imaging_thread: the frame in IR synthesis (rendered by the last
  // Next()) and the one in the depth engine (rendered by the one before), each on its thread
  // (declared last: joined before what their jobs use goes away). Frames come out of Next() two
  // calls late, the last two after rendering has ended.
  struct Stage {
    std::optional<Frame> frame;
    double seconds = 0.0;  // the job's time, added to stats once waited for
    std::unique_ptr<ImagingThread> thread;
  };
  Stage ir_stage, depth_stage;

  // Waits for a stage's job; a failed frame is dropped, never delivered half-imaged.
  void Wait(Stage* stage) {
    try {
      stage->thread->Wait();
    } catch (...) {
      stage->frame.reset();
      throw;
    }
    stats.imaging_s += stage->seconds;
  }
  // Moves the pipeline on by a frame: the frame in the depth engine is done and returned (if
  // any), the one in IR synthesis moves on to the depth engine.
  std::optional<Frame> Advance() {
    std::optional<Frame> ready;
    if (depth_stage.frame) {
      Wait(&depth_stage);
      ready = std::move(depth_stage.frame);
      depth_stage.frame.reset();
    }
    if (ir_stage.frame) {
      Wait(&ir_stage);
      depth_stage.frame = std::move(ir_stage.frame);
      ir_stage.frame.reset();
      Frame* f = &*depth_stage.frame;
      depth_stage.thread->Start([this, f] {
        const auto depth_start = Clock::now();
        imager->ComputeDepth(options.rig, f);
        depth_stage.seconds = Seconds(depth_start);
      });
    }
    return ready;
  }
};

Scanner::Scanner(const ScanOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  if (const std::string p = options.Problem(); !p.empty()) throw InputError("scan options", "", p);
  s.options = options;
  const auto setup_start = Clock::now();
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
                           std::to_string(options.pile.kinetic_energy_threshold_j) + " J): " +
                           s.stats.settle.BriefReport());
    }
  }
  World& world = *s.world;
  world.SetPileFrozen(true);  // scanning is kinematic for the pile
  if (options.levels_from_rig && s.options.approach.focused_far_m == 0) {
    const DepthRange range = MeasurableDepthRange(options.rig);
    s.options.approach.focused_near_m = range.near_m;
    s.options.approach.focused_far_m = range.far_m;
  }
  s.plan = PlanApproach(world, options.rig.camera, s.options.approach, options.ik);
  s.executor = std::make_unique<ApproachExecutor>(&world, s.plan, s.options.approach);
  s.stats.move_to_start_s = s.executor->MoveToStart();
  s.count = static_cast<int>(std::floor(s.plan.duration_s() * options.rig.frame_rate_hz + 1e-9)) + 1;
  s.scene = MirrorWorld(world, /*with_arm=*/true, &s.handles);
  s.render_options.samples_per_pixel = options.samples_per_pixel;
  s.render_options.threads = options.threads;
  s.render_options.focus_distance_m = options.rig.optics.focus_distance_m;
  s.render_options.aperture_radius_m = options.samples_per_pixel > 1 ? options.rig.optics.aperture_m / 2 : 0.0;
  s.stats.setup_s = Seconds(setup_start) - settle_wall_s;
}

Scanner::~Scanner() = default;

void Scanner::SetImager(std::unique_ptr<FrameImager> imager) {
  ROMUNECT_CHECK_MSG(!impl_->ir_stage.frame && !impl_->depth_stage.frame,
                     "Scanner::SetImager while a frame is being imaged");
  impl_->imager = std::move(imager);
}
const CameraModel& Scanner::camera() const { return impl_->options.rig.camera; }
int Scanner::frame_count() const { return impl_->count; }
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
  Impl& s = *impl_;
  const bool pipelined = s.imager != nullptr && s.options.imaging_thread;
  if (s.next >= s.count) {
    if (!pipelined || (!s.ir_stage.frame && !s.depth_stage.frame)) return FrameStatus::kEndOfStream;
    // Rendering has ended: the stages drain in order.
    std::optional<Frame> ready = s.Advance();
    if (!ready) return Next(frame, error);  // a one-frame scan: its depth is under way
    *frame = std::move(*ready);
    return FrameStatus::kOk;
  }
  const int k = s.next;
  const double t = k / s.options.rig.frame_rate_hz;

  auto start = Clock::now();
  s.executor->AdvanceTo(t);
  s.stats.physics_s += Seconds(start);

  start = Clock::now();
  World& world = *s.world;
  UpdatePoses(world, s.handles, &s.T_W_G, &s.scene);
  const Pose T_W_C = world.T_W_C();
  GeometryBuffer& geometry = s.geometry[k % 2];
  // The rig is the optics' truth (a saved scene may carry another projector site).
  s.renderer.Render(s.scene, s.options.rig.camera, T_W_C, s.options.rig.T_C_P, s.render_options, &geometry);
  Frame rendered;
  rendered.index = k;
  rendered.time_s = t;
  rendered.T_W_C = T_W_C;
  rendered.T_B_H = world.T_B_H();
  rendered.gt_depth_m = embree::GroundTruthDepth(geometry);
  s.stats.render_s += Seconds(start);
  s.stats.tracking = s.executor->tracking();
  s.stats.simulated_s = t;
  ++s.stats.frames;
  ++s.next;

  const uint64_t seed = s.options.seed * 1000003ULL + k;
  if (!s.imager) {
    rendered.depth_m = rendered.gt_depth_m.clone();  // an ideal sensor
    *frame = std::move(rendered);
    return FrameStatus::kOk;
  }
  if (!pipelined) {
    const auto imaging_start = Clock::now();
    s.imager->Image(s.options.rig, geometry, seed, &rendered);
    s.stats.imaging_s += Seconds(imaging_start);
    *frame = std::move(rendered);
    return FrameStatus::kOk;
  }
  // Frame k - 2 goes out, k - 1 moves from IR synthesis to the depth engine, k starts IR
  // synthesis from its geometry buffer (k - 1's IR, which read the other one, has ended).
  if (!s.ir_stage.thread) {
    s.ir_stage.thread = std::make_unique<ImagingThread>();
    s.depth_stage.thread = std::make_unique<ImagingThread>();
  }
  std::optional<Frame> ready = s.Advance();
  s.ir_stage.frame = std::move(rendered);
  Frame* f = &*s.ir_stage.frame;
  s.ir_stage.thread->Start([&s, &geometry, seed, f] {
    const auto ir_start = Clock::now();
    s.imager->SynthesizeIr(s.options.rig, geometry, seed, f);
    s.ir_stage.seconds = Seconds(ir_start);
  });
  if (!ready) return Next(frame, error);  // the first two frames: render the next meanwhile
  *frame = std::move(*ready);
  return FrameStatus::kOk;
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
  const Eigen::Vector3d centre(geometry.min_x_m + geometry.size_x_m() / 2,
                               geometry.min_y_m + geometry.size_y_m() / 2, kTruthCameraHeightM);
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
      height.at<float>(geometry.ny - 1 - v, u) =
          std::isnan(p[2]) ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(kTruthCameraHeightM - p[2]);
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
