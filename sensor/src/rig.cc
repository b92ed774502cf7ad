#include "romunect/sensor/rig.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <sstream>

#include <Eigen/LU>
#include <nlohmann/json.hpp>

#include "json_fields.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect {
namespace {

using json_fields::Field;
using nlohmann::json;

// A rule broken by a field's value: "field: rule, found value" when shown.
FieldProblem Bad(const std::string& field, const std::string& rule, double value) {
  std::ostringstream s;
  s << rule << ", found " << value;
  return {field, s.str()};
}

bool Finite(std::initializer_list<double> xs) {
  for (double x : xs) {
    if (!std::isfinite(x)) return false;
  }
  return true;
}

// A member's problem as its owner's: the field under `prefix`.
FieldProblem Prefixed(const std::string& prefix, const FieldProblem& problem) {
  return {problem.field.empty() ? prefix : prefix + "." + problem.field, problem.rule};
}

}  // namespace

// ---------------------------------------------------------------- ProjectorModel

std::string ProjectorModel::Problem() const { return Check().ToString(); }

FieldProblem ProjectorModel::Check() const {
  // The projector's image is rendered and stored whole: the image bounds of input_limits.h apply.
  if (width <= 0 || width > kMaxImageSidePx) return Bad("width", "must be in [1, 16384] px", width);
  if (height <= 0 || height > kMaxImageSidePx) return Bad("height", "must be in [1, 16384] px", height);
  if (static_cast<int64_t>(width) * height > kMaxImagePixels) {
    return Bad("width", "width x height must be at most 16777216 px", static_cast<double>(width) * height);
  }
  // Fields of view from ~0.1 to ~179 degrees, as for cameras (camera_model.h).
  const double side_px = std::max(width, height);
  if (!(std::isfinite(fx) && fx >= 0.005 * side_px && fx <= 1000 * side_px)) {
    return Bad("fx", "must be in [0.005, 1000] x the longer side in px", fx);
  }
  if (!(std::isfinite(fy) && fy >= 0.005 * side_px && fy <= 1000 * side_px)) {
    return Bad("fy", "must be in [0.005, 1000] x the longer side in px", fy);
  }
  if (!(Finite({cx}) && std::abs(cx) <= 10 * side_px)) return Bad("cx", "must be within 10 image sizes", cx);
  if (!(Finite({cy}) && std::abs(cy) <= 10 * side_px)) return Bad("cy", "must be within 10 image sizes", cy);
  if (!(std::isfinite(focus_distance_m) && focus_distance_m > 0)) {
    return Bad("focus_distance_m", "must be positive and finite", focus_distance_m);
  }
  if (!(std::isfinite(aperture_m) && aperture_m >= 0 && aperture_m < 0.1)) {
    return Bad("aperture_m", "must be in [0, 0.1) m", aperture_m);
  }
  if (!(std::isfinite(brightness_e_per_s) && brightness_e_per_s >= 0)) {
    return Bad("brightness_e_per_s", "must be non-negative and finite", brightness_e_per_s);
  }
  return {};
}

double ProjectorModel::CircleOfConfusionPx(double depth_m) const {
  return fx * aperture_m * std::abs(1.0 / depth_m - 1.0 / focus_distance_m);
}

std::optional<Eigen::Vector2d> ProjectorModel::Project(const Eigen::Vector3d& p_P) const {
  if (!(p_P.z() > 0.0)) return std::nullopt;
  return Eigen::Vector2d(fx * p_P.x() / p_P.z() + cx, fy * p_P.y() / p_P.z() + cy);
}

cv::Matx33d ProjectorModel::Matrix() const { return {fx, 0, cx, 0, fy, cy, 0, 0, 1}; }

// ---------------------------------------------------------------- CameraOptics

std::string CameraOptics::Problem() const { return Check().ToString(); }

