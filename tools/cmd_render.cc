// romunect render OUT_DIR: renders a rig (preset or JSON file) looking at a built-in target or a
// mesh file with the Embree renderer, synthesizes the IR image, runs the depth engine, and
// writes a frame directory (IR, raw, metric depth, ground-truth depth) plus pictures.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "commands.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/sensor_imager.h"

namespace romunect::tools {

namespace {
namespace fs = std::filesystem;

struct RenderCommandOptions {
  std::string out_dir;
  std::string rig = "romunect";  // preset name or JSON file
  std::string target = "plane";
  std::string mesh;              // a mesh file instead of a target (vertices in C, metres)
  double mesh_unit_m = 1.0;
  double distance_m = 0.0;       // 0: the camera's focus distance
  double size_m = 0.0;           // 0: 1.5 x the view's width at the distance
  std::string samples = "1";  // 1, 4 (thin lens at every pixel) or adaptive (4 at edges only)
  int threads = 2;
  uint64_t seed = 1;
  double albedo = 0.6;
};

// IR as an 8-bit picture, stretched so that the 99.5th percentile is white (the dots of a
// dim frame stay visible).
cv::Mat IrPicture(const cv::Mat& ir, int max_dn) {
  std::vector<uint16_t> values(ir.begin<uint16_t>(), ir.end<uint16_t>());
  const size_t k = values.size() * 995 / 1000;
  std::nth_element(values.begin(), values.begin() + k, values.end());
  const double white = std::clamp<double>(values[k], 1.0, max_dn);
  cv::Mat picture;
  ir.convertTo(picture, CV_8U, 255.0 / white);
  return picture;
}

// Depth colour-mapped over the valid range (near = red, far = blue); invalid pixels magenta.
cv::Mat DepthPicture(const cv::Mat& depth_m, double* lo, double* hi) {
  const cv::Mat valid = depth_m > 0.0f;
  *lo = 0.0;
  *hi = 0.0;
  if (cv::countNonZero(valid) > 0) cv::minMaxLoc(depth_m, lo, hi, nullptr, nullptr, valid);
  cv::Mat scaled;
  const double span = std::max(*hi - *lo, 1e-9);
  depth_m.convertTo(scaled, CV_8U, -255.0 / span, 255.0 * *hi / span);
  cv::Mat picture;
  cv::applyColorMap(scaled, picture, cv::COLORMAP_TURBO);
  picture.setTo(cv::Scalar(255, 0, 255), ~valid);
  return picture;
}

// Signed error (measured - truth): red too far, blue too near, full colour at +-scale; grey
// where either is missing.
cv::Mat ErrorPicture(const cv::Mat& depth_m, const cv::Mat& truth_m, double scale_m) {
  cv::Mat picture(depth_m.size(), CV_8UC3, cv::Scalar(128, 128, 128));
  for (int v = 0; v < depth_m.rows; ++v) {
    for (int u = 0; u < depth_m.cols; ++u) {
      const float d = depth_m.at<float>(v, u), t = truth_m.at<float>(v, u);
      if (d <= 0.0f || t <= 0.0f) continue;
      const double e = std::clamp((d - t) / scale_m, -1.0, 1.0);
      const auto level = static_cast<uint8_t>(255.0 * (1.0 - std::abs(e)));
      picture.at<cv::Vec3b>(v, u) = e > 0 ? cv::Vec3b(level, level, 255) : cv::Vec3b(255, level, level);
    }
  }
  return picture;
}

void RunRender(const RenderCommandOptions& o) {
  const Rig rig = LoadRigArgument(o.rig);
  const CameraModel& camera = rig.camera;
  if (o.samples != "1" && o.samples != "4" && o.samples != "adaptive") {
    throw InputError("--samples", o.samples, "must be 1, 4 or adaptive");
  }
  if (o.threads < 1 || o.threads > 64) {
    throw InputError("--threads", std::to_string(o.threads), "must be in [1, 64]");
  }
  if (!(o.albedo >= 0.0 && o.albedo <= 1.0)) {
    throw InputError("--albedo", std::to_string(o.albedo), "must be in [0, 1]");
  }
  // 0 means the default; anything else must be a size the float meshes can hold.
  for (const auto& [value, option] : {std::pair{o.distance_m, "--distance"}, std::pair{o.size_m, "--size"}}) {
    if (value != 0.0 && !(value > 0.0 && value <= 1000.0)) {
      throw InputError(option, std::to_string(value), "must be in (0, 1000] metres");
    }
  }
  const double distance_m = o.distance_m > 0.0 ? o.distance_m : rig.optics.focus_distance_m;
  const double size_m =
      o.size_m > 0.0 ? o.size_m : 1.5 * distance_m * camera.width / camera.fx;
  const TriangleMesh mesh = o.mesh.empty()
                                ? MakeBuiltinTarget(o.target, distance_m, size_m, "--target")
                                : LoadMesh(o.mesh, o.mesh_unit_m);

  // The frame directory refuses an existing frames.json before anything is rendered.
  FrameDirectoryWriter writer(o.out_dir, camera);

  embree::RaySceneOptions scene_options;
  scene_options.build_threads = o.threads;
  embree::RayScene scene(scene_options);
  scene.AddStatic(mesh, Pose::Identity(), IrMaterial{static_cast<float>(o.albedo), 0.0f, 50.0f}, 1);
  scene.Commit();
  embree::RenderOptions render_options;
  render_options.samples_per_pixel = o.samples == "1" ? 1 : 4;
  render_options.adaptive = o.samples == "adaptive";
  render_options.threads = o.threads;
  render_options.focus_distance_m = rig.optics.focus_distance_m;
  render_options.aperture_radius_m = 0.5 * rig.optics.aperture_m;
  embree::GeometryRenderer renderer;
  GeometryBuffer geometry;
  const embree::RenderStats render_stats =
      renderer.Render(scene, camera, Pose::Identity(), rig.T_C_P, render_options, &geometry);

  IrSynthesisOptions synthesis_options;
  synthesis_options.threads = o.threads;
  IrSynthesizer synthesizer(synthesis_options);
  Frame frame;
  IrSynthesisStats synthesis_stats;
  synthesizer.Synthesize(rig, geometry, o.seed, &frame.ir, &synthesis_stats);
  DepthEngineOptions engine_options = rig.depth_engine;
  engine_options.threads = o.threads;
  DepthEngine engine(engine_options);
  DepthEngineOutput depth;
  engine.Compute(frame.ir, &depth);

  // A frame directory's depth is metric (docs/frame-directory.md). The chip's own depth is, on
  // the stock device it assumes; on modified hardware (another camera or projector placement)
  // it is off, and the rig's ground-truth correction (a plane sweep, as `romunect scan` uses
  // without a calibration) makes it metric. The chip's depth is reported beside it either way.
  const ChipGeometry& chip_geometry = rig.depth_engine.chip;
  const bool stock = rig.camera == chip_geometry.camera && rig.T_C_P.linear().isIdentity(1e-12) &&
                     rig.T_C_P.translation().isApprox(Eigen::Vector3d(chip_geometry.baseline_m, 0, 0), 1e-12);
  frame.raw = depth.raw;
  if (stock) {
    frame.depth_m = depth.depth_m;
  } else {
    sim::SensorImagerOptions correction_options;
    correction_options.threads = o.threads;
    frame.depth_m = ApplyDepthCorrection(sim::GroundTruthDepthCorrection(rig, correction_options), depth);
  }
  frame.gt_depth_m = embree::GroundTruthDepth(geometry);
  frame.T_W_C = Pose::Identity();
  writer.Add(frame);
  writer.Finish();

  // Pictures for people.
  const fs::path pictures = fs::path(o.out_dir) / "pictures";
  fs::create_directories(pictures);
  WritePicture(pictures / "ir.png", IrPicture(frame.ir, rig.optics.MaxDn()));
  double lo = 0.0, hi = 0.0;
  WritePicture(pictures / "depth.png", DepthPicture(frame.depth_m, &lo, &hi));
  double gt_lo = 0.0, gt_hi = 0.0;
  WritePicture(pictures / "gt_depth.png", DepthPicture(frame.gt_depth_m, &gt_lo, &gt_hi));
  // Measured minus true depth where both exist: median, RMS, 95th percentile of |error|, count.
  struct DepthErrors {
    double median = 0.0, rms = 0.0, p95 = 0.0;
    size_t pixels = 0;
  };
  auto errors_of = [&](const cv::Mat& measured_m) {
    std::vector<double> errors;
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) {
        const float d = measured_m.at<float>(v, u), t = frame.gt_depth_m.at<float>(v, u);
        if (d > 0.0f && t > 0.0f) errors.push_back(static_cast<double>(d) - t);
      }
    }
    DepthErrors e;
    e.pixels = errors.size();
    if (errors.empty()) return e;
    for (double x : errors) e.rms += x * x;
    e.rms = std::sqrt(e.rms / errors.size());
    std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
    e.median = errors[errors.size() / 2];
    for (double& x : errors) x = std::abs(x);
    const size_t k = errors.size() * 95 / 100;
    std::nth_element(errors.begin(), errors.begin() + k, errors.end());
    e.p95 = errors[k];
    return e;
  };
  const DepthErrors metric = errors_of(frame.depth_m), chip = errors_of(depth.depth_m);
  // Full colour at the 95th percentile of |error|: outliers at edges do not wash it out.
  const double scale_m = std::max(metric.p95, 1e-5);
  WritePicture(pictures / "error.png", ErrorPicture(frame.depth_m, frame.gt_depth_m, scale_m));

