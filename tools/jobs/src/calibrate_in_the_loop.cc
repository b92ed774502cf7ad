#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/calib/chain.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sim/calibration_rig.h"
#include "romunect/sim/scanner.h"
#include "romunect/tools/jobs/calibrate.h"
#include "romunect/tools/jobs/output_folder.h"
#include "romunect/tools/jobs/rig_argument.h"
#include "romunect/tools/jobs/run_folder.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using namespace romunect::calib;
using nlohmann::json;
constexpr double kDeg = M_PI / 180.0;

// The goals of the calibration chain, measured against ground truth: the paper's, for the
// romunect at its 0.2 m working distance.
constexpr double kGoalMappingPx = 0.25;
constexpr double kGoalHandEyeDeg = 0.02;
constexpr double kGoalHandEyeMm = 0.15;
constexpr double kGoalHomographyPx = 0.1;
constexpr int kGoalHomographyCaptures = 5;
constexpr double kGoalDepthMm = 0.1;
constexpr double kGoalComputeS = 2.0;
constexpr double kRomunectWorkingM = 0.2;

// The goals a rig is judged against. A long-range rig (calibrated further out,
// CalibrationRigOptions::working_distance_m, as the stock Kinect) keeps the goals in pixels and
// degrees; its hand-eye translation goal grows with the distance (an angle's lever), and its depth
// goal is the stock sensor's own floor there, as the fidelity tests measure it: Nguyen et al.'s
// axial noise 1.2 + 1.9 (z - 0.4)^2 mm and the 11-bit raw's step 3.1 mm (z / 1 m)^2, in
// quadrature (the step as a uniform error, / sqrt 12), with 25 % for the planes' uneven sampling
// of the steps. No calibration beats the noise it measures through.
struct Goals {
  double mapping_px = kGoalMappingPx, hand_eye_deg = kGoalHandEyeDeg, hand_eye_mm = kGoalHandEyeMm;
  double homography_px = kGoalHomographyPx;
  int homography_captures = kGoalHomographyCaptures;
  double depth_mm = kGoalDepthMm, compute_s = kGoalComputeS;
  std::string basis = "the paper's goals (the romunect at 0.2 m)";
};

Goals GoalsFor(const sim::CalibrationRigOptions& rig_options) {
  Goals g;
  if (!(rig_options.working_distance_m > 0.0)) return g;
  const double z_m = rig_options.working_distance_m;
  const double noise_mm = 1.2 + 1.9 * (z_m - 0.4) * (z_m - 0.4);
  const double step_mm = 3.1 * z_m * z_m;
  g.hand_eye_mm = kGoalHandEyeMm * z_m / kRomunectWorkingM;
  g.depth_mm = 1.25 * std::hypot(noise_mm, step_mm / std::sqrt(12.0));
  g.basis = Format("a long-range sensor's goals at its %.2f m working distance (depth: the stock sensor's own "
                   "noise and quantization there)",
                   z_m);
  return g;
}

// Per-pixel RMS map (metres, NaN = unfitted) as a picture: 0 .. top_mm in the jet colours,
// unfitted grey, with a scale bar.
cv::Mat ResidualPicture(const cv::Mat& rms_m, double top_mm) {
  cv::Mat scaled(rms_m.size(), CV_8U), picture;
  cv::Mat unfitted(rms_m.size(), CV_8U, cv::Scalar(0));
  for (int y = 0; y < rms_m.rows; ++y) {
    for (int x = 0; x < rms_m.cols; ++x) {
      const float v = rms_m.at<float>(y, x);
      unfitted.at<uint8_t>(y, x) = std::isfinite(v) ? 0 : 255;
      scaled.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(std::isfinite(v) ? 255.0 * 1e3 * v / top_mm : 0.0);
    }
  }
  cv::applyColorMap(scaled, picture, cv::COLORMAP_JET);
  picture.setTo(cv::Scalar(128, 128, 128), unfitted);
  cv::Mat out(picture.rows + 40, picture.cols, CV_8UC3, cv::Scalar(255, 255, 255));
  picture.copyTo(out(cv::Rect(0, 0, picture.cols, picture.rows)));
  cv::Mat bar(1, 256, CV_8U);
  for (int i = 0; i < 256; ++i) bar.at<uint8_t>(0, i) = static_cast<uint8_t>(i);
  cv::Mat bar_colour;
  cv::applyColorMap(bar, bar_colour, cv::COLORMAP_JET);
  cv::resize(bar_colour, bar_colour, cv::Size(256, 12), 0, 0, cv::INTER_NEAREST);
  bar_colour.copyTo(out(cv::Rect(60, picture.rows + 6, 256, 12)));
  const std::string text = Format("0          per-pixel RMS after correction        %.2f mm (grey: unfitted)", top_mm);
  cv::putText(out, text, cv::Point(4, picture.rows + 34), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1);
  return out;
}