FieldProblem CameraOptics::Check() const {
  if (!(std::isfinite(focus_distance_m) && focus_distance_m > 0)) {
    return Bad("focus_distance_m", "must be positive and finite", focus_distance_m);
  }
  if (!(std::isfinite(aperture_m) && aperture_m >= 0 && aperture_m < 0.1)) {
    return Bad("aperture_m", "must be in [0, 0.1) m", aperture_m);
  }
  if (!(std::isfinite(psf_sigma_px) && psf_sigma_px >= 0 && psf_sigma_px <= 10)) {
    return Bad("psf_sigma_px", "must be in [0, 10]", psf_sigma_px);
  }
  if (!(std::isfinite(exposure_s) && exposure_s > 0 && exposure_s <= 1)) {
    return Bad("exposure_s", "must be in (0, 1] s", exposure_s);
  }
  if (!(std::isfinite(gain_dn_per_e) && gain_dn_per_e > 0)) {
    return Bad("gain_dn_per_e", "must be positive", gain_dn_per_e);
  }
  if (!(std::isfinite(full_well_e) && full_well_e > 0)) {
    return Bad("full_well_e", "must be positive", full_well_e);
  }
  if (!(std::isfinite(read_noise_e) && read_noise_e >= 0)) {
    return Bad("read_noise_e", "must be non-negative", read_noise_e);
  }
  if (!(speckle_contrast >= 0 && speckle_contrast <= 1)) {
    return Bad("speckle_contrast", "must be in [0, 1]", speckle_contrast);
  }
  if (bits < 1 || bits > 16) return Bad("bits", "must be in [1, 16]", bits);
  if (!(std::isfinite(ambient_e_per_s) && ambient_e_per_s >= 0)) {
    return Bad("ambient_e_per_s", "must be non-negative", ambient_e_per_s);
  }
  return {};
}

double CameraOptics::CircleOfConfusionPx(const CameraModel& camera, double depth_m) const {
  return camera.fx * aperture_m * std::abs(1.0 / depth_m - 1.0 / focus_distance_m);
}

// ---------------------------------------------------------------- PatternSpec

const char* PatternKindName(PatternKind kind) {
  switch (kind) {
    case PatternKind::kKinectDots: return "kinect_dots";
    case PatternKind::kDotGrid: return "dot_grid";
    case PatternKind::kFeatureGrid: return "feature_grid";
    case PatternKind::kCheckerboard: return "checkerboard";
    case PatternKind::kUniform: return "uniform";
    case PatternKind::kOff: return "off";
  }
  return "?";
}

std::optional<PatternKind> PatternKindFromName(const std::string& name) {
  for (PatternKind k : {PatternKind::kKinectDots, PatternKind::kDotGrid, PatternKind::kFeatureGrid,
                        PatternKind::kCheckerboard, PatternKind::kUniform, PatternKind::kOff}) {
    if (name == PatternKindName(k)) return k;
  }
  return std::nullopt;
}

std::string PatternSpec::Problem() const { return Check().ToString(); }

FieldProblem PatternSpec::Check() const {
  if (width <= 0 || width > 8192) return Bad("width", "must be in [1, 8192]", width);
  if (height <= 0 || height > 8192) return Bad("height", "must be in [1, 8192]", height);
  if (kind == PatternKind::kKinectDots) {
    if (width % 3 != 0 || width < 30) {
      return Bad("width", "Kinect dots tile 3 x 3: must be a multiple of 3, at least 30", width);
    }
    if (height % 3 != 0 || height < 30) {
      return Bad("height", "Kinect dots tile 3 x 3: must be a multiple of 3, at least 30", height);
    }
  }
  if (!(std::isfinite(dot_fill) && dot_fill > 0 && dot_fill < 0.5)) {
    return Bad("dot_fill", "must be in (0, 0.5)", dot_fill);
  }
  if (!(std::isfinite(dot_level) && dot_level > 0 && dot_level <= 1)) {
    return Bad("dot_level", "must be in (0, 1]", dot_level);
  }
  if (!(std::isfinite(centre_spot_level) && centre_spot_level > 0 && centre_spot_level <= 1)) {
    return Bad("centre_spot_level", "must be in (0, 1]", centre_spot_level);
  }
  if (pitch_px < 2 || pitch_px > std::min(width, height)) {
    return Bad("pitch_px", "must be in [2, min(width, height)]", pitch_px);
  }
  if (!(std::isfinite(min_level) && min_level >= 0 && min_level <= 1)) {
    return Bad("min_level", "must be in [0, 1]", min_level);
  }
  return {};
}

// ---------------------------------------------------------------- ChipGeometry, options

std::string ChipGeometry::Problem() const { return Check().ToString(); }