  std::printf("rig: %s, camera %d x %d, %s at %.4f m (%zu triangles)\n", rig.name.c_str(),
              camera.width, camera.height, o.mesh.empty() ? o.target.c_str() : o.mesh.c_str(),
              distance_m, mesh.triangle_count());
  std::printf("%s\n", render_stats.BriefReport().c_str());
  std::printf("%s\n", synthesis_stats.BriefReport().c_str());
  std::printf("%s\n", depth.stats.BriefReport().c_str());
  std::printf("valid depth: %.1f %% of pixels; reported depth %.4f .. %.4f m; ground truth %.4f .. %.4f m\n",
              100.0 * depth.stats.valid / (camera.width * camera.height), lo, hi, gt_lo, gt_hi);
  std::printf("metric - true depth: median %.3f mm, RMS %.3f mm over %zu pixels (%s; error.png scale +-%.3f mm)\n",
              1e3 * metric.median, 1e3 * metric.rms, metric.pixels,
              stock ? "the chip's depth: the rig is the stock device" : "the rig's ground-truth correction",
              1e3 * scale_m);
  std::printf("chip depth (uncorrected) - true depth: median %.3f mm, RMS %.3f mm\n", 1e3 * chip.median,
              1e3 * chip.rms);
  std::printf("wrote %s (frames.json, ir, raw, depth, gt_depth) and %s/{ir,depth,gt_depth,error}.png\n",
              o.out_dir.c_str(), pictures.string().c_str());
}

}  // namespace

void AddRenderCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "render", "Render a rig looking at a built-in target or a mesh into a frame directory");
  auto o = std::make_shared<RenderCommandOptions>();
  cmd->add_option("OUT_DIR", o->out_dir, "Output frame directory (must not hold frames.json)")
      ->required();
  cmd->add_option("--rig", o->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")
      ->capture_default_str();
  std::string targets;
  for (const auto& n : BuiltinTargetNames()) targets += (targets.empty() ? "" : ", ") + n;
  cmd->add_option("--target", o->target, "Built-in target: " + targets)->capture_default_str();
  cmd->add_option("--mesh", o->mesh, "Mesh file (.stl, .obj) in camera coordinates, instead of a target");
  cmd->add_option("--mesh-unit", o->mesh_unit_m, "Metres per mesh file unit (0.001 for mm)")
      ->capture_default_str();
  cmd->add_option("--distance", o->distance_m, "Target distance in m (default: camera focus distance)");
  cmd->add_option("--size", o->size_m, "Target size in m (default: 1.5 x the view width)");
  cmd->add_option("--samples", o->samples, "Samples per pixel: 1, 4 (thin lens), or adaptive (4 only where depth or defocus changes within the pixel)")->capture_default_str();
  cmd->add_option("--threads", o->threads, "Threads")->capture_default_str();
  cmd->add_option("--seed", o->seed, "Noise seed")->capture_default_str();
  cmd->add_option("--albedo", o->albedo, "Target albedo in [0, 1]")->capture_default_str();
  cmd->callback([o] { RunRender(*o); });
}

}  // namespace romunect::tools
