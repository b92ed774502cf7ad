#include "romunect/tools/jobs/render.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/sensor/color_camera.h"
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
#include "romunect/tools/jobs/rig_argument.h"
#include "romunect/tools/jobs/run_folder.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

void CheckOptions(const RenderJobOptions& o) {
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
}

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

DepthErrors ErrorsOf(const cv::Mat& measured_m, const cv::Mat& truth_m) {
  std::vector<double> errors;
  for (int v = 0; v < measured_m.rows; ++v) {
    for (int u = 0; u < measured_m.cols; ++u) {
      const float d = measured_m.at<float>(v, u), t = truth_m.at<float>(v, u);
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
}

// The colour camera's image (the stock colour camera beside the rig's depth camera, with C at the
// world origin), shaded for a surface at the target's distance to show at mid grey.
cv::Mat RenderColor(const embree::RayScene& scene, const Rig& rig, int threads, double distance_m,
                    embree::GeometryRenderer* renderer) {
  const ColorCamera color = StockColorCamera();
  embree::RenderOptions options;
  options.threads = threads;
  GeometryBuffer geometry;
  renderer->Render(scene, color.camera, color.T_C_RGB, color.T_C_RGB.inverse() * rig.T_C_P, options, &geometry);
  return ShadeColorImage(geometry, distance_m);
}

// The frame of `mesh` seen by the rig: geometry, IR, the depth engine's output (its chip depth
// in *chip_depth) and metric depth.
Frame RenderFrame(const RenderJobOptions& o, const Rig& rig, const TriangleMesh& mesh, RenderSummary* s,
                  cv::Mat* chip_depth_m) {
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
  s->render_stats =
      renderer.Render(scene, rig.camera, Pose::Identity(), rig.T_C_P, render_options, &geometry).BriefReport();

  IrSynthesisOptions synthesis_options;
  synthesis_options.threads = o.threads;
  IrSynthesizer synthesizer(synthesis_options);
  Frame frame;
  IrSynthesisStats synthesis_stats;
  synthesizer.Synthesize(rig, geometry, o.seed, &frame.ir, &synthesis_stats);
  s->synthesis_stats = synthesis_stats.BriefReport();
  DepthEngineOptions engine_options = rig.depth_engine;
  engine_options.threads = o.threads;
  DepthEngine engine(engine_options);
  DepthEngineOutput depth;
  engine.Compute(frame.ir, &depth);
  s->depth_stats = depth.stats.BriefReport();
  s->valid_fraction = static_cast<double>(depth.stats.valid) / (rig.camera.width * rig.camera.height);

  // A frame directory's depth is metric (docs/frame-directory.md). The chip's own depth is, on
  // the stock device it assumes; on modified hardware (another camera or projector placement)
  // it is off, and the rig's ground-truth correction (a plane sweep, as `romunect scan` uses
  // without a calibration) makes it metric. The chip's depth is reported beside it either way.
  const ChipGeometry& chip_geometry = rig.depth_engine.chip;
  s->stock = rig.camera == chip_geometry.camera && rig.T_C_P.linear().isIdentity(1e-12) &&
             rig.T_C_P.translation().isApprox(Eigen::Vector3d(chip_geometry.baseline_m, 0, 0), 1e-12);
  frame.raw = depth.raw;
  if (s->stock) {
    frame.depth_m = depth.depth_m;
  } else {
    sim::SensorImagerOptions correction_options;
    correction_options.threads = o.threads;
    frame.depth_m = ApplyDepthCorrection(sim::GroundTruthDepthCorrection(rig, correction_options), depth);
  }
  frame.gt_depth_m = embree::GroundTruthDepth(geometry);
  frame.T_W_C = Pose::Identity();
  frame.color = RenderColor(scene, rig, o.threads, s->distance_m, &renderer);
  *chip_depth_m = depth.depth_m;
  return frame;
}

// Pictures for people, and the depth errors against ground truth.
void WritePictures(const Rig& rig, const Frame& frame, const cv::Mat& chip_depth_m, RenderSummary* s) {
  fs::create_directories(s->pictures);
  WritePicture(s->pictures / "ir.png", IrPicture(frame.ir, rig.optics.MaxDn()));
  WritePicture(s->pictures / "depth.png", DepthPicture(frame.depth_m, &s->lo_m, &s->hi_m));
  WritePicture(s->pictures / "gt_depth.png", DepthPicture(frame.gt_depth_m, &s->gt_lo_m, &s->gt_hi_m));
  cv::Mat color_bgr;
  cv::cvtColor(frame.color, color_bgr, cv::COLOR_RGB2BGR);
  WritePicture(s->pictures / "color.png", color_bgr);
  s->metric = ErrorsOf(frame.depth_m, frame.gt_depth_m);
  s->chip = ErrorsOf(chip_depth_m, frame.gt_depth_m);
  std::vector<float> truth;
  for (auto it = frame.gt_depth_m.begin<float>(); it != frame.gt_depth_m.end<float>(); ++it) {
    if (*it > 0.0f) truth.push_back(*it);
  }
  double median_m = s->distance_m;
  if (!truth.empty()) {
    std::nth_element(truth.begin(), truth.begin() + truth.size() / 2, truth.end());
    median_m = truth[truth.size() / 2];
  }
  const double focal_px = rig.camera.fx, baseline_m = rig.T_C_P.translation().norm();
  s->code_step_m = median_m * median_m / (8.0 * focal_px * baseline_m);
  s->error_scale_m = ErrorPictureScaleM(s->metric.p95, median_m, focal_px, baseline_m);
  WritePicture(s->pictures / "error.png", ErrorPicture(frame.depth_m, frame.gt_depth_m, s->error_scale_m));
}

}  // namespace

RenderSummary Render(const RenderJobOptions& o) {
  const Rig rig = LoadRigArgument(o.rig);
  const CameraModel& camera = rig.camera;
  CheckOptions(o);
  // The frame directory is built in OUT_DIR.incomplete and renamed to OUT_DIR when complete; a
  // second run into OUT_DIR is refused here.
  FrameDirectoryWriter::CheckCanWrite(o.out_dir);
  RunFolder run(o.out_dir, "OUT_DIR", "render");
  RenderSummary s;
  s.out_dir = o.out_dir;
  s.pictures = run.work_dir() / "pictures";
  s.rig_name = rig.name;
  s.width = camera.width;
  s.height = camera.height;
  s.what = o.mesh.empty() ? o.target : o.mesh;
  s.distance_m = o.distance_m > 0.0 ? o.distance_m : rig.optics.focus_distance_m;
  const double size_m = o.size_m > 0.0 ? o.size_m : 1.5 * s.distance_m * camera.width / camera.fx;
  const TriangleMesh mesh = o.mesh.empty() ? MakeBuiltinTarget(o.target, s.distance_m, size_m, "--target")
                                           : LoadMesh(o.mesh, o.mesh_unit_m);
  s.triangles = mesh.triangle_count();
  run.Begin();
  FrameDirectoryWriter writer(run.work_dir(), camera);
  writer.SetColorCamera(StockColorCamera());
  cv::Mat chip_depth_m;
  const Frame frame = RenderFrame(o, rig, mesh, &s, &chip_depth_m);
  writer.Add(frame);
  writer.Finish();
  WritePictures(rig, frame, chip_depth_m, &s);
  run.Commit();
  s.pictures = fs::path(o.out_dir) / "pictures";
  return s;
}

double ErrorPictureScaleM(double p95_abs_error_m, double median_true_depth_m, double focal_px, double baseline_m) {
  const double step_m = median_true_depth_m * median_true_depth_m / (8.0 * focal_px * baseline_m);
  // A degenerate geometry (no truth, no baseline) still gets a finite, positive scale: 1 um.
  return std::max({p95_abs_error_m, std::isfinite(step_m) ? step_m : 0.0, 1e-6});
}

std::string RenderSummaryText(const RenderSummary& s) {
  std::string text = Format("rig: %s, camera %d x %d, %s at %.4f m (%zu triangles)\n", s.rig_name.c_str(), s.width,
                            s.height, s.what.c_str(), s.distance_m, s.triangles);
  text += s.render_stats + "\n" + s.synthesis_stats + "\n" + s.depth_stats + "\n";
  text += Format("valid depth: %.1f %% of pixels; reported depth %.4f .. %.4f m; ground truth %.4f .. %.4f m\n",
                 100.0 * s.valid_fraction, s.lo_m, s.hi_m, s.gt_lo_m, s.gt_hi_m);
  text += Format("metric - true depth: median %.3f mm, RMS %.3f mm over %zu pixels (%s)\n", 1e3 * s.metric.median,
                 1e3 * s.metric.rms, s.metric.pixels,
                 s.stock ? "the chip's depth: the rig is the stock device" : "the rig's ground-truth correction");
  text += Format("error.png: full colour at +-%.3f mm (the larger of the 95th percentile of |error|, %.3f mm, and one "
                 "raw code's depth step at the median true depth, %.3f mm); red too far, blue too near\n",
                 1e3 * s.error_scale_m, 1e3 * s.metric.p95, 1e3 * s.code_step_m);
  text += Format("chip depth (uncorrected) - true depth: median %.3f mm, RMS %.3f mm\n", 1e3 * s.chip.median,
                 1e3 * s.chip.rms);
  text += Format("wrote %s (frames.json, ir, raw, depth, gt_depth, color) and %s/{ir,depth,gt_depth,error,color}.png\n",
                 s.out_dir.string().c_str(), s.pictures.string().c_str());
  return text;
}

}  // namespace romunect::jobs