FieldProblem ChipGeometry::Check() const {
  if (std::string p = camera.Problem(); !p.empty()) return {"camera", p};
  if (FieldProblem p = projector.Check()) return Prefixed("projector", p);
  if (FieldProblem p = pattern.Check()) return Prefixed("pattern", p);
  if (pattern.kind != PatternKind::kKinectDots) return {"pattern.kind", "the chip's reference is kinect_dots"};
  if (pattern.width != projector.width || pattern.height != projector.height) {
    return {"pattern.width", "the reference pattern must be the stock projector's size (" +
                                 std::to_string(projector.width) + " x " + std::to_string(projector.height) +
                                 "), found " + std::to_string(pattern.width) + " x " + std::to_string(pattern.height)};
  }
  if (!(std::isfinite(baseline_m) && baseline_m > 0.001 && baseline_m < 1)) {
    return Bad("baseline_m", "must be in (0.001, 1) m", baseline_m);
  }
  if (!(std::isfinite(reference_distance_m) && reference_distance_m > 0.05)) {
    return Bad("reference_distance_m", "must be above 0.05 m", reference_distance_m);
  }
  if (!(std::isfinite(raw_offset) && raw_offset > 0 && raw_offset < 2047)) {
    return Bad("raw_offset", "must be in (0, 2047)", raw_offset);
  }
  const double raw_ref = raw_offset - 8.0 * FocalTimesBaseline() / reference_distance_m;
  if (!(raw_ref > 0)) {
    return Bad("reference_distance_m", "gives a negative raw value at the reference", reference_distance_m);
  }
  return {};
}

std::string DepthEngineOptions::Problem() const { return Check().ToString(); }

FieldProblem DepthEngineOptions::Check() const {
  if (FieldProblem p = chip.Check()) return Prefixed("chip", p);
  if (window_px < 3 || window_px > 11 || window_px % 2 == 0) {
    return Bad("window_px", "must be odd, in [3, 11] (costs fit 16 bits)", window_px);
  }
  if (search_range_px < 4 || search_range_px > 256) {
    return Bad("search_range_px", "must be in [4, 256]", search_range_px);
  }
  if (min_shift_px < -256 || min_shift_px > 256) {
    return Bad("min_shift_px", "must be in [-256, 256]", min_shift_px);
  }
  if (subpixel_steps != 8) return Bad("subpixel_steps", "the chip reports 1/8 px: must be 8", subpixel_steps);
  if (!(subpixel_equiangular_weight >= 0 && subpixel_equiangular_weight <= 1)) {
    return Bad("subpixel_equiangular_weight", "must be in [0, 1]", subpixel_equiangular_weight);
  }
  if (!(subpixel_rounding_slope >= 0 && subpixel_rounding_slope <= 4)) {
    return Bad("subpixel_rounding_slope", "must be in [0, 4]", subpixel_rounding_slope);
  }
  if (!(subpixel_quarter_correction >= -0.5 && subpixel_quarter_correction <= 0.5)) {
    return Bad("subpixel_quarter_correction", "must be in [-0.5, 0.5] (the map stays monotone)",
               subpixel_quarter_correction);
  }
  if (!(subpixel_eighth_correction >= -0.5 && subpixel_eighth_correction <= 0.5)) {
    return Bad("subpixel_eighth_correction", "must be in [-0.5, 0.5] (the map stays monotone)",
               subpixel_eighth_correction);
  }
  if (!(std::isfinite(min_texture) && min_texture >= 0)) return Bad("min_texture", "must be >= 0", min_texture);
  if (!(std::isfinite(max_cost) && max_cost > 0)) return Bad("max_cost", "must be positive", max_cost);
  if (!(std::isfinite(uniqueness) && uniqueness >= 0 && uniqueness < 1)) {
    return Bad("uniqueness", "must be in [0, 1)", uniqueness);
  }
  if (prefilter_px < 3 || prefilter_px > 31 || prefilter_px % 2 == 0) {
    return Bad("prefilter_px", "must be odd, in [3, 31]", prefilter_px);
  }
  if (threads < 1 || threads > 256) return Bad("threads", "must be in [1, 256]", threads);
  // Raw values of the whole search must fit the 11-bit output.
  const double raw_ref = chip.raw_offset - 8.0 * chip.FocalTimesBaseline() / chip.reference_distance_m;
  const double raw_max = raw_ref - 8.0 * min_shift_px;
  const double raw_min = raw_ref - 8.0 * (min_shift_px + search_range_px - 1);
  if (raw_max > 2046 || raw_min < 0) {
    std::ostringstream s;
    s << "shifts [" << min_shift_px << ", " << min_shift_px + search_range_px << ") give raw values [" << raw_min
      << ", " << raw_max << "], outside the 11-bit range [0, 2046]";
    return {"search_range_px", s.str()};
  }
  if (FieldProblem p = disparity_distortion.Check()) return Prefixed("disparity_distortion", p);
  // A real chip's fixed pattern is a few codes; beyond 8 px it would move matches out of the search.
  if (const double worst = disparity_distortion.WorstCaseCodes(raw_min); worst > 64) {
    return Bad("disparity_distortion",
               "4 x pattern_rms_codes and |corner_codes|, each times its factor at the search's smallest raw "
               "value, must be at most 64 raw codes (8 px) together",
               worst);
  }
  return {};
}

