#include "romunect/calib/chain.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>
#include <type_traits>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/calib/hand_eye_check.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/pattern.h"

namespace romunect::calib {
namespace {

constexpr const char* kSource = "calibration chain";

// Times a call into *seconds (accumulated CPU time of the process): compute is timed in CPU
// time because the machines this runs on are shared (wall time would count other people's work).
template <typename F>
auto Timed(double* seconds, F&& f) {
  const double start = ProcessCpuSeconds();
  if constexpr (std::is_void_v<decltype(f())>) {
    f();
    *seconds += ProcessCpuSeconds() - start;
  } else {
    auto result = f();
    *seconds += ProcessCpuSeconds() - start;
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
      plan_options.distance_m = options.view_distance_m *
                                (k == 0 ? 1.0 - options.view_distance_spread : 1.0 + options.view_distance_spread);
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
    const Stopwatch hardware;
    const std::optional<Pose> T_B_H = hw->MoveHand(setup.T_B_K_nominal * plan[i] * setup.T_H_C_nominal.inverse());
    cv::Mat ir;
    if (T_B_H) ir = hw->CaptureLampIr();
    times->hardware_s += hardware.seconds();
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

int ChainOptions::MinViews() const { return std::max(3, intrinsics.min_views); }
int ChainOptions::MinPlanes() const { return std::max(2, depth.min_planes); }

std::string ChainOptions::Problem() const {
  std::ostringstream s;
  // The steps' own minimums: fewer planned captures could never succeed.
  if (views < MinViews()) {
    s << "views = " << views << ": need at least " << MinViews() << " (the intrinsics step)";
  } else if (stations < 3) {
    s << "stations = " << stations << ": need at least 3 (hand-eye)";
  } else if (depth_planes < MinPlanes()) {
    s << "depth_planes = " << depth_planes << ": need at least " << MinPlanes() << " (the depth step)";
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
    for (const auto& [name, problem] :
         {std::pair{"feature_pattern.", feature_pattern.Problem()}, std::pair{"intrinsics.", intrinsics.Problem()},
          std::pair{"hand_eye.", hand_eye.Problem()}, std::pair{"homography.", homography.Problem()},
          std::pair{"depth.", depth.Problem()}}) {
      if (!problem.empty()) return name + problem;
    }
  }
  return s.str();
}

std::optional<Eigen::Vector2d> ProjectorPixelToCamera(const Rig& rig, const CameraModel& camera, const Pose& T_C_K,
                                                      const Eigen::Vector2d& q_P) {
  const ProjectorModel& p = rig.projector;
  const Eigen::Vector3d dir_C = rig.T_C_P.linear() *
                                Eigen::Vector3d((q_P.x() - p.cx) / p.fx, (q_P.y() - p.cy) / p.fy, 1.0);
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
  return {sx * (x_pattern.x() - chip.projector.cx) + chip.camera.cx +
              chip.FocalTimesBaseline() / chip.reference_distance_m,
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
    if (ok && (c - p).norm() <= max_offset_px)
      out[i] = cv::Point2f(static_cast<float>(c.x()), static_cast<float>(c.y()));
  }
  return out;
}

namespace {

// ---- 1. intrinsics (Zhang) on the first options.views planned views that were captured
void IntrinsicsStep(const BoardCaptures& board, const CalibrationSetup& setup, const ChainOptions& options,
                    const cv::Size& image_size, const ChainProgress& say, ChainResult* result) {
  std::vector<BoardView> views;
  for (size_t i = 0; i < board.views.size(); ++i) {
    if (board.planned_index[i] < options.views) {
      views.push_back(board.views[i]);
      result->view_names.push_back(board.views[i].name);
      result->view_T_B_H.push_back(board.T_B_H[i]);
    }
  }
  double zhang_s = 0.0;
  result->intrinsics = Timed(&zhang_s,
                             [&] { return CalibrateIntrinsics(views, setup.board, image_size, options.intrinsics); });
  result->times.intrinsics_s += zhang_s;
  say(result->intrinsics.BriefReport() + " (" + std::to_string(static_cast<int>(1e3 * zhang_s)) + " ms CPU)");
}

// ---- 2. projector homography (eq. 1), hardware in the loop over the reference area

// Eq. 1's points: the feature-grid points whose place in the chip's reference lies on the image,
// a dot's size inside its border (elsewhere there is nothing to line up).
void ChooseHomographyPoints(const ChipGeometry& chip, const ChainOptions& options, const cv::Size& image_size,
                            ChainResult* result) {
  const double dot_margin_px = 2.0 * options.feature_pattern.pitch_px / 6.0 + 4.0;
  for (const Eigen::Vector2d& x : PatternFeaturePoints(options.feature_pattern)) {
    const Eigen::Vector2d target = ChipReferencePx(chip, x);
    if (target.x() < dot_margin_px || target.y() < dot_margin_px || target.x() > image_size.width - 1 - dot_margin_px ||
        target.y() > image_size.height - 1 - dot_margin_px) {
      continue;
    }
    result->homography_pattern.push_back(x);
    result->homography_target.push_back(target);
  }
}

// The loop's observation: shows the pattern warped by H, finds each dot where the current model
// predicts it, and refits F_img (shown projector pixel -> ideal camera pixel) from every dot seen
// so far. The first prediction comes from nominal geometry; later ones from the fitted F_img.
class HomographyObserver {
 public:
  HomographyObserver(CalibrationHardware* hw, const ChainOptions& options, const CameraModel& camera,
                     const std::vector<Eigen::Vector2d>& pattern_P, const Pose& T_C_K_nominal, const ChainProgress& say,
                     ChainTimes* times)
      : hw_(*hw),
        options_(options),
        camera_(camera),
        pattern_P_(pattern_P),
        T_C_K_nominal_(T_C_K_nominal),
        say_(say),
        times_(*times) {}

  std::vector<cv::Point2f> operator()(const Eigen::Matrix3d& H) {
    const std::vector<Eigen::Vector2d> predicted = Predict(H);
    const double spacing_px = DotSpacingPx(predicted);
    const Stopwatch wall;
    const double cpu_start = ProcessCpuSeconds();
    const cv::Mat ir = hw_.CaptureProjectedIr(options_.feature_pattern, H);
    hardware_cpu_s_ += ProcessCpuSeconds() - cpu_start;
    times_.hardware_s += wall.seconds();
    std::vector<cv::Point2f> dots = DetectProjectedDots(ir, predicted, spacing_px / 6.0, 0.35 * spacing_px);
    Refit(H, dots);
    say_("  capture: " +
         std::to_string(
             std::count_if(dots.begin(), dots.end(), [](const cv::Point2f& d) { return std::isfinite(d.x); })) +
         " of " + std::to_string(dots.size()) + " features found");
    return dots;
  }

  // The simulated projector's CPU inside the loop (not the calibration's compute).
  double hardware_cpu_s() const { return hardware_cpu_s_; }

 private:
  std::vector<Eigen::Vector2d> Predict(const Eigen::Matrix3d& H) const {
    std::vector<Eigen::Vector2d> predicted(pattern_P_.size(),
                                           Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN()));
    const CalibrationSetup& setup = hw_.setup();
    for (size_t i = 0; i < pattern_P_.size(); ++i) {
      const Eigen::Vector2d q = MapH(H, pattern_P_[i]);
      if (F_fit_.empty()) {
        // the datasheet camera: robust even where few views left Zhang's estimate poor
        if (auto u = ProjectorPixelToCamera(setup.nominal_rig, setup.nominal_rig.camera, T_C_K_nominal_, q)) {
          predicted[i] = *u;
        }
      } else {
        std::vector<cv::Point2d> in{{q.x(), q.y()}}, ideal;
        cv::perspectiveTransform(in, ideal, F_fit_);
        const Eigen::Vector3d ray((ideal[0].x - camera_.cx) / camera_.fx, (ideal[0].y - camera_.cy) / camera_.fy, 1.0);
        if (auto u = camera_.Project(ray)) predicted[i] = *u;
      }
    }
    return predicted;
  }

  // Dot spacing in the camera from two predicted neighbours (dot size and search radius follow).
  double DotSpacingPx(const std::vector<Eigen::Vector2d>& predicted) const {
    const double pitch_px = options_.feature_pattern.pitch_px;
    for (size_t i = 0; i + 1 < predicted.size(); ++i) {
      if (predicted[i].allFinite() && predicted[i + 1].allFinite() && pattern_P_[i + 1].y() == pattern_P_[i].y()) {
        return (predicted[i + 1] - predicted[i]).norm() * pitch_px / (pattern_P_[i + 1].x() - pattern_P_[i].x());
      }
    }
    return pitch_px;
  }

  void Refit(const Eigen::Matrix3d& H, const std::vector<cv::Point2f>& dots) {
    for (size_t i = 0; i < dots.size(); ++i) {
      if (!std::isfinite(dots[i].x)) continue;
      const Eigen::Vector2d q = MapH(H, pattern_P_[i]);
      const Eigen::Vector2d ideal = camera_.UndistortPixel(Eigen::Vector2d(dots[i].x, dots[i].y));
      shown_all_.emplace_back(q.x(), q.y());
      seen_all_.emplace_back(ideal.x(), ideal.y());
    }
    if (shown_all_.size() >= 8) F_fit_ = cv::findHomography(shown_all_, seen_all_, cv::RANSAC, 2.0);
  }

  CalibrationHardware& hw_;
  const ChainOptions& options_;
  const CameraModel& camera_;
  const std::vector<Eigen::Vector2d>& pattern_P_;
  const Pose T_C_K_nominal_;
  const ChainProgress& say_;
  ChainTimes& times_;
  std::vector<cv::Point2d> shown_all_, seen_all_;
  cv::Mat F_fit_;
  double hardware_cpu_s_ = 0.0;
};

// What the depth engine makes of the default pattern: unwarped, with the nominal pre-warp and
// with the calibrated one.
void MeasureDepthEngineMatches(CalibrationHardware* hw, const Eigen::Matrix3d& H_initial, const ChainProgress& say,
                               ChainResult* result) {
  const Stopwatch hardware;
  result->raw_valid_fraction_unwarped = ValidFraction(hw->CaptureRaw(Eigen::Matrix3d::Identity()));
  result->raw_valid_fraction_initial = ValidFraction(hw->CaptureRaw(H_initial));
  result->raw_valid_fraction_final = ValidFraction(hw->CaptureRaw(result->homography.H_P_rec));
  result->times.hardware_s += hardware.seconds();
  say(result->homography.BriefReport());
  char line[200];
  std::snprintf(line, sizeof line,
                "  depth engine matches: %.1f %% unwarped, %.1f %% nominal pre-warp, %.1f %% calibrated",
                100 * result->raw_valid_fraction_unwarped, 100 * result->raw_valid_fraction_initial,
                100 * result->raw_valid_fraction_final);
  say(line);
}

void HomographyStep(CalibrationHardware* hw, const ChainOptions& options, const cv::Size& image_size,
                    const ChainProgress& say, ChainResult* result) {
  const CalibrationSetup& setup = hw->setup();
  say("projector homography: feature grid on the reference area");
  const Pose T_K_C = LookingAt(setup.reference_centre_K, Eigen::Matrix3d::Identity(), options.homography_distance_m);
  const Stopwatch move;
  const bool reached = hw->MoveHand(setup.T_B_K_nominal * T_K_C * setup.T_H_C_nominal.inverse()).has_value();
  result->times.hardware_s += move.seconds();
  if (!reached) {
    throw InputError(kSource, "homography station",
                     "the pose over the plate's reference area is out of reach; "
                     "move the plate closer to the robot");
  }
  ChooseHomographyPoints(setup.nominal_rig.depth_engine.chip, options, image_size, result);
  const Eigen::Matrix3d H_initial = IdealPrewarp(setup.nominal_rig, options.homography_distance_m);
  HomographyObserver observer(hw, options, result->intrinsics.camera, result->homography_pattern, T_K_C.inverse(), say,
                              &result->times);
  const double start = ProcessCpuSeconds();
  result->homography = CalibrateProjectorHomography(
      result->homography_pattern, result->homography_target, result->intrinsics.camera, H_initial,
      [&observer](const Eigen::Matrix3d& H) { return observer(H); }, options.homography);
  result->times.homography_s += ProcessCpuSeconds() - start - observer.hardware_cpu_s();
  MeasureDepthEngineMatches(hw, H_initial, say, result);
}

// ---- 3. hand-eye (Tsai/Park initial estimate, Ceres refinement) from the same views

void HandEyeStep(const BoardCaptures& board, const CalibrationSetup& setup, const ChainOptions& options,
                 const ChainProgress& say, ChainResult* result) {
  HandEyeCaptures captures;
  for (size_t i = 0; i < board.views.size(); ++i) {
    if (board.planned_index[i] < options.stations) {
      captures.T_B_H.push_back(board.T_B_H[i]);
      captures.views.push_back(board.views[i]);
    }
  }
  say("hand-eye: " + std::to_string(captures.T_B_H.size()) + " stations");
  // the same corners fit the camera alone to intrinsics.rms_px: far more means stations whose
  // poses and images disagree; those far above the median are dropped once (hand_eye_check.h)
  HandEyeCheckOptions check;
  check.hand_eye = options.hand_eye;
  check.intrinsics_rms_px = result->intrinsics.rms_px;
  const CheckedHandEye checked = Timed(&result->times.hand_eye_s, [&] {
    return CalibrateHandEyeChecked(captures, result->intrinsics.camera, setup.board, check);
  });
  for (const auto& [name, rms_px] : checked.dropped) {
    result->rejected.emplace_back(name, "hand-eye outlier (" + std::to_string(rms_px) + " px)");
    say("  dropped " + name + ": " + std::to_string(rms_px) + " px against the fit");
  }
  result->hand_eye = checked.fit;
  result->stations_used = static_cast<int>(checked.used.size());
  say(result->hand_eye.BriefReport());
  if (!checked.accepted) {
    throw InputError(kSource, "hand-eye",
                     "the stations do not agree (reprojection RMS " + std::to_string(result->hand_eye.rms_px) +
                         " px against " + std::to_string(result->intrinsics.rms_px) + " px for the views alone): " +
                         checked.cause + "; check the reported hand poses and the board's corner order");
  }
  result->hand_eye_stations = checked.used;
}

// ---- 4. per-pixel depth correction (eqs. 2-3): planes placed with the calibrated hand-eye

// The camera over the reference area for plane i of the depth step: distances spread over
// [near, far], tilts turned by the golden angle so the planes cross each pixel at varied depths.
Pose DepthPlaneT_K_C(const CalibrationSetup& setup, const ChainOptions& options, int i) {
  const double distance_m = options.depth_near_m +
                            (options.depth_far_m - options.depth_near_m) * i / (options.depth_planes - 1);
  const double phi = 2.39996 * i;
  const double tilt = options.depth_max_tilt_rad * (i % 2 == 0 ? 1.0 : 0.5);
  const Eigen::Matrix3d R_K_C = (Eigen::AngleAxisd(tilt * std::cos(phi), Eigen::Vector3d::UnitX()) *
                                 Eigen::AngleAxisd(tilt * std::sin(phi), Eigen::Vector3d::UnitY()))
                                    .toRotationMatrix();
  return LookingAt(setup.reference_centre_K, R_K_C, distance_m);
}

void DepthStep(CalibrationHardware* hw, const ChainOptions& options, const ChainProgress& say, ChainResult* result) {
  const CalibrationSetup& setup = hw->setup();
  say("depth: " + std::to_string(options.depth_planes) + " reference-plane captures");
  const Pose& T_H_C = result->hand_eye.T_H_C;
  const Pose& T_B_K = result->hand_eye.T_B_K;
  std::vector<PlaneCapture> captures;
  for (int i = 0; i < options.depth_planes; ++i) {
    const Stopwatch hardware;
    const std::optional<Pose> T_B_H = hw->MoveHand(T_B_K * DepthPlaneT_K_C(setup, options, i) * T_H_C.inverse());
    cv::Mat raw;
    if (T_B_H) raw = hw->CaptureRaw(result->homography.H_P_rec);
    result->times.hardware_s += hardware.seconds();
    if (!T_B_H) {
      say("  plane " + std::to_string(i) + ": out of reach");
      continue;
    }
    // eq. 2's ground truth comes from the EXECUTED pose and the calibrated hand-eye
    captures.push_back({raw, (*T_B_H * T_H_C).inverse() * T_B_K});
  }
  result->planes_used = static_cast<int>(captures.size());
  DepthCorrectionOptions depth_options = options.depth;
  depth_options.chip = setup.nominal_rig.depth_engine.chip;
  // the camera refined with the robot's motion (when the options ask for it)
  result->depth = Timed(&result->times.depth_s,
                        [&] { return FitDepthCorrection(result->hand_eye.camera, captures, depth_options); });
  say(result->depth.BriefReport());
}

// The calibration file's content: the hand-eye step's camera, the exact depth model.
Calibration MakeCalibration(const ChainResult& result, const ChipGeometry& chip) {
  Calibration c;
  c.camera = result.hand_eye.camera;
  c.H_P_rec = result.homography.H_P_rec;
  c.T_H_C = result.hand_eye.T_H_C;
  c.T_B_K = result.hand_eye.T_B_K;
  c.depth = result.depth.inverse;
  c.chip = chip;
  c.residuals.intrinsics_rms_px = result.intrinsics.rms_px;
  c.residuals.intrinsics_holdout_rms_px = result.intrinsics.holdout_rms_px;
  c.residuals.hand_eye_rms_px = result.hand_eye.rms_px;
  c.residuals.homography_rms_px = result.homography.predicted_rms_px;
  c.residuals.depth_rms_m = result.depth.inverse_rms_m;
  return c;
}

}  // namespace

ChainResult RunCalibrationChain(CalibrationHardware* hardware, const ChainOptions& options,
                                const ChainProgress& progress) {
  ROMUNECT_CHECK(hardware != nullptr);
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  const CalibrationSetup& setup = hardware->setup();
  if (const std::string p = setup.nominal_rig.Problem(); !p.empty()) throw InputError(kSource, "nominal_rig", p);
  if (const std::string p = setup.board.Problem(); !p.empty()) throw InputError(kSource, "board", p);
  const ChainProgress say = [&](const std::string& line) {
    if (progress) progress(line);
  };
  ChainResult result;
  const cv::Size image_size(setup.nominal_rig.camera.width, setup.nominal_rig.camera.height);

  // Board views, lamp on and projector off: the intrinsics' views and the hand-eye's stations.
  say("intrinsics: " + std::to_string(std::max(options.views, options.stations)) + " planned views");
  const BoardCaptures board = CaptureBoardViews(hardware, options, say, &result.times);
  result.rejected = board.rejected;
  IntrinsicsStep(board, setup, options, image_size, say, &result);
  HomographyStep(hardware, options, image_size, say, &result);
  HandEyeStep(board, setup, options, say, &result);
  DepthStep(hardware, options, say, &result);
  result.calibration = MakeCalibration(result, setup.nominal_rig.depth_engine.chip);
  return result;
}

}  // namespace romunect::calib
