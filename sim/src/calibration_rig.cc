#include "romunect/sim/calibration_rig.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "romunect/sensor/check.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/world.h"

namespace romunect::sim {
namespace {

constexpr const char* kSource = "calibration rig";
constexpr int kPlateId = 3000;
constexpr int kSceneId = 1000;
// Plate margins around the board (m): room for tilted views and the reference area's
// footprint (6.3 x 4.7 cm at 210 mm, more when tilted).
constexpr double kPlateMarginM = 0.03;
// The romunect calibration that CalibrationRigOptionsFor scales (CalibrationRigOptions' defaults).
constexpr double kRomunectWorkingDistanceM = 0.2;
constexpr double kRomunectFocalPx = 2133.0;
// The reference area's centre from the board's: both where the arm reaches; the area overlaps
// the board's edge, which the depth planes' views (~1 m wide) barely see.
constexpr double kLongRangeReferenceOffsetM = 0.7;
// The distance a long-range rig is calibrated at: as far as the arm holds the camera above the
// table (shoulder 0.4 m up, reach ~0.9 m), clear of a long range's near end.
constexpr double kLongRangeWorkingM = 0.79;
constexpr double kDepthPlaneSpan = 0.15;  // depth planes within +-15 % of the working distance
constexpr IrMaterial kWhite{0.8f, 0.0f, 50.0f};
constexpr IrMaterial kBlack{0.04f, 0.0f, 50.0f};

void AddQuad(TriangleMesh* mesh, double x0, double y0, double x1, double y1) {
  if (!(x1 > x0 && y1 > y0)) return;
  const int base = static_cast<int>(mesh->vertices_O.size());
  for (const auto& [x, y] : {std::pair{x0, y0}, std::pair{x1, y0}, std::pair{x1, y1}, std::pair{x0, y1}}) {
    mesh->vertices_O.emplace_back(static_cast<float>(x), static_cast<float>(y), 0.0f);
  }
  mesh->triangles.emplace_back(base, base + 1, base + 2);
  mesh->triangles.emplace_back(base, base + 2, base + 3);
}

// The plate in K: board squares (i, j) for i in [-1, cols], j in [-1, rows], square (-1, -1)
// black; white everywhere else out to the margins and the reference area along +x.
void MakePlate(const calib::BoardSpec& board, bool print_board, double reference_offset_m, double reference_half_m,
               TriangleMesh* white, TriangleMesh* black) {
  const double kReferenceHalfM = reference_half_m;
  const double s = board.square_m;
  const double bx0 = -s, by0 = -s, bx1 = board.cols * s, by1 = board.rows * s;
  const double cx = board.CentreK().x(), cy = board.CentreK().y();
  const double x0 = bx0 - kPlateMarginM, y0 = std::min(by0 - kPlateMarginM, cy - kReferenceHalfM);
  const double x1 = std::max(bx1 + kPlateMarginM, cx + reference_offset_m + kReferenceHalfM);
  const double y1 = std::max(by1 + kPlateMarginM, cy + kReferenceHalfM);
  // white frame around the board region (four rectangles), then the squares
  AddQuad(white, x0, y0, x1, by0);
  AddQuad(white, x0, by1, x1, y1);
  AddQuad(white, x0, by0, bx0, by1);
  AddQuad(white, bx1, by0, x1, by1);
  for (int j = -1; j <= board.rows; ++j) {
    for (int i = -1; i <= board.cols; ++i) {
      const bool dark = print_board && (i + j) % 2 == 0;
      AddQuad(dark ? black : white, i * s, j * s, (i + 1) * s, (j + 1) * s);
    }
  }
}

// A pose moved by exactly angle_rad about a random axis and distance_m in a random direction.
Pose Perturb(const Pose& T, double angle_rad, double distance_m, std::mt19937_64* rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(n(*rng), n(*rng), n(*rng)).normalized();
  const Eigen::Vector3d dir = Eigen::Vector3d(n(*rng), n(*rng), n(*rng)).normalized();
  return MakePose(Eigen::AngleAxisd(angle_rad, axis).toRotationMatrix() * T.linear(),
                  T.translation() + distance_m * dir);
}

TriangleMesh ToTriangleMesh(const Mesh& mesh) {
  TriangleMesh out;
  for (const auto& v : mesh.vertices) out.vertices_O.push_back(v.cast<float>());
  out.triangles = mesh.triangles;
  return out;
}

}  // namespace

std::string CalibrationRigOptions::Problem() const {
  std::ostringstream s;
  const std::string rig_problem = rig.Problem(), board_problem = board.Problem();
  if (!rig_problem.empty()) {
    s << "rig." << rig_problem;
  } else if (!board_problem.empty()) {
    s << "board." << board_problem;
  } else if (board_samples < 1 || board_samples % 2 == 0 || board_samples > 7) {
    s << "board_samples = " << board_samples << ": must be odd, 1..7";
  } else if (threads < 1 || threads > 256) {
    s << "threads = " << threads << ": must be 1..256";
  } else if (!(lamp_e_per_s > 0)) {
    s << "lamp_e_per_s = " << lamp_e_per_s << ": must be positive";
  } else if (!(reference_offset_m > 0) || !(reference_half_m > 0)) {
    s << "reference_offset_m, reference_half_m = " << reference_offset_m << ", " << reference_half_m
      << ": must be positive";
  } else if (!(working_distance_m >= 0)) {
    s << "working_distance_m = " << working_distance_m << ": must be >= 0 (0 = the focus distance)";
  } else if (!(mount_error_rad >= 0 && mount_error_m >= 0 && plate_error_rad >= 0 && plate_error_m >= 0 &&
               projector_error_rad >= 0 && projector_error_m >= 0 && focal_error >= 0 && focal_error < 0.5 &&
               principal_error_px >= 0)) {
    s << "nominal errors must be >= 0 (focal_error < 0.5)";
  } else if (!plate_origin_W.allFinite() || !std::isfinite(plate_yaw_rad)) {
    s << "plate_origin_W, plate_yaw_rad: must be finite";
  }
  return s.str();
}

CalibrationRigOptions CalibrationRigOptionsFor(const Rig& rig) {
  CalibrationRigOptions o;
  o.rig = rig;
  const DepthRange range = MeasurableDepthRange(rig, 0.7);
  // A long range is calibrated at its near end: the arm (shoulder 0.4 m above the table, reach
  // ~0.9 m) holds a camera there over the table.
  const double working_m = std::min(0.5 * (range.near_m + range.far_m), range.near_m);
  // Lengths in the image stay the romunect's: scale by (distance / focal length).
  double k = (working_m / rig.camera.fx) / (kRomunectWorkingDistanceM / kRomunectFocalPx);
  if (std::abs(k - 1.0) < 0.1) return o;  // the romunect's own calibration
  // A long range's near end is where its chip loses the pattern's edges (few valid pixels on a
  // plane): calibrate a little further out, where the arm still holds the camera above the table.
  const double long_working_m = std::min(0.5 * (range.near_m + range.far_m), std::max(range.near_m, kLongRangeWorkingM));
  k *= long_working_m / working_m;
  o.working_distance_m = long_working_m;
  o.board.square_m = std::max(0.001, std::round(o.board.square_m * k * 1e3) * 1e-3);
  // The reference area fills the view at the far depth plane, tilted; it lies beside the board.
  const double far_m = CalibrationDepthRange(o).far_m;
  o.reference_half_m = 0.6 * far_m * rig.camera.width / rig.camera.fx;
  // Beside the robot, where the arm holds the camera ~0.9 m above the table: the board centred
  // at (0.22, 0.3) in W, the reference area towards -x, clear of the bin (x > 0.38). The plate
  // is yawed as the romunect's (K's x along -W's x, K's y along W's y), so the board's centre
  // (cx, cy in K) lies at (-cx, +cy) from K's origin.
  o.reference_offset_m = kLongRangeReferenceOffsetM;
  const Eigen::Vector2d board_centre_W(0.22, 0.25);
  const Eigen::Vector3d centre_K = o.board.CentreK();
  o.plate_origin_W = Eigen::Vector3d(board_centre_W.x() + centre_K.x(), board_centre_W.y() - centre_K.y(), 0.001);
  return o;
}

DepthRange CalibrationDepthRange(const CalibrationRigOptions& options) {
  const DepthRange range = MeasurableDepthRange(options.rig, 0.7);
  const double working_m = options.WorkingDistanceM();
  return {std::max(range.near_m, (1.0 - kDepthPlaneSpan) * working_m),
          std::min(range.far_m, (1.0 + kDepthPlaneSpan) * working_m)};
}

struct SimulatedCalibrationRig::Impl {
  CalibrationRigOptions options;
  std::unique_ptr<World> world;
  calib::CalibrationSetup setup;
  Pose T_W_K;
  embree::RayScene scene;
  std::vector<embree::GeometryRenderer> renderers;  // one per sub-pixel offset (keeps ray tables)
  embree::RenderOptions render_options;
  GeometryBuffer geometry, layer_buffer;
  IrSynthesizer synthesizer;
  std::unique_ptr<DepthEngine> engine;
  DepthEngineOutput output;
  cv::Mat truth_depth;
  int captures = 0, moves = 0;
  // IK seeds: the scene's start pose, then every pose reached so far (latest first)
  std::vector<World::ArmVector> seeds;
  Pose projected_T_W_C = Pose::Identity();  // camera of the last CaptureProjectedIr