// ---------------------------------------------------------------- Rig

std::string Rig::Problem() const { return Check().ToString(); }

FieldProblem Rig::Check() const {
  if (std::string p = camera.Problem(); !p.empty()) return {"camera", p};
  if (FieldProblem p = optics.Check()) return Prefixed("optics", p);
  if (FieldProblem p = projector.Check()) return Prefixed("projector", p);
  if (FieldProblem p = pattern.Check()) return Prefixed("pattern", p);
  if (FieldProblem p = depth_engine.Check()) return Prefixed("depth_engine", p);
  Eigen::Matrix4d m = T_C_P.matrix();
  if (std::string p = RigidityProblem(m); !p.empty()) return {"T_C_P", p};
  const Eigen::Vector3d t = T_C_P.translation();
  if (t.z() < -0.02) return Bad("T_C_P", "projector behind the camera (centre z in C must be >= -0.02 m)", t.z());
  if (T_C_P.linear()(2, 2) < 0.5) {
    return Bad("T_C_P", "projector must look forward (its z axis within 60 degrees of the camera's)",
               T_C_P.linear()(2, 2));
  }
  if (t.norm() < 0.005) return Bad("T_C_P", "baseline must be at least 5 mm", t.norm());
  if (t.norm() > 1.0) return Bad("T_C_P", "baseline must be at most 1 m (a hand-held sensor)", t.norm());
  if (!H_P_rec.allFinite() || std::abs(H_P_rec.determinant()) < 1e-12) {
    return {"H_P_rec", "must be a finite, invertible 3x3 matrix"};
  }
  const CameraModel& chip_camera = depth_engine.chip.camera;
  if (camera.width != chip_camera.width || camera.height != chip_camera.height) {
    return {"camera", "image size " + std::to_string(camera.width) + " x " + std::to_string(camera.height) +
                          " differs from the depth chip's " + std::to_string(chip_camera.width) + " x " +
                          std::to_string(chip_camera.height)};
  }
  if (!(std::isfinite(frame_rate_hz) && frame_rate_hz > 0 && frame_rate_hz <= 1000)) {
    return Bad("frame_rate_hz", "must be in (0, 1000]", frame_rate_hz);
  }
  return {};
}

