#include "romunect/calib/hand_eye_check.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "romunect/sensor/errors.h"

namespace romunect::calib {
namespace {

// Fits, and when over the limit drops the stations far above the median and fits again, once,
// when enough stations remain (a flipped corner order, a pose reported wrong).
void FitDroppingOutliers(const CameraModel& camera, const BoardSpec& board, const HandEyeCheckOptions& options,
                         CheckedHandEye* out) {
  out->fit = CalibrateHandEye(out->used, camera, board, options.hand_eye);
  out->station_rms_px = HandEyeStationRmsPx(out->used, out->fit, board);
  if (out->fit.rms_px <= out->limit_px) return;
  std::vector<double> sorted = out->station_rms_px;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double outlier_px = options.outlier_factor * sorted[sorted.size() / 2];
  std::vector<HandEyeStation> kept;
  std::vector<std::pair<std::string, double>> dropped;
  for (size_t s = 0; s < out->used.size(); ++s) {
    if (out->station_rms_px[s] <= outlier_px) {
      kept.push_back(out->used[s]);
    } else {
      dropped.emplace_back(out->used[s].view.name, out->station_rms_px[s]);
    }
  }
  if (dropped.empty() || static_cast<int>(kept.size()) < options.hand_eye.min_stations) return;
  try {
    out->fit = CalibrateHandEye(kept, camera, board, options.hand_eye);
  } catch (const InputError&) {
    return;  // the kept stations alone are degenerate: keep the fit of all; the limit decides
  }
  out->used = std::move(kept);
  out->dropped = std::move(dropped);
  out->station_rms_px = HandEyeStationRmsPx(out->used, out->fit, board);
}

// A refit's RMS (outliers dropped as in the fit itself), or -1 when the refit has no solution
// (degenerate motion after the change).
double RefitRmsPx(const std::vector<HandEyeStation>& stations, const CameraModel& camera, const BoardSpec& board,
                  const HandEyeCheckOptions& options) {
  CheckedHandEye refit;
  refit.limit_px = options.LimitPx();
  refit.used = stations;
  try {
    FitDroppingOutliers(camera, board, options, &refit);
  } catch (const InputError&) {
    return -1.0;
  }
  return std::isfinite(refit.fit.rms_px) ? refit.fit.rms_px : -1.0;
}

// Stations with view i paired to pose i + shift.
std::vector<HandEyeStation> Shifted(const HandEyeCaptures& captures, int shift) {
  std::vector<HandEyeStation> stations;
  const int n = static_cast<int>(captures.T_B_H.size());
  for (int i = 0; i < n; ++i) {
    if (captures.views[i] && i + shift >= 0 && i + shift < n)
      stations.push_back({captures.T_B_H[i + shift], *captures.views[i]});
  }
  return stations;
}

std::vector<HandEyeStation> Transformed(std::vector<HandEyeStation> stations, double translation_scale, bool invert) {
  for (HandEyeStation& s : stations) {
    s.T_B_H.translation() *= translation_scale;
    if (invert) s.T_B_H = s.T_B_H.inverse();
  }
  return stations;
}

// The square edge that best explains the stations: a coarse log grid of unrefined fits (cheap:
// PnP and OpenCV's solver), then a golden-section search of refined fits around the best.
HandEyeAlternative SquareSizeAlternative(const std::vector<HandEyeStation>& stations, const CameraModel& camera,
                                         const BoardSpec& board, const HandEyeCheckOptions& options) {
  HandEyeCheckOptions coarse = options;
  coarse.hand_eye.refine = false;
  double best_log = 0.0, best_rms = std::numeric_limits<double>::infinity();
  for (double log_k = std::log(0.2); log_k <= std::log(5.0); log_k += 0.1) {
    BoardSpec scaled = board;
    scaled.square_m = board.square_m * std::exp(log_k);
    const double rms = RefitRmsPx(stations, camera, scaled, coarse);
    if (rms >= 0.0 && rms < best_rms) best_rms = rms, best_log = log_k;
  }
  const auto refined_rms = [&](double log_k) {
    BoardSpec scaled = board;
    scaled.square_m = board.square_m * std::exp(log_k);
    const double rms = RefitRmsPx(stations, camera, scaled, options);
    return rms < 0.0 ? std::numeric_limits<double>::infinity() : rms;
  };
  const double g = (std::sqrt(5.0) - 1.0) / 2.0;
  double a = best_log - 0.1, b = best_log + 0.1;
  double c = b - g * (b - a), d = a + g * (b - a);
  double fc = refined_rms(c), fd = refined_rms(d);
  for (int i = 0; i < 14; ++i) {  // the bracket shrinks to 0.2 * 0.618^14: 2e-4 of the square
    if (fc < fd) {
      b = d, d = c, fd = fc, c = b - g * (b - a), fc = refined_rms(c);
    } else {
      a = c, c = d, fc = fd, d = a + g * (b - a), fd = refined_rms(d);
    }
  }
  HandEyeAlternative alt;
  alt.mistake = HandEyeMistake::kSquareSize;
  alt.square_m = board.square_m * std::exp(fc < fd ? c : d);
  alt.rms_px = std::min(fc, fd);
  if (!std::isfinite(alt.rms_px)) alt.rms_px = -1.0;
  char text[160];
  std::snprintf(text, sizeof(text), "squares of %.4f m instead of %.4f m", alt.square_m, board.square_m);
  alt.description = text;
  return alt;
}

std::vector<HandEyeAlternative> TryAlternatives(const HandEyeCaptures& captures, const CameraModel& camera,
                                                const BoardSpec& board, const HandEyeCheckOptions& options) {
  const std::vector<HandEyeStation> stations = captures.Stations();
  std::vector<HandEyeAlternative> out;
  const auto add = [&](HandEyeMistake mistake, const std::string& description,
                       const std::vector<HandEyeStation>& refit) {
    out.push_back({mistake, description, 0.0, RefitRmsPx(refit, camera, board, options), false});
  };
  add(HandEyeMistake::kPosesInMillimetres, "pose translations in millimetres (divided by 1000)",
      Transformed(stations, 1e-3, false));
  add(HandEyeMistake::kPosesInMetres, "pose translations in metres (multiplied by 1000)",
      Transformed(stations, 1e3, false));
  add(HandEyeMistake::kInvertedPoses, "inverted poses (base in hand)", Transformed(stations, 1.0, true));
  add(HandEyeMistake::kPairedOneLate, "image i paired with pose i + 1", Shifted(captures, 1));
  add(HandEyeMistake::kPairedOneEarly, "image i paired with pose i - 1", Shifted(captures, -1));
  out.push_back(SquareSizeAlternative(stations, camera, board, options));
  for (HandEyeAlternative& alt : out) alt.fits = alt.rms_px >= 0.0 && alt.rms_px <= options.LimitPx();
  return out;
}

std::string Cause(const std::vector<HandEyeAlternative>& alternatives, double limit_px) {
  const HandEyeAlternative* best = nullptr;
  for (const HandEyeAlternative& alt : alternatives) {
    if (alt.fits && (best == nullptr || alt.rms_px < best->rms_px)) best = &alt;
  }
  char text[200];
  if (best != nullptr) {
    std::snprintf(text, sizeof(text), "the data fit with %s (RMS %.3f px)", best->description.c_str(), best->rms_px);
    return text;
  }
  std::string cause = "none of the usual mistakes explains it (refit RMS:";
  for (const HandEyeAlternative& alt : alternatives) {
    std::snprintf(text, sizeof(text), " %s %.1f px;", alt.description.c_str(), alt.rms_px);
    cause += text;
  }
  std::snprintf(text, sizeof(text), " limit %.3f px)", limit_px);
  return cause + text;
}

}  // namespace

std::vector<HandEyeStation> HandEyeCaptures::Stations() const {
  std::vector<HandEyeStation> stations;
  for (size_t i = 0; i < T_B_H.size() && i < views.size(); ++i) {
    if (views[i]) stations.push_back({T_B_H[i], *views[i]});
  }
  return stations;
}

double HandEyeCheckOptions::LimitPx() const { return std::max(min_limit_px, limit_factor * intrinsics_rms_px); }

std::string CheckedHandEye::StationTable() const {
  std::string table;
  char line[200];
  for (size_t i = 0; i < used.size(); ++i) {
    std::snprintf(line, sizeof(line), "  %-32s %9.3f px\n", used[i].view.name.c_str(), station_rms_px[i]);
    table += line;
  }
  for (const auto& [name, rms] : dropped) {
    std::snprintf(line, sizeof(line), "  %-32s %9.3f px  dropped (outlier)\n", name.c_str(), rms);
    table += line;
  }
  return table;
}

std::vector<double> HandEyeStationRmsPx(const std::vector<HandEyeStation>& stations, const HandEyeResult& fit,
                                        const BoardSpec& board) {
  std::vector<double> rms(stations.size());
  const std::vector<Eigen::Vector3d> corners_K = board.CornersK();
  for (size_t s = 0; s < stations.size(); ++s) {
    const Pose T_C_K = (stations[s].T_B_H * fit.T_H_C).inverse() * fit.T_B_K;
    double sum = 0.0;
    for (size_t i = 0; i < corners_K.size(); ++i) {
      const auto u = fit.camera.Project(T_C_K * corners_K[i]);
      const cv::Point2f& d = stations[s].view.corners_px[i];
      sum += u ? (*u - Eigen::Vector2d(d.x, d.y)).squaredNorm() : 1e6;
    }
    rms[s] = std::sqrt(sum / corners_K.size());
  }
  return rms;
}

CheckedHandEye CalibrateHandEyeChecked(const HandEyeCaptures& captures, const CameraModel& camera,
                                       const BoardSpec& board, const HandEyeCheckOptions& options) {
  if (captures.views.size() != captures.T_B_H.size()) {
    throw InputError("hand-eye", "captures",
                     std::to_string(captures.views.size()) + " images for " + std::to_string(captures.T_B_H.size()) +
                         " poses; each image needs the pose it was taken at");
  }
  CheckedHandEye out;
  out.limit_px = options.LimitPx();
  out.used = captures.Stations();
  FitDroppingOutliers(camera, board, options, &out);
  out.accepted = out.fit.rms_px <= out.limit_px;
  if (!out.accepted) {
    out.alternatives = TryAlternatives(captures, camera, board, options);
    out.cause = Cause(out.alternatives, out.limit_px);
  }
  return out;
}

double FocalChangeFraction(const CameraModel& before, const HandEyeResult& refined_fit) {
  const double f_before = 0.5 * (before.fx + before.fy);
  const double f_after = 0.5 * (refined_fit.camera.fx + refined_fit.camera.fy);
  return (f_after - f_before) / f_before;
}

}  // namespace romunect::calib
