#include "romunect/calib/chain.h"

#include <algorithm>
#include <chrono>
#include <ctime>
#include <cmath>
#include <limits>
#include <sstream>
#include <type_traits>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/pattern.h"

namespace romunect::calib {
namespace {

constexpr const char* kSource = "calibration chain";
using Clock = std::chrono::steady_clock;

double Since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

// CPU time of the process (all threads), seconds: compute is timed in CPU time because the
// machines this runs on are shared (wall time would count other people's work).
double CpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

// Times a call into *seconds (accumulated CPU time).
template <typename F>
auto Timed(double* seconds, F&& f) {
  const double start = CpuSeconds();
  if constexpr (std::is_void_v<decltype(f())>) {
    f();
    *seconds += CpuSeconds() - start;
  } else {
    auto result = f();
    *seconds += CpuSeconds() - start;
    return result;
  }
}

double ValidFraction(const cv::Mat& raw) {
  ROMUNECT_CHECK(raw.type() == CV_16U && !raw.empty());
  return static_cast<double>(cv::countNonZero(raw != kRawInvalid)) / raw.total();
}

// The camera pose over a point of the plate: optical axis through point_K, tilted by R_K_C.
Pose LookingAt(const Eigen::Vector3d& point_K, const Eigen::Matrix3d& R_K_C, double distance_m) {
  return MakePose(R_K_C, point_K - distance_m * R_K_C.col(2));
}

Eigen::Vector2d MapH(const Eigen::Matrix3d& H, const Eigen::Vector2d& x) { return (H * x.homogeneous()).hnormalized(); }

// Intrinsics views (and hand-eye stations): planned with nominal values, executed, detected.
struct BoardCaptures {
  std::vector<BoardView> views;
  std::vector<int> planned_index;
  std::vector<Pose> T_B_H;
  std::vector<std::pair<std::string, std::string>> rejected;
};

BoardCaptures CaptureBoardViews(CalibrationHardware* hw, const ChainOptions& options, const ChainProgress& say,
                                ChainTimes* times) {
  const CalibrationSetup& setup = hw->setup();
  const CameraModel& nominal = setup.nominal_rig.camera;
  // two plans, near and far, interleaved: both cover the image and the tilts
  const int count = std::max(options.views, options.stations);
  std::vector<Pose> plan;
  Timed(&times->intrinsics_s, [&] {
    std::vector<Pose> near_far[2];
    for (int k = 0; k < 2; ++k) {
      ViewPlanOptions plan_options;
      plan_options.view_count = std::max(3, (count + 1 - k) / 2);  // the planner needs 3
      plan_options.distance_m = options.view_distance_m * (k == 0 ? 1.0 - options.view_distance_spread
                                                                   : 1.0 + options.view_distance_spread);
      plan_options.max_tilt_rad = options.max_tilt_rad;
      plan_options.margin_px = options.margin_px;
      plan_options.seed = options.seed + static_cast<unsigned>(k);
      near_far[k] = PlanViews(nominal, setup.board, plan_options);
    }
    for (int i = 0; i < count; ++i) plan.push_back(near_far[i % 2][i / 2]);
  });
  BoardCaptures out;
  for (size_t i = 0; i < plan.size(); ++i) {
    const std::string name = "view " + std::to_string(i);
    const auto hw_start = Clock::now();
    const std::optional<Pose> T_B_H = hw->MoveHand(setup.T_B_K_nominal * plan[i] * setup.T_H_C_nominal.inverse());
    cv::Mat ir;
    if (T_B_H) ir = hw->CaptureLampIr();
    times->hardware_s += Since(hw_start);
    if (!T_B_H) {
      out.rejected.emplace_back(name, "out of the robot's reach");
      if (say) say("  " + name + ": out of reach");
      continue;
    }
    std::string reason;
    double detect_s = 0.0;
    auto corners = Timed(&detect_s, [&] { return DetectBoard(ir, setup.board, &reason); });
    times->intrinsics_s += detect_s;
    if (!corners) {
      out.rejected.emplace_back(name, reason);
      if (say) say("  " + name + ": " + reason + " (" + std::to_string(static_cast<int>(1e3 * detect_s)) + " ms CPU)");
      continue;
    }
    // OpenCV may order the corners from either end: keep the order the plan predicts.
    std::vector<cv::Point2f> predicted;
    if (ProjectBoard(nominal, setup.board, plan[i].inverse(), &predicted) &&
        cv::norm(corners->front() - predicted.front()) > cv::norm(corners->front() - predicted.back())) {
      std::reverse(corners->begin(), corners->end());
    }
    out.views.push_back({name, std::move(*corners)});
    out.planned_index.push_back(static_cast<int>(i));
    out.T_B_H.push_back(*T_B_H);
    if (say) say("  " + name + ": board found (" + std::to_string(static_cast<int>(1e3 * detect_s)) + " ms CPU)");
  }
  return out;
}

}  // namespace

std::string ChainOptions::Problem() const {
  std::ostringstream s;
  // The steps' own minimums: fewer planned captures could never succeed.
  if (views < std::max(3, intrinsics.min_views)) {
    s << "views = " << views << ": need at least " << std::max(3, intrinsics.min_views) << " (the intrinsics step)";
  } else if (stations < 3) {
    s << "stations = " << stations << ": need at least 3 (hand-eye)";
  } else if (depth_planes < std::max(2, depth.min_planes)) {
    s << "depth_planes = " << depth_planes << ": need at least " << std::max(2, depth.min_planes) << " (the depth step)";
  } else if (!(view_distance_spread >= 0 && view_distance_spread < 0.5)) {
    s << "view_distance_spread = " << view_distance_spread << ": must be in [0, 0.5)";
  } else if (!(view_distance_m > 0) || !(homography_distance_m > 0)) {
    s << "view_distance_m = " << view_distance_m << ", homography_distance_m = " << homography_distance_m
      << ": must be positive";
  } else if (!(depth_near_m > 0 && depth_far_m > depth_near_m)) {
    s << "depth_near_m = " << depth_near_m << ", depth_far_m = " << depth_far_m << ": need 0 < near < far";
  } else if (!(max_tilt_rad >= 0 && max_tilt_rad < 1.4) || !(depth_max_tilt_rad >= 0 && depth_max_tilt_rad < 1.4)) {
    s << "max_tilt_rad = " << max_tilt_rad << ", depth_max_tilt_rad = " << depth_max_tilt_rad
      << ": must be in [0, 1.4)";
  } else if (feature_pattern.kind != PatternKind::kFeatureGrid) {
    s << "feature_pattern.kind = " << PatternKindName(feature_pattern.kind) << ": must be feature-grid";
  } else {
    // the nested options, each under its name
    for (const auto& [name, problem] : {std::pair{"feature_pattern.", feature_pattern.Problem()},
                                        std::pair{"intrinsics.", intrinsics.Problem()},
                                        std::pair{"hand_eye.", hand_eye.Problem()},
                                        std::pair{"homography.", homography.Problem()},
                                        std::pair{"depth.", depth.Problem()}}) {
      if (!problem.empty()) return name + problem;
    }
  }
  return s.str();
}

std::optional<Eigen::Vector2d> ProjectorPixelToCamera(const Rig& rig, const CameraModel& camera, const Pose& T_C_K,
                                                 const Eigen::Vector2d& q_P) {
  const ProjectorModel& p = rig.projector;
  const Eigen::Vector3d dir_C = rig.T_C_P.linear() * Eigen::Vector3d((q_P.x() - p.cx) / p.fx, (q_P.y() - p.cy) / p.fy, 1.0);
  const Eigen::Vector3d o_C = rig.T_C_P.translation();
  const Eigen::Vector3d n_C = T_C_K.linear().col(2);
  const double denom = n_C.dot(dir_C);
  if (std::abs(denom) < 1e-9) return std::nullopt;
  const double s = n_C.dot(T_C_K.translation() - o_C) / denom;
  if (s <= 0) return std::nullopt;
  return camera.Project(o_C + s * dir_C);
}

Eigen::Vector2d ChipReferencePx(const ChipGeometry& chip, const Eigen::Vector2d& x_pattern) {
  // Parallel stock axes, projector at +b along x: a pure horizontal offset f b / Z_ref.
  const double sx = chip.camera.fx / chip.projector.fx, sy = chip.camera.fy / chip.projector.fy;
  return {sx * (x_pattern.x() - chip.projector.cx) + chip.camera.cx + chip.FocalTimesBaseline() / chip.reference_distance_m,
          sy * (x_pattern.y() - chip.projector.cy) + chip.camera.cy};
}

std::vector<cv::Point2f> DetectProjectedDots(const cv::Mat& ir, const std::vector<Eigen::Vector2d>& predicted_px,
                                             double dot_radius_px, double max_offset_px) {
  ROMUNECT_CHECK(ir.type() == CV_16U || ir.type() == CV_8U);
  ROMUNECT_CHECK(dot_radius_px > 0 && max_offset_px > 0);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<cv::Point2f> out(predicted_px.size(), cv::Point2f(nan, nan));
  cv::Mat image;
  ir.convertTo(image, CV_32F);
  const int half = static_cast<int>(std::ceil(max_offset_px + 2.0 * dot_radius_px));
  const double min_area = 0.3 * M_PI * dot_radius_px * dot_radius_px;
  for (size_t i = 0; i < predicted_px.size(); ++i) {
    const Eigen::Vector2d& p = predicted_px[i];
    if (!std::isfinite(p.x()) || !std::isfinite(p.y())) continue;
    const cv::Rect full(static_cast<int>(std::lround(p.x())) - half, static_cast<int>(std::lround(p.y())) - half,
                        2 * half + 1, 2 * half + 1);
    const cv::Rect rect = full & cv::Rect(0, 0, image.cols, image.rows);
    if (rect.area() < full.area() / 4) continue;
    const cv::Mat window = image(rect);
    // background and peak from the window's distribution; the dot must stand out clearly
    std::vector<float> values(window.begin<float>(), window.end<float>());
    std::nth_element(values.begin(), values.begin() + values.size() / 10, values.end());
    const float background = values[values.size() / 10];
    double peak = 0.0;
    cv::minMaxLoc(window, nullptr, &peak);
    if (peak - background < 20.0) continue;
    // the bright component nearest the prediction
    cv::Mat mask = window > background + 0.5 * (peak - background);
    cv::Mat labels, stats, centroids;
    const int n = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8, CV_32S);
    int best = -1;
    double best_d = max_offset_px;
    for (int c = 1; c < n; ++c) {
      if (stats.at<int>(c, cv::CC_STAT_AREA) < min_area) continue;
      const Eigen::Vector2d centre(centroids.at<double>(c, 0) + rect.x, centroids.at<double>(c, 1) + rect.y);
      const double d = (centre - p).norm();
      if (d < best_d) best_d = d, best = c;
    }
    if (best < 0) continue;
    const int bx = stats.at<int>(best, cv::CC_STAT_LEFT), by = stats.at<int>(best, cv::CC_STAT_TOP);
    if (bx == 0 || by == 0 || bx + stats.at<int>(best, cv::CC_STAT_WIDTH) >= window.cols ||
        by + stats.at<int>(best, cv::CC_STAT_HEIGHT) >= window.rows) {
      continue;  // cut by the window or the image: the centroid would be biased
    }
    // refine: intensity-weighted centroid over a disk around the current estimate, iterated
    Eigen::Vector2d c(centroids.at<double>(best, 0) + rect.x, centroids.at<double>(best, 1) + rect.y);
    const double r = 1.6 * dot_radius_px;
    bool ok = true;
    for (int it = 0; it < 4 && ok; ++it) {
      double sw = 0.0, sx = 0.0, sy = 0.0;
      const int x0 = static_cast<int>(std::floor(c.x() - r)), x1 = static_cast<int>(std::ceil(c.x() + r));
      const int y0 = static_cast<int>(std::floor(c.y() - r)), y1 = static_cast<int>(std::ceil(c.y() + r));
      if (x0 < 0 || y0 < 0 || x1 >= image.cols || y1 >= image.rows) {
        ok = false;
        break;
      }
      for (int y = y0; y <= y1; ++y) {
        const float* row = image.ptr<float>(y);
        for (int x = x0; x <= x1; ++x) {
          if ((x - c.x()) * (x - c.x()) + (y - c.y()) * (y - c.y()) > r * r) continue;
          const double w = std::max(0.0, static_cast<double>(row[x]) - background);
          sw += w, sx += w * x, sy += w * y;
        }
      }
      if (sw <= 0) {
        ok = false;
        break;
      }
      c = Eigen::Vector2d(sx / sw, sy / sw);
    }
    if (ok && (c - p).norm() <= max_offset_px) out[i] = cv::Point2f(static_cast<float>(c.x()), static_cast<float>(c.y()));
  }
  return out;
}