namespace {

ChipGeometry StockChip() {
  ChipGeometry chip;
  chip.camera = CameraModel{};
  chip.camera.fx = chip.camera.fy = 580.0;
  chip.camera.cx = 319.5;
  chip.camera.cy = 239.5;
  chip.projector = ProjectorModel{};  // 792 x 594, f = 580: one pattern pixel ~ one camera pixel
  chip.projector.aperture_m = 0.0;    // the reference is stored sharp
  chip.pattern = PatternSpec{};
  return chip;
}

Rig KinectV1() {
  Rig rig;
  rig.name = "kinect-v1";
  rig.depth_engine.chip = StockChip();
  rig.camera = rig.depth_engine.chip.camera;
  rig.optics = CameraOptics{};
  // A fast fixed-focus IR lens: near targets blur in the camera (much of the noise at 0.5 m).
  rig.optics.aperture_m = 0.0045;
  rig.optics.focus_distance_m = 2.0;
  // The laser's speckle: code noise of about 0.55 raw units on any plane (docs/fidelity.md).
  rig.optics.speckle_contrast = 0.18;
  // The laser's DOE keeps the pattern sharp from ~0.5 m on: a tiny effective aperture.
  rig.projector = rig.depth_engine.chip.projector;
  rig.projector.focus_distance_m = 2.0;
  rig.projector.aperture_m = 0.0015;
  rig.projector.brightness_e_per_s = 9.6e5;
  rig.T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.075, 0, 0));
  rig.pattern = rig.depth_engine.chip.pattern;
  rig.H_P_rec = Eigen::Matrix3d::Identity();
  // 0.43 m .. 7.4 m (raw 286 .. 1046): the stock range needs more than the default 64 px.
  rig.depth_engine.min_shift_px = -38;
  rig.depth_engine.search_range_px = 96;
  // The real chip keeps a plane valid from 0.55 to 6 m: it accepts the faint dots of far
  // surfaces and the blurred, speckled ones of near surfaces.
  rig.depth_engine.min_texture = 1.5;
  rig.depth_engine.max_cost = 32.0;
  // Its blurred (near), speckled and faint (far) pattern rounds the cost's minimum: mostly V,
  // more parabola the rounder the minimum.
  rig.depth_engine.subpixel_equiangular_weight = 0.92;
  rig.depth_engine.subpixel_rounding_slope = 0.33;
  rig.depth_engine.subpixel_quarter_correction = 0.0625;
  rig.depth_engine.subpixel_eighth_correction = 0.03;
  // The stock unit's fixed-pattern error after its own raw-to-depth mapping.
  rig.depth_engine.disparity_distortion = KinectV1DisparityDistortion();
  return rig;
}

Rig Romunect() {
  Rig rig;
  rig.name = "romunect";
  rig.depth_engine.chip = StockChip();
  // C-mount lens: 6.0 cm across 640 px at 200 mm.
  rig.camera = CameraModel{};
  rig.camera.fx = rig.camera.fy = 2133.0;
  rig.camera.cx = 319.5;
  rig.camera.cy = 239.5;
  rig.optics = CameraOptics{};
  rig.optics.focus_distance_m = 0.2;
  rig.optics.aperture_m = 0.002;
  rig.optics.ambient_e_per_s = 4000.0;
  // DLP pico projector, toed in 14 degrees so its axis meets the camera's at 200 mm.
  rig.projector.width = 1280;
  rig.projector.height = 720;
  rig.projector.fx = rig.projector.fy = 2900.0;
  rig.projector.cx = 639.5;
  rig.projector.cy = 359.5;
  rig.projector.focus_distance_m = 0.206;
  rig.projector.aperture_m = 0.004;
  rig.projector.brightness_e_per_s = 6.0e3;
  const double baseline_m = 0.05;
  const double toe_rad = -std::atan2(baseline_m, 0.2);
  rig.T_C_P = MakePose(Eigen::AngleAxisd(toe_rad, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                       Eigen::Vector3d(baseline_m, 0, 0));
  rig.pattern = rig.depth_engine.chip.pattern;
  rig.depth_engine.min_shift_px = -32;
  rig.depth_engine.search_range_px = 64;
  // Within its focused range the pattern is sharp: a stricter match threshold costs no valid
  // pixels and rejects the false matches at the image borders (true match off the reference).
  rig.depth_engine.max_cost = 20.0;
  rig.depth_engine.subpixel_equiangular_weight = 0.96;  // its codes' phases spread evenly
  rig.depth_engine.subpixel_rounding_slope = 0.085;
  rig.depth_engine.subpixel_quarter_correction = 0.075;
  rig.depth_engine.subpixel_eighth_correction = 0.04;
  rig.H_P_rec = IdealPrewarp(rig, 0.2);
  return rig;
}

}  // namespace

Rig RigPreset(const std::string& name) {
  Rig rig;
  if (name == "romunect") {
    rig = Romunect();
  } else if (name == "kinect-v1") {
    rig = KinectV1();
  } else {
    throw InputError("rig preset", name, "unknown preset; expected romunect or kinect-v1");
  }
  ROMUNECT_CHECK_MSG(rig.Problem().empty(), rig.Problem().c_str());
  return rig;
}