// Bars of the per-view reprojection RMS (px), with the overall RMS as a line.
cv::Mat ReprojectionPicture(const std::vector<double>& per_view_px, double rms_px) {
  const int w = 640, h = 320, left = 50, bottom = 40, top = 20;
  cv::Mat out(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
  double max_px = rms_px;
  for (double v : per_view_px) max_px = std::max(max_px, v);
  max_px = std::max(1e-3, 1.2 * max_px);
  const int n = std::max<int>(1, static_cast<int>(per_view_px.size()));
  const double bar_w = static_cast<double>(w - left - 10) / n;
  auto y_of = [&](double v) { return static_cast<int>(h - bottom - (h - bottom - top) * v / max_px); };
  for (int i = 0; i < static_cast<int>(per_view_px.size()); ++i) {
    const int x0 = left + static_cast<int>(i * bar_w + 0.15 * bar_w),
              x1 = left + static_cast<int>((i + 1) * bar_w - 0.15 * bar_w);
    cv::rectangle(out, cv::Point(x0, y_of(per_view_px[i])), cv::Point(x1, h - bottom), cv::Scalar(180, 110, 40),
                  cv::FILLED);
    cv::putText(out, std::to_string(i), cv::Point(x0, h - bottom + 14), cv::FONT_HERSHEY_SIMPLEX, 0.35,
                cv::Scalar(0, 0, 0), 1);
  }
  cv::line(out, cv::Point(left, y_of(rms_px)), cv::Point(w - 10, y_of(rms_px)), cv::Scalar(0, 0, 200), 1);
  cv::line(out, cv::Point(left, top), cv::Point(left, h - bottom), cv::Scalar(0, 0, 0), 1);
  cv::line(out, cv::Point(left, h - bottom), cv::Point(w - 10, h - bottom), cv::Scalar(0, 0, 0), 1);
  cv::putText(out, Format("%.3f px", max_px / 1.2), cv::Point(2, y_of(max_px / 1.2) + 4), cv::FONT_HERSHEY_SIMPLEX, 0.3,
              cv::Scalar(0, 0, 0), 1);
  cv::putText(out, Format("reprojection RMS per view (px); red: all views %.3f px", rms_px), cv::Point(left, h - 8),
              cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1);
  return out;
}

std::string Yes(bool met) { return met ? "met" : "NOT met"; }

// The existing-file rules first, so a long run does not end in a refusal.
void CheckExistingFile(const fs::path& file, bool overwrite_worse) {
  if (!fs::exists(file) || overwrite_worse) return;
  try {
    LoadCalibration(file);
  } catch (const InputError&) {
    throw InputError(file.string(), "", "exists and does not load; give --overwrite-worse to replace it");
  }
}

// The chain's findings against ground truth, and which goals they meet.
struct Measured {
  ChainResult r;
  sim::ChainTruthErrors truth;
  CameraModel truth_camera;  // the rig's (report only)
  Pose truth_T_H_C, truth_T_B_K;
  double wall_s = 0.0, compute_s = 0.0;
  double homography_px = 0.0, depth_mm = -1.0, affine_mm = -1.0;
  Goals goals;
  bool met_mapping = false, met_hand_eye = false, met_homography = false, met_depth = false, met_compute = false;
};

void JudgeGoals(Measured* m) {
  const ChainResult& r = m->r;
  const sim::ChainTruthErrors& truth = m->truth;
  m->homography_px = truth.homography_px;
  m->depth_mm = truth.depth_rms_m >= 0 ? 1e3 * truth.depth_rms_m : -1.0;
  m->affine_mm = truth.depth_affine_rms_m >= 0 ? 1e3 * truth.depth_affine_rms_m : -1.0;
  m->compute_s = r.times.ComputeS();
  m->met_mapping = truth.mapping.rms_px <= m->goals.mapping_px;
  // the goal's condition is "intrinsics known": the step re-run with the true camera
  const PoseError& known = truth.hand_eye_known_intrinsics;
  m->met_hand_eye = known.angle_rad / kDeg <= m->goals.hand_eye_deg &&
                    1e3 * known.translation_m <= m->goals.hand_eye_mm;
  m->met_homography = m->homography_px >= 0 && m->homography_px <= m->goals.homography_px &&
                      r.homography.captures <= m->goals.homography_captures;
  m->met_depth = m->depth_mm >= 0 && m->depth_mm <= m->goals.depth_mm;
  m->met_compute = m->compute_s < m->goals.compute_s;
}

json IntrinsicsJson(const Measured& m) {
  const ChainResult& r = m.r;
  json views = json::array();
  for (size_t i = 0; i < r.view_names.size(); ++i) {
    views.push_back({{"name", r.view_names[i]}, {"rms_px", r.intrinsics.per_view_rms_px[i]}});
  }
  json rejected = json::array();
  for (const auto& [name, why] : r.rejected) rejected.push_back({{"name", name}, {"reason", why}});
  const CameraModel& c = r.calibration.camera;
  return {{"views_used", r.view_names.size()},
          {"rejected", rejected},
          {"rms_px", r.intrinsics.rms_px},
          {"holdout_rms_px", r.intrinsics.holdout_rms_px},
          {"views", views},
          {"coverage_cell_fraction", r.intrinsics.coverage.cell_fraction},
          {"truth_mapping_rms_px", m.truth.mapping.rms_px},
          {"truth_mapping_max_px", m.truth.mapping.max_px},
          {"truth_mapping_uncompensated_rms_px", m.truth.mapping_uncompensated.rms_px},
          {"truth_mapping_zhang_rms_px", m.truth.mapping_zhang.rms_px},
          {"camera", {{"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx}, {"cy", c.cy}, {"distortion", c.distortion}}},
          {"compute_s", r.times.intrinsics_s}};
}

json HomographyJson(const Measured& m) {
  const ChainResult& r = m.r;
  return {{"captures", r.homography.captures},
          {"converged", r.homography.converged},
          {"observed_rms_px", r.homography.observed_rms_px},
          {"predicted_rms_px", r.homography.predicted_rms_px},
          {"truth_residual_px", m.homography_px},
          {"points", m.truth.homography_points},
          {"depth_engine_valid_fraction",
           {{"unwarped", r.raw_valid_fraction_unwarped},
            {"nominal_prewarp", r.raw_valid_fraction_initial},
            {"calibrated", r.raw_valid_fraction_final}}},
          {"compute_s", r.times.homography_s}};
}

json HandEyeJson(const Measured& m) {
  const ChainResult& r = m.r;
  const sim::ChainTruthErrors& t = m.truth;
  return {{"stations", r.stations_used},
          {"initial_method", r.hand_eye.initial_method},
          {"rms_px", r.hand_eye.rms_px},
          {"truth_rotation_deg", t.hand_eye.angle_rad / kDeg},
          {"truth_translation_mm", 1e3 * t.hand_eye.translation_m},
          {"truth_known_intrinsics_rotation_deg", t.hand_eye_known_intrinsics.angle_rad / kDeg},
          {"truth_known_intrinsics_translation_mm", 1e3 * t.hand_eye_known_intrinsics.translation_m},
          {"truth_line_of_sight_rms_deg", t.line_of_sight_rms_rad / kDeg},
          {"truth_line_of_sight_max_deg", t.line_of_sight_max_rad / kDeg},
          {"truth_initial_rotation_deg", t.hand_eye_initial.angle_rad / kDeg},
          {"truth_initial_translation_mm", 1e3 * t.hand_eye_initial.translation_m},
          {"truth_board_rotation_deg", t.board.angle_rad / kDeg},
          {"truth_board_translation_mm", 1e3 * t.board.translation_m},
          {"compute_s", r.times.hand_eye_s}};
}

json DepthJson(const Measured& m) {
  const ChainResult& r = m.r;
  const sim::ChainTruthErrors& t = m.truth;
  json planes = json::array();
  for (size_t i = 0; i < t.depth_exact.size(); ++i) {
    const sim::PlaneDepthError& e = t.depth_exact[i];
    planes.push_back({{"distance_m", e.distance_m},
                      {"tilt_rad", e.tilt_rad},
                      {"exact_rms_mm", 1e3 * e.rms_m},
                      {"exact_mean_mm", 1e3 * e.mean_m},
                      {"affine_rms_mm", 1e3 * t.depth_affine[i].rms_m},
                      {"valid_fraction", e.valid_fraction}});
  }
  return {{"planes", r.planes_used},
          {"model", "inverse_affine_in_raw"},
          {"fit_exact_rms_mm", 1e3 * r.depth.inverse_rms_m},
          {"fit_affine_rms_mm", 1e3 * r.depth.affine_rms_m},
          {"fitted_pixels", r.depth.fitted_pixels},
          {"truth_planes", planes},
          {"truth_rms_mm", m.depth_mm},
          {"truth_affine_rms_mm", m.affine_mm},
          {"compute_s", r.times.depth_s}};
}

json GoalsJson(const Measured& m) {
  const PoseError& known = m.truth.hand_eye_known_intrinsics;
  const PoseError& end_to_end = m.truth.hand_eye;
  return {{"basis", m.goals.basis},
          {"intrinsics_mapping_px",
           {{"goal", m.goals.mapping_px}, {"value", m.truth.mapping.rms_px}, {"met", m.met_mapping}}},
          {"hand_eye",
           {{"goal_deg", m.goals.hand_eye_deg},
            {"goal_mm", m.goals.hand_eye_mm},
            {"condition", "intrinsics known (true camera, the chain's stations)"},
            {"deg", known.angle_rad / kDeg},
            {"mm", 1e3 * known.translation_m},
            {"end_to_end_deg", end_to_end.angle_rad / kDeg},
            {"end_to_end_mm", 1e3 * end_to_end.translation_m},
            {"end_to_end_line_of_sight_rms_deg", m.truth.line_of_sight_rms_rad / kDeg},
            {"met", m.met_hand_eye}}},
          {"homography_px",
           {{"goal", m.goals.homography_px},
            {"value", m.homography_px},
            {"captures", m.r.homography.captures},
            {"met", m.met_homography}}},
          {"depth_rms_mm", {{"goal", m.goals.depth_mm}, {"value", m.depth_mm}, {"met", m.met_depth}}},
          {"compute_s", {{"goal", m.goals.compute_s}, {"value", m.compute_s}, {"met", m.met_compute}}}};
}

json ValuesJson(const Measured& m) {
  const auto camera = [](const CameraModel& c) {
    return json{{"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx}, {"cy", c.cy}, {"distortion", c.distortion}};
  };
  const auto pose = [](const Pose& T) { return PoseToRowMajor(T); };
  return {{"camera", {{"estimate", camera(m.r.calibration.camera)}, {"truth", camera(m.truth_camera)}}},
          {"T_H_C", {{"estimate", pose(m.r.calibration.T_H_C)}, {"truth", pose(m.truth_T_H_C)}}},
          {"T_B_K", {{"estimate", pose(m.r.calibration.T_B_K)}, {"truth", pose(m.truth_T_B_K)}}}};
}

std::string ReportJson(const Measured& m, const std::string& rig_name, unsigned seed) {
  const json report = {{"rig", rig_name},
                       {"seed", seed},
                       {"calibration_file", "calibration.yaml"},
                       {"values", ValuesJson(m)},
                       {"intrinsics", IntrinsicsJson(m)},
                       {"homography", HomographyJson(m)},
                       {"hand_eye", HandEyeJson(m)},
                       {"depth", DepthJson(m)},
                       {"times",
                        {{"compute_s", m.compute_s}, {"hardware_s", m.r.times.hardware_s}, {"wall_s", m.wall_s}}},
                       {"goals", GoalsJson(m)}};
  return report.dump(2) + "\n";
}

// Markdown: each goal, its value against ground truth, met or not.
std::string GoalsTable(const Measured& m) {
  const ChainResult& r = m.r;
  const sim::ChainTruthErrors& t = m.truth;
  const PoseError& known = t.hand_eye_known_intrinsics;
  std::string table = "Goals: " + m.goals.basis +
                      ".\n\n| step | goal | measured against truth | |\n| --- | --- | --- | --- |\n";
  table += Format("| intrinsics, %zu views, full-image mapping error | <= %.2f px "
                  "| %.3f px (max %.3f; Zhang alone %.3f) | %s |\n",
                  r.view_names.size(), m.goals.mapping_px, t.mapping.rms_px, t.mapping.max_px, t.mapping_zhang.rms_px,
                  Yes(m.met_mapping).c_str());
  table += Format("| hand-eye, %d stations, intrinsics known (the step on the same captures with the true camera) "
                  "| <= %.2f deg, <= %.2f mm | %.4f deg, %.3f mm | %s |\n",
                  r.stations_used, m.goals.hand_eye_deg, m.goals.hand_eye_mm, known.angle_rad / kDeg,
                  1e3 * known.translation_m, Yes(m.met_hand_eye).c_str());
  table += Format("| hand-eye end to end (estimated intrinsics): T_H_C alone | | %.4f deg, %.3f mm | |\n",
                  t.hand_eye.angle_rad / kDeg, 1e3 * t.hand_eye.translation_m);
  table += Format("| hand-eye end to end: lines of sight in H (T_H_C with its camera) | <= %.2f deg "
                  "| %.4f deg RMS (max %.4f) | %s |\n",
                  m.goals.hand_eye_deg, t.line_of_sight_rms_rad / kDeg, t.line_of_sight_max_rad / kDeg,
                  Yes(t.line_of_sight_max_rad / kDeg <= m.goals.hand_eye_deg).c_str());
  table += Format("| projector homography residual | <= %.2f px within %d captures | %.3f px, %d captures | %s |\n",
                  m.goals.homography_px, m.goals.homography_captures, m.homography_px, r.homography.captures,
                  Yes(m.met_homography).c_str());
  table += Format("| metric depth after correction (exact model), planes in focus | <= %.2f mm RMS "
                  "| %.4f mm (paper's affine: %.3f mm) | %s |\n",
                  m.goals.depth_mm, m.depth_mm, m.affine_mm, Yes(m.met_depth).c_str());
  table += Format("| whole chain, compute only | < %.1f s | %.2f s | %s |\n\n", m.goals.compute_s, m.compute_s,
                  Yes(m.met_compute).c_str());
  return table;
}

// The file's final values (the camera after the hand-eye refinement) beside the rig's truth.
std::string ValuesTable(const Measured& m) {
  const CameraModel& c = m.r.calibration.camera;
  const CameraModel& t = m.truth_camera;
  std::string table = "## Values: calibration.yaml against the truth\n\n| quantity | calibration.yaml | truth | "
                      "error |\n| --- | --- | --- | --- |\n";
  const auto row = [&](const char* name, double estimate, double truth, const char* unit) {
    table += Format("| %s | %.4f %s | %.4f %s | %+.4f %s |\n", name, estimate, unit, truth, unit, estimate - truth,
                    unit);
  };
  row("fx", c.fx, t.fx, "px");
  row("fy", c.fy, t.fy, "px");
  row("cx", c.cx, t.cx, "px");
  row("cy", c.cy, t.cy, "px");
  const char* distortion[] = {"k1", "k2", "p1", "p2", "k3"};  // OpenCV's order
  for (int i = 0; i < 5; ++i) row(distortion[i], c.distortion[i], t.distortion[i], "");
  const char* hand_eye[] = {"T_H_C x", "T_H_C y", "T_H_C z"};
  const char* board[] = {"T_B_K x", "T_B_K y", "T_B_K z"};
  for (int i = 0; i < 3; ++i) {
    row(hand_eye[i], 1e3 * m.r.calibration.T_H_C.translation()[i], 1e3 * m.truth_T_H_C.translation()[i], "mm");
  }
  for (int i = 0; i < 3; ++i) {
    row(board[i], 1e3 * m.r.calibration.T_B_K.translation()[i], 1e3 * m.truth_T_B_K.translation()[i], "mm");
  }
  table += Format("| T_H_C rotation | | | %.4f deg |\n| T_B_K rotation | | | %.4f deg |\n\n",
                  m.truth.hand_eye.angle_rad / kDeg, m.truth.board.angle_rad / kDeg);
  return table;
}

std::string ReportMarkdown(const Measured& m, const std::string& table, const std::string& rig_name, unsigned seed) {
  const ChainResult& r = m.r;
  std::string md = "# Calibration in the loop: simulated rig '" + rig_name + "', seed " + std::to_string(seed) +
                   "\n\nThe chain planned with nominal values and calibrated from "
                   "executed robot poses and rendered images; ground truth was used only for this report.\n\n";
  md += table;
  md += "The hand-eye goal is for known intrinsics: the step re-run on the chain's own stations with the rig's "
        "true camera (report only). The chain's T_H_C goes with its estimated camera: a principal point d px off "
        "turns T_H_C by about d / f, while the lines of sight in H (what scanning uses) stay right; the 0.02 deg "
        "applied to them is this report's own check; the goal itself is stated for known intrinsics.\n\n";
  md += Format("Compute per step: intrinsics %.3f s, homography %.3f s, hand-eye %.3f s, depth %.3f s; "
               "simulated hardware (moves, rendering, imaging) %.1f s.\n\n",
               r.times.intrinsics_s, r.times.homography_s, r.times.hand_eye_s, r.times.depth_s, r.times.hardware_s);
  md += ValuesTable(m);
  md += "- Zhang's step, before the hand-eye refinement: " + r.intrinsics.BriefReport() + "\n- " +
        r.homography.BriefReport() + "\n- " + r.hand_eye.BriefReport() + "\n- " + r.depth.BriefReport() + "\n";
  md += Format("- depth engine matches on the reference area: %.1f %% unwarped, %.1f %% with the nominal pre-warp, "
               "%.1f %% with the calibrated H_P_rec\n",
               100 * r.raw_valid_fraction_unwarped, 100 * r.raw_valid_fraction_initial,
               100 * r.raw_valid_fraction_final);
  for (const auto& [name, why] : r.rejected) md += "- rejected " + name + ": " + why + "\n";
  md += "\n## Reprojection errors per view\n\n![reprojection errors](reprojection_errors.png)\n\n"
        "## Per-pixel depth residual (exact model, fit)\n\n![depth residual](depth_residual.png)\n";
  return md;
}

// The views' largest tilt for a rig calibrated far out (CalibrationRigOptions::working_distance_m).
constexpr double kLongRangeMaxTiltRad = 0.35;

// The hardware with every lamp-lit board view and every raw capture kept with the hand pose it
// was taken at, for --save-captures: the chain's motion as the single steps' input.
class RecordingHardware : public calib::CalibrationHardware {
 public:
  explicit RecordingHardware(calib::CalibrationHardware* inner) : inner_(inner) {}
  const calib::CalibrationSetup& setup() const override { return inner_->setup(); }
  std::optional<Pose> MoveHand(const Pose& T_B_H) override {
    const std::optional<Pose> executed = inner_->MoveHand(T_B_H);
    if (executed) T_B_H_ = *executed;
    return executed;
  }
  cv::Mat CaptureLampIr() override {
    cv::Mat ir = inner_->CaptureLampIr();
    board_.push_back({ir.clone(), T_B_H_, Eigen::Matrix3d::Identity()});
    return ir;
  }
  cv::Mat CaptureProjectedIr(const PatternSpec& pattern, const Eigen::Matrix3d& H) override {
    return inner_->CaptureProjectedIr(pattern, H);
  }
  cv::Mat CaptureRaw(const Eigen::Matrix3d& H) override {
    cv::Mat raw = inner_->CaptureRaw(H);
    raw_.push_back({raw.clone(), T_B_H_, H});
    return raw;
  }

  // DIR/intrinsics/view_NN.png, DIR/hand_eye/ (IR with T_B_H), DIR/depth/ (raw with T_B_H:
  // the captures taken through the final pre-warp H_P_rec, as the depth step's were).
  void Save(const fs::path& dir, const CameraModel& camera, const Eigen::Matrix3d& H_P_rec) const {
    fs::create_directories(dir / "intrinsics");
    FrameDirectoryWriter hand_eye(dir / "hand_eye", camera), depth(dir / "depth", camera);
    for (size_t i = 0; i < board_.size(); ++i) {
      cv::imwrite((dir / "intrinsics" / Format("view_%02zu.png", i)).string(), board_[i].image);
      Frame frame;
      frame.index = static_cast<int>(i);
      frame.time_s = 0.1 * static_cast<double>(i);
      frame.ir = board_[i].image;
      frame.raw = cv::Mat(board_[i].image.size(), CV_16U, cv::Scalar(kRawInvalid));
      frame.T_B_H = board_[i].T_B_H;
      hand_eye.Add(frame);
    }
    int index = 0;
    for (const Capture& c : raw_) {
      if (!c.H.isApprox(H_P_rec, 1e-12)) continue;  // the engine checks with the nominal pre-warp
      Frame frame;
      frame.index = index;
      frame.time_s = 0.1 * index++;
      frame.raw = c.image;
      frame.T_B_H = c.T_B_H;
      depth.Add(frame);
    }
    hand_eye.Finish();
    depth.Finish();
    std::printf("saved the captures in %s: intrinsics/ (%zu images), hand_eye/ (%zu frames), depth/ (%d frames)\n",
                dir.c_str(), board_.size(), board_.size(), index);
  }

 private:
  struct Capture {
    cv::Mat image;
    Pose T_B_H;
    Eigen::Matrix3d H;
  };
  calib::CalibrationHardware* inner_;
  Pose T_B_H_ = Pose::Identity();
  std::vector<Capture> board_, raw_;
};

// The chain with the simulated rig, then its comparison with the rig's ground truth.
Measured RunChain(const InTheLoopOptions& o, const sim::CalibrationRigOptions& rig_options,
                  const ChainOptions& options) {
  std::printf("calibrating the simulated rig '%s' in the loop (seed %u): %d views, %d stations, %d planes\n",
              rig_options.rig.name.c_str(), o.seed, o.views, o.stations, o.planes);
  std::fflush(stdout);
  sim::SimulatedCalibrationRig rig(rig_options);
  std::optional<RecordingHardware> recorder;
  if (!o.save_captures.empty()) recorder.emplace(&rig);
  Measured m;
  const Stopwatch chain;
  m.r = RunCalibrationChain(recorder ? static_cast<calib::CalibrationHardware*>(&*recorder) : &rig, options,
                            [](const std::string& line) {
                              std::printf("%s\n", line.c_str());
                              std::fflush(stdout);
                            });
  m.wall_s = chain.seconds();
  // ground truth (simulation only)
  std::printf("comparing with the rig's ground truth\n");
  m.truth = sim::CompareWithTruth(&rig, m.r);
  m.truth_camera = rig.TruthRig().camera;
  m.truth_T_H_C = rig.TruthT_H_C();
  m.truth_T_B_K = rig.TruthT_B_K();
  m.goals = GoalsFor(rig_options);
  JudgeGoals(&m);
  if (recorder) recorder->Save(o.save_captures, rig.setup().nominal_rig.camera, m.r.calibration.H_P_rec);
  return m;
}

}  // namespace

InTheLoopSummary CalibrateInTheLoop(const InTheLoopOptions& o) {
  InTheLoopSummary s;
  s.out = OutputFolder(o.out, "--out");
  CheckFolderCanBeCreated(s.out, "--out");
  const FolderLock lock(s.out, "--out", "calibrate");  // a second run into --out is refused here
  s.calibration_file = s.out / "calibration.yaml";
  CheckExistingFile(s.calibration_file, o.overwrite_worse);
  sim::CalibrationRigOptions rig_options = sim::CalibrationRigOptionsFor(LoadRigArgument(o.rig));
  rig_options.seed = o.seed;
  rig_options.threads = o.threads;
  rig_options.board_samples = o.board_samples;
  if (!(o.nominal_errors >= 0.0 && o.nominal_errors <= 10.0)) {
    throw InputError("--nominal-errors", "", std::to_string(o.nominal_errors) + ": must be a scale in [0, 10]");
  }
  for (double* error : {&rig_options.mount_error_rad, &rig_options.mount_error_m, &rig_options.plate_error_rad,
                        &rig_options.plate_error_m, &rig_options.projector_error_rad, &rig_options.projector_error_m,
                        &rig_options.focal_error, &rig_options.principal_error_px}) {
    *error *= o.nominal_errors;
  }
  if (!o.save_captures.empty()) {
    for (const char* step : {"hand_eye", "depth"})
      FrameDirectoryWriter::CheckCanWrite(fs::path(o.save_captures) / step);
  }
  ChainOptions options;
  options.views = o.views;
  options.stations = o.stations;
  options.depth_planes = o.planes;
  options.seed = o.seed;
  // Board views, the homography's plane and the depth planes at the rig's working distance.
  options.view_distance_m = options.homography_distance_m = rig_options.WorkingDistanceM();
  // At a long rig's ~0.8 m a 0.5 rad tilt moves the camera 0.4 m sideways, beyond the arm.
  if (rig_options.working_distance_m > 0.0) options.max_tilt_rad = kLongRangeMaxTiltRad;
  const sim::DepthRange range = sim::CalibrationDepthRange(rig_options);
  options.depth_near_m = range.near_m;
  options.depth_far_m = range.far_m;
  if (const std::string p = options.Problem(); !p.empty()) throw InputError("calibrate", "options", p);
  const Measured m = RunChain(o, rig_options, options);

  // outputs: calibration first (the existing-file rules), then the report
  fs::create_directories(s.out);
  const SaveReport saved = SaveCalibration(s.calibration_file, m.r.calibration, {.overwrite_worse = o.overwrite_worse});
  if (!saved.worse_than_existing.empty()) {
    std::printf("warning: replaced %s with a WORSE result (--overwrite-worse): %s\n", s.calibration_file.c_str(),
                saved.worse_than_existing.c_str());
  }
  WritePicture(s.out / "depth_residual.png", ResidualPicture(m.r.depth.inverse_residual_rms_m, 0.2));
  WritePicture(s.out / "reprojection_errors.png",
               ReprojectionPicture(m.r.intrinsics.per_view_rms_px, m.r.intrinsics.rms_px));
  WriteTextAtomically(s.out / "report.json", ReportJson(m, rig_options.rig.name, o.seed));
  s.goals_table = GoalsTable(m);
  WriteTextAtomically(s.out / "report.md", ReportMarkdown(m, s.goals_table, rig_options.rig.name, o.seed));
  s.all_met = m.met_mapping && m.met_hand_eye && m.met_homography && m.met_depth && m.met_compute;
  return s;
}

std::string InTheLoopSummaryText(const InTheLoopSummary& s) {
  return "\n" + s.goals_table + "wrote " + s.calibration_file.string() +
         ", report.json, report.md, depth_residual.png, reprojection_errors.png\n";
}

}  // namespace romunect::jobs