  // Renders the current view: samples x samples sub-pixel rays per pixel (layer 0 the centre).
  void Render(int samples) {
    const Rig& rig = options.rig;
    const Pose T_W_C = world->T_W_C();
    if (samples == 1) {
      renderers[0].Render(scene, rig.camera, T_W_C, rig.T_C_P, render_options, &geometry);
    } else {
      geometry.layers.clear();
      geometry.materials = scene.materials();
      for (int k = 0; k < samples * samples; ++k) {
        // centre first; the others on a regular grid of 1/samples px
        const int idx = (k + samples * samples / 2) % (samples * samples);
        const double dx = ((idx % samples) + 0.5) / samples - 0.5, dy = ((idx / samples) + 0.5) / samples - 0.5;
        CameraModel shifted = rig.camera;  // pixel u of `shifted` sees the ray through u + d
        shifted.cx -= dx;
        shifted.cy -= dy;
        renderers[k].Render(scene, shifted, T_W_C, rig.T_C_P, render_options, &layer_buffer);
        GeometryLayer layer = layer_buffer.layers[0];
        layer.p_C = layer.p_C.clone();
        layer.normal_C = layer.normal_C.clone();
        layer.material = layer.material.clone();
        layer.object_id = layer.object_id.clone();
        layer.lit = layer.lit.clone();
        layer.pixel_offset_px = Eigen::Vector2f(static_cast<float>(dx), static_cast<float>(dy));
        geometry.layers.push_back(std::move(layer));
      }
    }
    truth_depth = embree::GroundTruthDepth(geometry);
  }