Eigen::Matrix3d IdealPrewarp(const Rig& rig, double plane_distance_m) {
  const ChipGeometry& chip = rig.depth_engine.chip;
  // Pattern pixel -> the stock camera's pixel on the reference plane (parallel axes, pure
  // translation along x): u = f_c/f_p (x - cx_p) + cx_c + f_c b / Z_ref.
  const double sx = chip.camera.fx / chip.projector.fx, sy = chip.camera.fy / chip.projector.fy;
  Eigen::Matrix3d A;
  A << sx, 0, chip.camera.cx - sx * chip.projector.cx + chip.FocalTimesBaseline() / chip.reference_distance_m, 0, sy,
      chip.camera.cy - sy * chip.projector.cy, 0, 0, 1;
  // Camera pixel -> point on the plane z = Z -> projector pixel: K_P (Z R_P_C + t_P_C e3^T) K_C^-1.
  Eigen::Matrix3d K_C;
  K_C << rig.camera.fx, 0, rig.camera.cx, 0, rig.camera.fy, rig.camera.cy, 0, 0, 1;
  Eigen::Matrix3d K_P;
  K_P << rig.projector.fx, 0, rig.projector.cx, 0, rig.projector.fy, rig.projector.cy, 0, 0, 1;
  const Pose T_P_C = rig.T_C_P.inverse();
  Eigen::Matrix3d M = plane_distance_m * T_P_C.linear();
  M.col(2) += T_P_C.translation();
  Eigen::Matrix3d H = K_P * M * K_C.inverse() * A;
  return H / H(2, 2);
}

// ---------------------------------------------------------------- JSON