ChainResult RunCalibrationChain(CalibrationHardware* hardware, const ChainOptions& options,
                                const ChainProgress& progress) {
  ROMUNECT_CHECK(hardware != nullptr);
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  CalibrationHardware& hw = *hardware;
  const CalibrationSetup& setup = hw.setup();
  if (const std::string p = setup.nominal_rig.Problem(); !p.empty()) throw InputError(kSource, "nominal_rig", p);
  if (const std::string p = setup.board.Problem(); !p.empty()) throw InputError(kSource, "board", p);
  auto say = [&](const std::string& line) {
    if (progress) progress(line);
  };
  ChainResult result;
  ChainTimes& times = result.times;
  const cv::Size image_size(setup.nominal_rig.camera.width, setup.nominal_rig.camera.height);

  // ---- 1. intrinsics (Zhang): planned views of the board, lamp on, projector off
  say("intrinsics: " + std::to_string(std::max(options.views, options.stations)) + " planned views");
  BoardCaptures board = CaptureBoardViews(&hw, options, say, &times);
  result.rejected = board.rejected;
  std::vector<BoardView> intrinsics_views;
  for (size_t i = 0; i < board.views.size(); ++i) {
    if (board.planned_index[i] < options.views) {
      intrinsics_views.push_back(board.views[i]);
      result.view_names.push_back(board.views[i].name);
      result.view_T_B_H.push_back(board.T_B_H[i]);
    }
  }
  double zhang_s = 0.0;
  result.intrinsics = Timed(&zhang_s, [&] {
    return CalibrateIntrinsics(intrinsics_views, setup.board, image_size, options.intrinsics);
  });
  times.intrinsics_s += zhang_s;
  const CameraModel& camera = result.intrinsics.camera;
  say(result.intrinsics.BriefReport() + " (" + std::to_string(static_cast<int>(1e3 * zhang_s)) + " ms CPU)");

  // ---- 2. projector homography (eq. 1), hardware in the loop over the reference area
  say("projector homography: feature grid on the reference area");
  const Pose T_K_C_homography =
      LookingAt(setup.reference_centre_K, Eigen::Matrix3d::Identity(), options.homography_distance_m);
  {
    const auto start = Clock::now();
    const bool reached = hw.MoveHand(setup.T_B_K_nominal * T_K_C_homography * setup.T_H_C_nominal.inverse()).has_value();
    times.hardware_s += Since(start);
    if (!reached) {
      throw InputError(kSource, "homography station", "the pose over the plate's reference area is out of reach; "
                                                      "move the plate closer to the robot");
    }
  }
  const ChipGeometry& chip = setup.nominal_rig.depth_engine.chip;
  const double dot_margin_px = 2.0 * options.feature_pattern.pitch_px / 6.0 + 4.0;
  for (const Eigen::Vector2d& x : PatternFeaturePoints(options.feature_pattern)) {
    const Eigen::Vector2d target = ChipReferencePx(chip, x);
    if (target.x() < dot_margin_px || target.y() < dot_margin_px || target.x() > image_size.width - 1 - dot_margin_px ||
        target.y() > image_size.height - 1 - dot_margin_px) {
      continue;  // the chip's reference has it off the image: nothing to line up
    }
    result.homography_pattern.push_back(x);
    result.homography_target.push_back(target);
  }
  const std::vector<Eigen::Vector2d>& pattern_P = result.homography_pattern;
  const Eigen::Matrix3d H_initial = IdealPrewarp(setup.nominal_rig, options.homography_distance_m);
  // The first prediction comes from nominal geometry; later ones from the fitted F_img.
  std::vector<cv::Point2d> shown_all, seen_all;
  double hardware_cpu_s = 0.0;  // the simulated projector's CPU inside the loop (not compute)
  cv::Mat F_fit;
  const Pose T_C_K_nominal = T_K_C_homography.inverse();
  auto observe = [&](const Eigen::Matrix3d& H) {
    std::vector<Eigen::Vector2d> predicted(pattern_P.size(),
                                           Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN()));
    for (size_t i = 0; i < pattern_P.size(); ++i) {
      const Eigen::Vector2d q = MapH(H, pattern_P[i]);
      if (F_fit.empty()) {
        // the datasheet camera: robust even where few views left Zhang's estimate poor
        if (auto u = ProjectorPixelToCamera(setup.nominal_rig, setup.nominal_rig.camera, T_C_K_nominal, q)) {
          predicted[i] = *u;
        }
      } else {
        std::vector<cv::Point2d> in{{q.x(), q.y()}}, ideal;
        cv::perspectiveTransform(in, ideal, F_fit);
        const Eigen::Vector3d ray((ideal[0].x - camera.cx) / camera.fx, (ideal[0].y - camera.cy) / camera.fy, 1.0);
        if (auto u = camera.Project(ray)) predicted[i] = *u;
      }
    }
    // dot size and spacing in the camera from two predicted neighbours
    double spacing_px = options.feature_pattern.pitch_px;
    for (size_t i = 0; i + 1 < predicted.size(); ++i) {
      if (predicted[i].allFinite() && predicted[i + 1].allFinite() && pattern_P[i + 1].y() == pattern_P[i].y()) {
        spacing_px = (predicted[i + 1] - predicted[i]).norm() * options.feature_pattern.pitch_px /
                     (pattern_P[i + 1].x() - pattern_P[i].x());
        break;
      }
    }
    const auto start = Clock::now();
    const double cpu_start = CpuSeconds();
    const cv::Mat ir = hw.CaptureProjectedIr(options.feature_pattern, H);
    hardware_cpu_s += CpuSeconds() - cpu_start;
    times.hardware_s += Since(start);
    std::vector<cv::Point2f> dots = DetectProjectedDots(ir, predicted, spacing_px / 6.0, 0.35 * spacing_px);
    // F_img for the next prediction: shown projector pixel -> ideal camera pixel
    for (size_t i = 0; i < dots.size(); ++i) {
      if (!std::isfinite(dots[i].x)) continue;
      const Eigen::Vector2d q = MapH(H, pattern_P[i]);
      const Eigen::Vector2d ideal = camera.UndistortPixel(Eigen::Vector2d(dots[i].x, dots[i].y));
      shown_all.emplace_back(q.x(), q.y());
      seen_all.emplace_back(ideal.x(), ideal.y());
    }
    if (shown_all.size() >= 8) F_fit = cv::findHomography(shown_all, seen_all, cv::RANSAC, 2.0);
    say("  capture: " + std::to_string(std::count_if(dots.begin(), dots.end(), [](const cv::Point2f& d) {
          return std::isfinite(d.x);
        })) + " of " + std::to_string(dots.size()) + " features found");
    return dots;
  };
  {
    const double start = CpuSeconds();
    hardware_cpu_s = 0.0;
    result.homography = CalibrateProjectorHomography(pattern_P, result.homography_target, camera, H_initial, observe,
                                                     options.homography);
    times.homography_s += CpuSeconds() - start - hardware_cpu_s;
  }
  // what the depth engine makes of the default pattern, before and after
  {
    const auto start = Clock::now();
    result.raw_valid_fraction_unwarped = ValidFraction(hw.CaptureRaw(Eigen::Matrix3d::Identity()));
    result.raw_valid_fraction_initial = ValidFraction(hw.CaptureRaw(H_initial));
    result.raw_valid_fraction_final = ValidFraction(hw.CaptureRaw(result.homography.H_P_rec));
    times.hardware_s += Since(start);
  }
  say(result.homography.BriefReport());
  {
    char line[200];
    std::snprintf(line, sizeof line, "  depth engine matches: %.1f %% unwarped, %.1f %% nominal pre-warp, %.1f %% calibrated",
                  100 * result.raw_valid_fraction_unwarped, 100 * result.raw_valid_fraction_initial,
                  100 * result.raw_valid_fraction_final);
    say(line);
  }

  // ---- 3. hand-eye (Tsai/Park initial estimate, Ceres refinement) from the same views
  std::vector<HandEyeStation> stations;
  for (size_t i = 0; i < board.views.size(); ++i) {
    if (board.planned_index[i] < options.stations) stations.push_back({board.T_B_H[i], board.views[i]});
  }
  result.stations_used = static_cast<int>(stations.size());
  say("hand-eye: " + std::to_string(stations.size()) + " stations");
  result.hand_eye = Timed(&times.hand_eye_s, [&] { return CalibrateHandEye(stations, camera, setup.board, options.hand_eye); });
  say(result.hand_eye.BriefReport());
  // stations the fit cannot explain (a corner order flipped, a pose reported wrong): drop
  // those far above the median and fit again, once
  if (result.hand_eye.rms_px > std::max(1.0, 5.0 * result.intrinsics.rms_px)) {
    std::vector<double> rms(stations.size());
    const std::vector<Eigen::Vector3d> corners_K = setup.board.CornersK();
    for (size_t s = 0; s < stations.size(); ++s) {
      const Pose T_C_K = (stations[s].T_B_H * result.hand_eye.T_H_C).inverse() * result.hand_eye.T_B_K;
      double sum = 0.0;
      for (size_t i = 0; i < corners_K.size(); ++i) {
        const auto u = result.hand_eye.camera.Project(T_C_K * corners_K[i]);
        const cv::Point2f& d = stations[s].view.corners_px[i];
        sum += u ? (*u - Eigen::Vector2d(d.x, d.y)).squaredNorm() : 1e6;
      }
      rms[s] = std::sqrt(sum / corners_K.size());
    }
    std::vector<double> sorted = rms;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double limit = 3.0 * sorted[sorted.size() / 2];
    std::vector<HandEyeStation> kept;
    for (size_t s = 0; s < stations.size(); ++s) {
      if (rms[s] <= limit) {
        kept.push_back(stations[s]);
      } else {
        result.rejected.emplace_back(stations[s].view.name, "hand-eye outlier (" + std::to_string(rms[s]) + " px)");
        say("  dropped " + stations[s].view.name + ": " + std::to_string(rms[s]) + " px against the fit");
      }
    }
    if (kept.size() < stations.size() && static_cast<int>(kept.size()) >= options.hand_eye.min_stations) {
      stations = std::move(kept);
      result.stations_used = static_cast<int>(stations.size());
      result.hand_eye =
          Timed(&times.hand_eye_s, [&] { return CalibrateHandEye(stations, camera, setup.board, options.hand_eye); });
      say(result.hand_eye.BriefReport());
    }
  }
  // the same corners fit the camera alone to intrinsics.rms_px: far more here means stations
  // whose poses and images disagree (a corner order flipped, a pose reported wrong)
  if (result.hand_eye.rms_px > std::max(1.0, 5.0 * result.intrinsics.rms_px)) {
    throw InputError(kSource, "hand-eye", "the stations do not agree (reprojection RMS " +
                                              std::to_string(result.hand_eye.rms_px) + " px against " +
                                              std::to_string(result.intrinsics.rms_px) +
                                              " px for the views alone): check the reported hand poses and "
                                              "the board's corner order");
  }
  result.hand_eye_stations = stations;
  // from here on the camera refined with the robot's motion (when the options ask for it)
  const CameraModel& refined = result.hand_eye.camera;
  // ---- 4. per-pixel depth correction (eqs. 2-3): planes placed with the calibrated hand-eye
  say("depth: " + std::to_string(options.depth_planes) + " reference-plane captures");
  const Pose& T_H_C = result.hand_eye.T_H_C;
  const Pose& T_B_K = result.hand_eye.T_B_K;
  std::vector<PlaneCapture> captures;
  for (int i = 0; i < options.depth_planes; ++i) {
    const double distance_m =
        options.depth_near_m + (options.depth_far_m - options.depth_near_m) * i / (options.depth_planes - 1);
    // tilts turn by the golden angle so the planes cross each pixel at varied depths
    const double phi = 2.39996 * i;
    const double tilt = options.depth_max_tilt_rad * (i % 2 == 0 ? 1.0 : 0.5);
    const Eigen::Matrix3d R_K_C = (Eigen::AngleAxisd(tilt * std::cos(phi), Eigen::Vector3d::UnitX()) *
                                   Eigen::AngleAxisd(tilt * std::sin(phi), Eigen::Vector3d::UnitY()))
                                      .toRotationMatrix();
    const Pose T_K_C = LookingAt(setup.reference_centre_K, R_K_C, distance_m);
    const auto start = Clock::now();
    const std::optional<Pose> T_B_H = hw.MoveHand(T_B_K * T_K_C * T_H_C.inverse());
    cv::Mat raw;
    if (T_B_H) raw = hw.CaptureRaw(result.homography.H_P_rec);
    times.hardware_s += Since(start);
    if (!T_B_H) {
      say("  plane " + std::to_string(i) + ": out of reach");
      continue;
    }
    // eq. 2's ground truth comes from the EXECUTED pose and the calibrated hand-eye
    captures.push_back({raw, (*T_B_H * T_H_C).inverse() * T_B_K});
  }
  result.planes_used = static_cast<int>(captures.size());
  DepthCorrectionOptions depth_options = options.depth;
  depth_options.chip = chip;
  result.depth = Timed(&times.depth_s, [&] { return FitDepthCorrection(refined, captures, depth_options); });
  say(result.depth.BriefReport());

  Calibration& c = result.calibration;
  c.camera = refined;
  c.H_P_rec = result.homography.H_P_rec;
  c.T_H_C = T_H_C;
  c.T_B_K = T_B_K;
  c.depth = result.depth.inverse;
  c.chip = chip;
  c.residuals.intrinsics_rms_px = result.intrinsics.rms_px;
  c.residuals.intrinsics_holdout_rms_px = result.intrinsics.holdout_rms_px;
  c.residuals.hand_eye_rms_px = result.hand_eye.rms_px;
  c.residuals.homography_rms_px = result.homography.predicted_rms_px;
  c.residuals.depth_rms_m = result.depth.inverse_rms_m;
  return result;
}

}  // namespace romunect::calib