  cv::Mat Synthesize(const Rig& rig) {
    cv::Mat ir;
    synthesizer.Synthesize(rig, geometry, options.seed * 1000003ull + static_cast<uint64_t>(captures), &ir, nullptr);
    ++captures;
    return ir;
  }

  cv::Mat Raw(const Eigen::Matrix3d& H) {
    Render(1);
    Rig rig = options.rig;
    rig.H_P_rec = H;
    engine->Compute(Synthesize(rig), &output);
    return output.raw.clone();
  }
};

SimulatedCalibrationRig::SimulatedCalibrationRig(const CalibrationRigOptions& options)
    : impl_(std::make_unique<Impl>()) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  Impl& s = *impl_;
  s.options = options;
  WorldOptions w;
  w.T_C_P = options.rig.T_C_P;
  s.world = std::make_unique<World>(w);
  s.seeds.push_back(s.world->arm_q());
  // the plate: K's z into the plate (down), x along W's x turned by the yaw
  const Eigen::Matrix3d R_W_K = Eigen::AngleAxisd(options.plate_yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                                Eigen::Vector3d(1, -1, -1).asDiagonal();
  s.T_W_K = MakePose(R_W_K, options.plate_origin_W);
  TriangleMesh white, black;
  MakePlate(options.board, options.print_board, options.reference_offset_m, options.reference_half_m, &white, &black);
  s.scene.AddStatic(white, s.T_W_K, kWhite, kPlateId);
  if (!black.triangles.empty()) s.scene.AddStatic(black, s.T_W_K, kBlack, kPlateId);
  // the scene's fixed geoms (table, bin) around it; the arm stays behind the camera
  std::vector<Pose> T_W_G;
  s.world->GeomPoses(&T_W_G);
  const auto& geoms = s.world->Geoms();
  for (size_t i = 0; i < geoms.size(); ++i) {
    if (geoms[i].moving || geoms[i].arm) continue;
    const TriangleMesh mesh = ToTriangleMesh(geoms[i].mesh_G);
    if (mesh.Problem().empty()) s.scene.AddStatic(mesh, T_W_G[i], geoms[i].material, kSceneId);
  }
  s.scene.Commit();
  s.renderers.resize(options.board_samples * options.board_samples);
  s.render_options.threads = options.threads;
  s.render_options.focus_distance_m = options.rig.optics.focus_distance_m;
  IrSynthesisOptions synthesis;
  synthesis.threads = options.threads;
  s.synthesizer = IrSynthesizer(synthesis);
  DepthEngineOptions engine = options.rig.depth_engine;
  engine.threads = options.threads;
  s.engine = std::make_unique<DepthEngine>(engine);

  // nominal knowledge: the truth off by the stated errors (seeded)
  std::mt19937_64 rng(options.seed);
  calib::CalibrationSetup& n = s.setup;
  n.nominal_rig = options.rig;
  std::uniform_int_distribution<int> sign(0, 1);
  const double focal_scale = 1.0 + (sign(rng) ? 1 : -1) * options.focal_error;
  n.nominal_rig.camera.fx *= focal_scale;
  n.nominal_rig.camera.fy *= focal_scale;
  const double angle = std::uniform_real_distribution<double>(0.0, 2 * M_PI)(rng);
  n.nominal_rig.camera.cx += options.principal_error_px * std::cos(angle);
  n.nominal_rig.camera.cy += options.principal_error_px * std::sin(angle);
  n.nominal_rig.T_C_P = Perturb(options.rig.T_C_P, options.projector_error_rad, options.projector_error_m, &rng);
  n.T_H_C_nominal = Perturb(s.world->T_H_C(), options.mount_error_rad, options.mount_error_m, &rng);
  n.T_B_K_nominal = Perturb(TruthT_B_K(), options.plate_error_rad, options.plate_error_m, &rng);
  n.board = options.board;
  n.reference_centre_K = options.board.CentreK() + Eigen::Vector3d(options.reference_offset_m, 0, 0);
}

SimulatedCalibrationRig::~SimulatedCalibrationRig() = default;

const calib::CalibrationSetup& SimulatedCalibrationRig::setup() const { return impl_->setup; }
int SimulatedCalibrationRig::captures() const { return impl_->captures; }
int SimulatedCalibrationRig::moves() const { return impl_->moves; }
const cv::Mat& SimulatedCalibrationRig::last_truth_depth_m() const { return impl_->truth_depth; }
const Rig& SimulatedCalibrationRig::TruthRig() const { return impl_->options.rig; }
double SimulatedCalibrationRig::working_distance_m() const { return impl_->options.WorkingDistanceM(); }
Pose SimulatedCalibrationRig::TruthT_H_C() const { return impl_->world->T_H_C(); }
Pose SimulatedCalibrationRig::TruthT_B_K() const { return impl_->world->T_W_B().inverse() * impl_->T_W_K; }

std::optional<Pose> SimulatedCalibrationRig::MoveHand(const Pose& T_B_H) {
  World& world = *impl_->world;
  const Pose T_W_goal = world.T_W_B() * T_B_H;
  // from the current joints, then from the start pose and the poses reached before (a far
  // move can need another branch; damped steps can stall at a joint limit)
  IkOptions options;
  options.max_iterations = 1000;  // long moves from a far seed converge slowly near limits
  IkResult ik = SolveIk(world, ArmSite::kHand, T_W_goal, world.arm_q(), options);
  for (auto seed = impl_->seeds.rbegin(); !ik.converged && seed != impl_->seeds.rend(); ++seed) {
    ik = SolveIk(world, ArmSite::kHand, T_W_goal, *seed, options);
  }
  if (!ik.converged) return std::nullopt;
  world.SetArmQ(ik.q);
  impl_->seeds.push_back(ik.q);
  ++impl_->moves;
  return world.T_B_H();  // what the robot reports: its executed pose
}

cv::Mat SimulatedCalibrationRig::CaptureLampIr() {
  Impl& s = *impl_;
  s.Render(s.options.board_samples);
  Rig rig = s.options.rig;
  rig.pattern.kind = PatternKind::kOff;
  rig.optics.ambient_e_per_s = s.options.lamp_e_per_s;
  return s.Synthesize(rig);
}

cv::Mat SimulatedCalibrationRig::CaptureProjectedIr(const PatternSpec& pattern, const Eigen::Matrix3d& H) {
  Impl& s = *impl_;
  s.Render(1);
  s.projected_T_W_C = s.world->T_W_C();
  Rig rig = s.options.rig;
  rig.pattern = pattern;
  rig.H_P_rec = H;
  return s.Synthesize(rig);
}

cv::Mat SimulatedCalibrationRig::CaptureRaw(const Eigen::Matrix3d& H) { return impl_->Raw(H); }

double SimulatedCalibrationRig::TrueHomographyResidualPx(const Eigen::Matrix3d& H,
                                                         const std::vector<Eigen::Vector2d>& pattern,
                                                         const std::vector<Eigen::Vector2d>& target, int* used) const {
  ROMUNECT_CHECK(pattern.size() == target.size());
  const Rig& rig = impl_->options.rig;
  const Pose T_C_K = impl_->projected_T_W_C.inverse() * impl_->T_W_K;
  double sum = 0.0;
  int n = 0;
  for (size_t i = 0; i < pattern.size(); ++i) {
    const Eigen::Vector2d q = (H * pattern[i].homogeneous()).hnormalized();
    const auto u = calib::ProjectorPixelToCamera(rig, rig.camera, T_C_K, q);
    if (!u) continue;
    sum += (*u - target[i]).squaredNorm();
    ++n;
  }
  if (used) *used = n;
  return n > 0 ? std::sqrt(sum / n) : -1.0;
}

std::vector<PlaneDepthError> SimulatedCalibrationRig::EvaluateDepth(const std::vector<DepthCorrection>& corrections,
                                                                    const ChipGeometry& chip, const Eigen::Matrix3d& H,
                                                                    double distance_m, double tilt_rad) {
  Impl& s = *impl_;
  const Eigen::Matrix3d R_K_C = Eigen::AngleAxisd(tilt_rad, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Pose T_K_C = MakePose(R_K_C, s.setup.reference_centre_K - distance_m * R_K_C.col(2));
  if (!MoveHand(TruthT_B_K() * T_K_C * TruthT_H_C().inverse())) return {};
  const cv::Mat raw = s.Raw(H);
  std::vector<PlaneDepthError> out;
  for (const DepthCorrection& correction : corrections) {
    const cv::Mat depth = ApplyDepthCorrection(correction, raw, chip);
    PlaneDepthError e;
    e.distance_m = distance_m;
    e.tilt_rad = tilt_rad;
    double sum = 0.0, sum2 = 0.0;
    int n = 0;
    for (int y = 0; y < depth.rows; ++y) {
      for (int x = 0; x < depth.cols; ++x) {
        const float d = depth.at<float>(y, x), t = s.truth_depth.at<float>(y, x);
        if (!(d > 0) || !(t > 0)) continue;
        sum += d - t;
        sum2 += (d - t) * static_cast<double>(d - t);
        ++n;
      }
    }
    e.valid_fraction = static_cast<double>(n) / depth.total();
    e.mean_m = n > 0 ? sum / n : 0.0;
    e.rms_m = n > 0 ? std::sqrt(sum2 / n) : 0.0;
    out.push_back(e);
  }
  return out;
}

ChainTruthErrors CompareWithTruth(SimulatedCalibrationRig* rig, const calib::ChainResult& result) {
  ROMUNECT_CHECK(rig != nullptr);
  const calib::Calibration& c = result.calibration;
  ChainTruthErrors e;
  e.mapping = calib::FullImageMappingError(c.camera, rig->TruthRig().camera);
  e.mapping_uncompensated = calib::FullImageMappingError(c.camera, rig->TruthRig().camera, 8, false);
  e.mapping_zhang = calib::FullImageMappingError(result.intrinsics.camera, rig->TruthRig().camera);
  e.hand_eye = ComparePoses(c.T_H_C, rig->TruthT_H_C());
  e.hand_eye_initial = ComparePoses(result.hand_eye.T_H_C_initial, rig->TruthT_H_C());
  e.board = ComparePoses(c.T_B_K, rig->TruthT_B_K());
  const CameraModel& truth_camera = rig->TruthRig().camera;
  if (!result.hand_eye_stations.empty()) {
    calib::HandEyeOptions known;  // the chain's hand-eye step, camera given and kept
    known.refine_intrinsics = false;
    e.hand_eye_known_intrinsics =
        ComparePoses(calib::CalibrateHandEye(result.hand_eye_stations, truth_camera, rig->setup().board, known).T_H_C,
                     rig->TruthT_H_C());
  }
  double sum2 = 0.0;
  int n = 0;
  for (int y = 0; y < truth_camera.height; y += 16) {
    for (int x = 0; x < truth_camera.width; x += 16) {
      const Eigen::Vector2d u(x, y);
      const Eigen::Vector3d est = c.T_H_C.linear() * c.camera.Ray(u).normalized();
      const Eigen::Vector3d truth = rig->TruthT_H_C().linear() * truth_camera.Ray(u).normalized();
      const double angle = std::atan2(est.cross(truth).norm(), est.dot(truth));
      sum2 += angle * angle;
      e.line_of_sight_max_rad = std::max(e.line_of_sight_max_rad, angle);
      ++n;
    }
  }
  e.line_of_sight_rms_rad = std::sqrt(sum2 / n);
  e.homography_px = rig->TrueHomographyResidualPx(c.H_P_rec, result.homography_pattern, result.homography_target,
                                                  &e.homography_points);
  const double focus_m = rig->working_distance_m();
  double exact2 = 0.0, affine2 = 0.0;
  for (const auto& [distance_m, tilt_rad] : {std::pair{focus_m - 0.005, 0.0}, std::pair{focus_m, 0.0},
                                             std::pair{focus_m + 0.005, 0.0}, std::pair{focus_m, 0.1}}) {
    const std::vector<PlaneDepthError> planes = rig->EvaluateDepth({result.depth.inverse, result.depth.affine}, c.chip,
                                                                   c.H_P_rec, distance_m, tilt_rad);
    if (planes.empty()) continue;
    e.depth_exact.push_back(planes[0]);
    e.depth_affine.push_back(planes[1]);
    exact2 += planes[0].rms_m * planes[0].rms_m;
    affine2 += planes[1].rms_m * planes[1].rms_m;
  }
  if (!e.depth_exact.empty()) {
    e.depth_rms_m = std::sqrt(exact2 / e.depth_exact.size());
    e.depth_affine_rms_m = std::sqrt(affine2 / e.depth_exact.size());
  }
  return e;
}

}  // namespace romunect::sim