namespace {

json CameraJson(const CameraModel& c) {
  return {{"width", c.width}, {"height", c.height},        {"fx", c.fx}, {"fy", c.fy}, {"cx", c.cx},
          {"cy", c.cy},       {"distortion", c.distortion}};
}

CameraModel ReadCamera(const Field& f) {
  CameraModel c;
  c.width = f["width"].Int();
  c.height = f["height"].Int();
  c.fx = f["fx"].Number();
  c.fy = f["fy"].Number();
  c.cx = f["cx"].Number();
  c.cy = f["cy"].Number();
  c.distortion = f["distortion"].Numbers<5>();
  if (c.fx <= 0) f["fx"].Fail("focal length must be positive, found " + std::to_string(c.fx));
  if (c.fy <= 0) f["fy"].Fail("focal length must be positive, found " + std::to_string(c.fy));
  if (std::string p = c.Problem(); !p.empty()) f.Fail(p);
  return c;
}

json ProjectorJson(const ProjectorModel& p) {
  return {{"width", p.width},
          {"height", p.height},
          {"fx", p.fx},
          {"fy", p.fy},
          {"cx", p.cx},
          {"cy", p.cy},
          {"focus_distance_m", p.focus_distance_m},
          {"aperture_m", p.aperture_m},
          {"brightness_e_per_s", p.brightness_e_per_s}};
}

// A Check() finding as an InputError on its field under f.
[[noreturn]] void FailProblem(const Field& f, const FieldProblem& problem) {
  if (problem.field.empty()) f.Fail(problem.rule);
  throw InputError(f.source(), f.path().empty() ? problem.field : f.path() + "." + problem.field, problem.rule);
}

ProjectorModel ReadProjector(const Field& f) {
  ProjectorModel p;
  p.width = f["width"].Int();
  p.height = f["height"].Int();
  p.fx = f["fx"].Number();
  p.fy = f["fy"].Number();
  p.cx = f["cx"].Number();
  p.cy = f["cy"].Number();
  p.focus_distance_m = f["focus_distance_m"].Number();
  p.aperture_m = f["aperture_m"].Number();
  p.brightness_e_per_s = f["brightness_e_per_s"].Number();
  if (const FieldProblem problem = p.Check()) FailProblem(f, problem);
  return p;
}

json OpticsJson(const CameraOptics& o) {
  return {{"focus_distance_m", o.focus_distance_m},
          {"aperture_m", o.aperture_m},
          {"psf_sigma_px", o.psf_sigma_px},
          {"exposure_s", o.exposure_s},
          {"gain_dn_per_e", o.gain_dn_per_e},
          {"full_well_e", o.full_well_e},
          {"read_noise_e", o.read_noise_e},
          {"shot_noise", o.shot_noise},
          {"speckle_contrast", o.speckle_contrast},
          {"bits", o.bits},
          {"ambient_e_per_s", o.ambient_e_per_s}};
}

CameraOptics ReadOptics(const Field& f) {
  CameraOptics o;
  o.focus_distance_m = f["focus_distance_m"].Number();
  o.aperture_m = f["aperture_m"].Number();
  o.psf_sigma_px = f["psf_sigma_px"].Number();
  o.exposure_s = f["exposure_s"].Number();
  o.gain_dn_per_e = f["gain_dn_per_e"].Number();
  o.full_well_e = f["full_well_e"].Number();
  o.read_noise_e = f["read_noise_e"].Number();
  o.shot_noise = f["shot_noise"].Bool();
  if (f.Has("speckle_contrast")) o.speckle_contrast = f["speckle_contrast"].Number();
  o.bits = f["bits"].Int();
  o.ambient_e_per_s = f["ambient_e_per_s"].Number();
  if (const FieldProblem problem = o.Check()) FailProblem(f, problem);
  return o;
}

json PatternJson(const PatternSpec& p) {
  return {{"kind", PatternKindName(p.kind)},
          {"width", p.width},
          {"height", p.height},
          {"seed", p.seed},
          {"dot_fill", p.dot_fill},
          {"centre_spot_level", p.centre_spot_level},
          {"dot_level", p.dot_level},
          {"pitch_px", p.pitch_px},
          {"min_level", p.min_level}};
}

PatternSpec ReadPattern(const Field& f) {
  PatternSpec p;
  const std::string kind = f["kind"].String();
  const auto k = PatternKindFromName(kind);
  if (!k)
    f["kind"].Fail("unknown pattern '" + kind +
                   "'; expected kinect_dots, dot_grid, feature_grid, checkerboard, uniform or off");
  p.kind = *k;
  p.width = f["width"].Int();
  p.height = f["height"].Int();
  const Field seed = f["seed"];
  if (!seed.value().is_number_unsigned()) seed.Fail("expected a non-negative integer");
  p.seed = seed.value().get<uint64_t>();
  p.dot_fill = f["dot_fill"].Number();
  p.centre_spot_level = f["centre_spot_level"].Number();
  p.dot_level = f["dot_level"].Number();
  p.pitch_px = f["pitch_px"].Int();
  p.min_level = f["min_level"].Number();
  if (const FieldProblem problem = p.Check()) FailProblem(f, problem);
  return p;
}

json DistortionJson(const DisparityDistortion& d) {
  return {{"seed", d.seed},
          {"alpha0", d.alpha0},
          {"alpha1", d.alpha1},
          {"pattern_rms_codes", d.pattern_rms_codes},
          {"pattern_scale_px", d.pattern_scale_px},
          {"corner_codes", d.corner_codes},
          {"pattern_alpha0", d.pattern_alpha0},
          {"pattern_alpha1", d.pattern_alpha1}};
}

DisparityDistortion ReadDistortion(const Field& f) {
  DisparityDistortion d;
  const Field seed = f["seed"];
  if (!seed.value().is_number_unsigned()) seed.Fail("expected a non-negative integer");
  d.seed = seed.value().get<uint64_t>();
  d.alpha0 = f["alpha0"].Number();
  d.alpha1 = f["alpha1"].Number();
  d.pattern_rms_codes = f["pattern_rms_codes"].Number();
  d.pattern_scale_px = f["pattern_scale_px"].Number();
  d.corner_codes = f["corner_codes"].Number();
  // Optional: absent, the random part decays as the radial one (the published model).
  d.pattern_alpha0 = f.Has("pattern_alpha0") ? f["pattern_alpha0"].Number() : d.alpha0;
  d.pattern_alpha1 = f.Has("pattern_alpha1") ? f["pattern_alpha1"].Number() : d.alpha1;
  if (const FieldProblem problem = d.Check()) FailProblem(f, problem);
  return d;
}

json EngineJson(const DepthEngineOptions& o) {
  const ChipGeometry& c = o.chip;
  return {{"chip",
           {{"camera", CameraJson(c.camera)},
            {"projector", ProjectorJson(c.projector)},
            {"pattern", PatternJson(c.pattern)},
            {"baseline_m", c.baseline_m},
            {"reference_distance_m", c.reference_distance_m},
            {"raw_offset", c.raw_offset}}},
          {"window_px", o.window_px},
          {"min_shift_px", o.min_shift_px},
          {"search_range_px", o.search_range_px},
          {"subpixel_steps", o.subpixel_steps},
          {"subpixel_equiangular_weight", o.subpixel_equiangular_weight},
          {"subpixel_rounding_slope", o.subpixel_rounding_slope},
          {"subpixel_quarter_correction", o.subpixel_quarter_correction},
          {"subpixel_eighth_correction", o.subpixel_eighth_correction},
          {"min_texture", o.min_texture},
          {"max_cost", o.max_cost},
          {"uniqueness", o.uniqueness},
          {"prefilter_px", o.prefilter_px},
          {"threads", o.threads},
          {"disparity_distortion", DistortionJson(o.disparity_distortion)}};
}

DepthEngineOptions ReadEngine(const Field& f) {
  DepthEngineOptions o;
  const Field c = f["chip"];
  o.chip.camera = ReadCamera(c["camera"]);
  o.chip.projector = ReadProjector(c["projector"]);
  o.chip.pattern = ReadPattern(c["pattern"]);
  o.chip.baseline_m = c["baseline_m"].Number();
  o.chip.reference_distance_m = c["reference_distance_m"].Number();
  o.chip.raw_offset = c["raw_offset"].Number();
  o.window_px = f["window_px"].Int();
  o.min_shift_px = f["min_shift_px"].Int();
  o.search_range_px = f["search_range_px"].Int();
  o.subpixel_steps = f["subpixel_steps"].Int();
  if (f.Has("subpixel_equiangular_weight")) o.subpixel_equiangular_weight = f["subpixel_equiangular_weight"].Number();
  if (f.Has("subpixel_rounding_slope")) o.subpixel_rounding_slope = f["subpixel_rounding_slope"].Number();
  if (f.Has("subpixel_quarter_correction")) o.subpixel_quarter_correction = f["subpixel_quarter_correction"].Number();
  if (f.Has("subpixel_eighth_correction")) o.subpixel_eighth_correction = f["subpixel_eighth_correction"].Number();
  o.min_texture = f["min_texture"].Number();
  o.max_cost = f["max_cost"].Number();
  o.uniqueness = f["uniqueness"].Number();
  o.prefilter_px = f["prefilter_px"].Int();
  o.threads = f["threads"].Int();
  if (f.Has("disparity_distortion")) o.disparity_distortion = ReadDistortion(f["disparity_distortion"]);
  if (const FieldProblem problem = o.Check()) FailProblem(f, problem);
  return o;
}

}  // namespace

void SaveRig(const std::filesystem::path& path, const Rig& rig) {
  ROMUNECT_CHECK_MSG(rig.Problem().empty(), rig.Problem().c_str());
  json H = json::array();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) H.push_back(rig.H_P_rec(r, c));
  }
  const json doc = {
      {"name", rig.name},
      {"frame_rate_hz", rig.frame_rate_hz},
      {"camera", CameraJson(rig.camera)},
      {"optics", OpticsJson(rig.optics)},
      {"projector", ProjectorJson(rig.projector)},
      {"T_C_P", PoseToRowMajor(rig.T_C_P)},
      {"pattern", PatternJson(rig.pattern)},
      {"H_P_rec", H},
      {"depth_engine", EngineJson(rig.depth_engine)},
  };
  WriteTextAtomically(path, doc.dump(2) + "\n");
}

Rig LoadRig(const std::filesystem::path& path) {
  const json doc = json_fields::ParseFile(path);
  const Field root(doc, path.string(), "");
  Rig rig;
  rig.name = root["name"].String();
  rig.frame_rate_hz = root["frame_rate_hz"].PositiveNumber();
  rig.camera = ReadCamera(root["camera"]);
  rig.optics = ReadOptics(root["optics"]);
  rig.projector = ReadProjector(root["projector"]);
  {
    const Field f = root["T_C_P"];
    const std::array<double, 16> numbers = f.Numbers<16>();
    Eigen::Matrix4d m;
    for (int i = 0; i < 16; ++i) m(i / 4, i % 4) = numbers[i];
    if (std::string problem = RigidityProblem(m); !problem.empty()) {
      f.Fail("not a rigid transform (row-major 4x4 expected): " + problem);
    }
    rig.T_C_P = PoseFromRowMajor(numbers);
  }
  rig.pattern = ReadPattern(root["pattern"]);
  {
    const std::array<double, 9> h = root["H_P_rec"].Numbers<9>();
    for (int i = 0; i < 9; ++i) rig.H_P_rec(i / 3, i % 3) = h[i];
  }
  rig.depth_engine = ReadEngine(root["depth_engine"]);
  if (const FieldProblem problem = rig.Check()) FailProblem(root, problem);
  return rig;
}

}  // namespace romunect
