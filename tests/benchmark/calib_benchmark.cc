// calib's accuracy table (docs/calibrate.md) over seeded synthetic trials, median / p95 / max, against
// OpenCV 4.6 alone, then the goal table of the whole chain IN THE LOOP with the simulated rig
// (sim/calibration_rig.h; 20 views, 15 stations, 12 planes) over seeded trials, with its
// compute time, then Google Benchmark timings of each step.
//   calib_benchmark [--trials=N] [--loop-trials=N] [benchmark flags]
// Synthetic truth as in tests/calib (synthetic.h): corner noise 0.2 px per coordinate.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/calib/intrinsics.h"
#include "romunect/calib/projector_homography.h"
#include "synthetic.h"
#ifdef ROMUNECT_CALIB_LOOP
#include "romunect/calib/chain.h"
#include "romunect/sensor/errors.h"
#include "romunect/sim/calibration_rig.h"
#include "romunect/sim/scanner.h"
#endif

namespace romunect::calib {
namespace {

constexpr double kDeg = M_PI / 180.0;
constexpr double kNoisePx = 0.2;
int g_trials = 20;
int g_loop_trials = 5;

BoardSpec Board() { return {9, 6, 0.025}; }

struct Stats {
  double median, p95, max;
};
Stats Summarize(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  auto at = [&](double q) { return v[std::min(v.size() - 1, static_cast<size_t>(std::ceil(q * v.size())) - 1)]; };
  return {at(0.5), at(0.95), v.back()};
}
void Row(const char* step, const char* method, const char* unit, const std::vector<double>& values) {
  const Stats s = Summarize(values);
  std::printf("| %-34s | %-34s | %8.4f | %8.4f | %8.4f | %-4s |\n", step, method, s.median, s.p95, s.max, unit);
}

std::vector<BoardView> Observe(const CameraModel& camera, const std::vector<Pose>& T_C_K, std::mt19937* rng) {
  std::vector<BoardView> views;
  for (const Pose& T : T_C_K) {
    if (auto v = testing::ObserveBoard(camera, Board(), T, kNoisePx, rng)) views.push_back(*v);
  }
  return views;
}

void IntrinsicsTable() {
  const CameraModel truth = testing::TruthCamera();
  std::vector<double> planned, weak, planned_raw;
  IntrinsicsOptions options;
  options.holdout_folds = 0;
  for (int t = 0; t < g_trials; ++t) {
    std::mt19937 rng(1000 + t);
    ViewPlanOptions plan;
    plan.distance_m = 0.3;
    plan.seed = 1000 + t;
    std::vector<Pose> T_C_K;
    for (const Pose& T_K_C : PlanViews(truth, Board(), plan)) T_C_K.push_back(T_K_C.inverse());
    const IntrinsicsResult a = CalibrateIntrinsics(Observe(truth, T_C_K, &rng), Board(), {640, 480}, options);
    planned.push_back(FullImageMappingError(a.camera, truth).rms_px);
    planned_raw.push_back(FullImageMappingError(a.camera, truth, 8, false).rms_px);
    const IntrinsicsResult b = CalibrateIntrinsics(
        Observe(truth, testing::CentralViews(truth, Board(), 20, 0.3, &rng), &rng), Board(), {640, 480}, options);
    weak.push_back(FullImageMappingError(b.camera, truth).rms_px);
  }
  Row("intrinsics, 20 views (goal <= 0.25)", "planned views + calibrateCamera", "px", planned);
  Row("  same, no rotation compensation", "planned views + calibrateCamera", "px", planned_raw);
  Row("  weak coverage", "central views, calibrateCamera", "px", weak);
}

void HandEyeTable(const char* label, double max_roll_rad) {
  const CameraModel camera = testing::TruthCamera();
  std::vector<double> ours_deg, ours_mm, tsai_deg, tsai_mm, park_deg, park_mm;
  for (int t = 0; t < g_trials; ++t) {
    const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 15, kNoisePx, 0.5, max_roll_rad, 2000 + t);
    const PoseError ours = ComparePoses(CalibrateHandEye(rig.stations, camera, Board()).T_H_C, rig.T_H_C);
    const PoseError tsai = ComparePoses(OpenCvHandEye(rig.stations, camera, Board(), HandEyeInitialMethod::kTsai),
                                        rig.T_H_C);
    const PoseError park = ComparePoses(OpenCvHandEye(rig.stations, camera, Board(), HandEyeInitialMethod::kPark),
                                        rig.T_H_C);
    ours_deg.push_back(ours.angle_rad / kDeg);
    ours_mm.push_back(ours.translation_m * 1e3);
    tsai_deg.push_back(tsai.angle_rad / kDeg);
    tsai_mm.push_back(tsai.translation_m * 1e3);
    park_deg.push_back(park.angle_rad / kDeg);
    park_mm.push_back(park.translation_m * 1e3);
  }
  const std::string step = std::string("hand-eye 15 st., ") + label;
  Row(step.c_str(), "ours: guard + Ceres (goal 0.02)", "deg", ours_deg);
  Row("", "ours: guard + Ceres (goal 0.15)", "mm", ours_mm);
  Row("", "OpenCV 4.6 Tsai alone", "deg", tsai_deg);
  Row("", "OpenCV 4.6 Tsai alone", "mm", tsai_mm);
  Row("", "OpenCV 4.6 Park alone", "deg", park_deg);
  Row("", "OpenCV 4.6 Park alone", "mm", park_mm);
}

void HomographyTable() {
  const testing::ProjectorScene scene;
  std::vector<double> residual, captures;
  for (int t = 0; t < g_trials; ++t) {
    std::mt19937 rng(3000 + t);
    std::normal_distribution<double> noise(0.0, kNoisePx);
    auto observe = [&](const Eigen::Matrix3d& H) {
      std::vector<cv::Point2f> detected;
      for (const Eigen::Vector2d& x : scene.pattern_P) {
        const Eigen::Vector2d u = scene.Map((H * x.homogeneous()).hnormalized());
        detected.emplace_back(static_cast<float>(u.x() + noise(rng)), static_cast<float>(u.y() + noise(rng)));
      }
      return detected;
    };
    const ProjectorHomographyResult r = CalibrateProjectorHomography(scene.pattern_P, scene.target_C, scene.camera,
                                                                     Eigen::Matrix3d::Identity(), observe);
    residual.push_back(scene.TrueResidualPx(r.H_P_rec));
    captures.push_back(r.captures);
  }
  Row("projector homography (goal <= 0.1)", "Ceres LM loop, true residual", "px", residual);
  Row("", "captures used (goal <= 5)", "", captures);
}

std::vector<PlaneCapture> PlaneCaptures(const CameraModel& camera, int count, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> tilt(-0.15, 0.15);
  std::vector<PlaneCapture> captures;
  const testing::RawDepthTruth truth;
  for (int i = 0; i < count; ++i) {
    const Pose T_C_K = testing::PlaneAt(0.19 + 0.02 * i / (count - 1), tilt(rng), tilt(rng));
    captures.push_back({testing::RenderPlaneRaw(camera, truth, T_C_K, 0.3, &rng), T_C_K});
  }
  return captures;
}

double HeldOutRms(const CameraModel& camera, const DepthCorrection& model, const std::vector<PlaneCapture>& fresh) {
  double sum = 0.0;
  size_t n = 0;
  for (const PlaneCapture& c : fresh) {
    const cv::Mat depth = ApplyDepthCorrection(model, c.raw, StockChipGeometry()), gt = PlaneDepth(camera, c.T_C_K);
    for (int r = 0; r < depth.rows; ++r) {
      for (int k = 0; k < depth.cols; ++k) {
        if (depth.at<float>(r, k) == 0.0f) continue;
        const double e = depth.at<float>(r, k) - gt.at<float>(r, k);
        sum += e * e;
        ++n;
      }
    }
  }
  return std::sqrt(sum / n);
}

void DepthTable() {
  const CameraModel camera = testing::Scaled(testing::TruthCamera(), 0.25);  // 160 x 120: per-pixel cost only
  std::vector<double> exact, affine;
  for (int t = 0; t < g_trials; ++t) {
    const DepthCorrectionResult fit = FitDepthCorrection(camera, PlaneCaptures(camera, 12, 4000 + t));
    const std::vector<PlaneCapture> fresh = PlaneCaptures(camera, 5, 5000 + t);
    exact.push_back(HeldOutRms(camera, fit.inverse, fresh) * 1e3);
    affine.push_back(HeldOutRms(camera, fit.affine, fresh) * 1e3);
  }
  Row("depth, 0.19-0.21 m, held-out planes", "exact: 1/Z affine in raw (goal 0.1)", "mm", exact);
  Row("", "paper eq. 3: affine in chip depth", "mm", affine);
}

// --- timings (the machine is shared: read CPU time, medians over repetitions) ---

void BM_Intrinsics20Views(benchmark::State& state) {
  const CameraModel truth = testing::TruthCamera();
  std::mt19937 rng(1);
  ViewPlanOptions plan;
  plan.distance_m = 0.3;
  std::vector<Pose> T_C_K;
  for (const Pose& T : PlanViews(truth, Board(), plan)) T_C_K.push_back(T.inverse());
  const std::vector<BoardView> views = Observe(truth, T_C_K, &rng);
  IntrinsicsOptions options;
  options.holdout_folds = static_cast<int>(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(CalibrateIntrinsics(views, Board(), {640, 480}, options));
}
BENCHMARK(BM_Intrinsics20Views)->Arg(0)->Arg(5)->Unit(benchmark::kMillisecond);

void BM_HandEye20Stations(benchmark::State& state) {
  const CameraModel camera = testing::TruthCamera();
  const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 20, kNoisePx, 0.5, 0.8, 1);
  for (auto _ : state) benchmark::DoNotOptimize(CalibrateHandEye(rig.stations, camera, Board()));
}
BENCHMARK(BM_HandEye20Stations)->Unit(benchmark::kMillisecond);

void BM_DepthCorrection640x480(benchmark::State& state) {
  const CameraModel camera = testing::TruthCamera();
  const std::vector<PlaneCapture> captures = PlaneCaptures(camera, static_cast<int>(state.range(0)), 1);
  for (auto _ : state) benchmark::DoNotOptimize(FitDepthCorrection(camera, captures));
}
BENCHMARK(BM_DepthCorrection640x480)->Arg(20)->Unit(benchmark::kMillisecond);

void BM_ProjectorHomographyStep(benchmark::State& state) {
  const testing::ProjectorScene scene;
  ProjectorCapture capture;
  for (const Eigen::Vector2d& x : scene.pattern_P) {
    const Eigen::Vector2d u = scene.Map(x);
    capture.detected_px.emplace_back(static_cast<float>(u.x()), static_cast<float>(u.y()));
  }
  for (auto _ : state) {
    benchmark::DoNotOptimize(SolveProjectorHomography(scene.pattern_P, scene.target_C, {capture}, scene.camera));
  }
}
BENCHMARK(BM_ProjectorHomographyStep)->Unit(benchmark::kMillisecond);

#ifdef ROMUNECT_CALIB_LOOP
// The chain in the loop with the default simulated rig, seeds 1..N: every goal in docs/calibrate.md's accuracy table.
void LoopTable() {
  std::vector<double> mapping, he_deg, he_mm, known_deg, known_mm, sight_deg, homography, captures, depth, affine,
      compute, hardware;
  std::vector<std::string> failed;
  for (int seed = 1; seed <= g_loop_trials; ++seed) {
    try {
      sim::CalibrationRigOptions rig_options;
      rig_options.seed = static_cast<uint64_t>(seed);
      sim::SimulatedCalibrationRig rig(rig_options);
      ChainOptions options;
      options.seed = static_cast<unsigned>(seed);
      const sim::DepthRange range = sim::MeasurableDepthRange(rig.TruthRig(), 0.7);
      options.depth_near_m = range.near_m;
      options.depth_far_m = range.far_m;
      const ChainResult r = RunCalibrationChain(&rig, options);
      const sim::ChainTruthErrors e = sim::CompareWithTruth(&rig, r);
      mapping.push_back(e.mapping.rms_px);
      he_deg.push_back(e.hand_eye.angle_rad / kDeg);
      he_mm.push_back(1e3 * e.hand_eye.translation_m);
      known_deg.push_back(e.hand_eye_known_intrinsics.angle_rad / kDeg);
      known_mm.push_back(1e3 * e.hand_eye_known_intrinsics.translation_m);
      sight_deg.push_back(e.line_of_sight_rms_rad / kDeg);
      homography.push_back(e.homography_px);
      captures.push_back(r.homography.captures);
      depth.push_back(1e3 * e.depth_rms_m);
      affine.push_back(1e3 * e.depth_affine_rms_m);
      compute.push_back(r.times.ComputeS());
      hardware.push_back(r.times.hardware_s);
    } catch (const InputError& e) {
      failed.push_back("seed " + std::to_string(seed) + ": " + e.what());
    }
  }
  for (const std::string& f : failed) std::printf("in the loop, FAILED %s\n", f.c_str());
  if (mapping.empty()) return;
  const char* m = "in the loop, simulated rig";
  Row("intrinsics 20 views: mapping (<=0.25)", m, "px", mapping);
  Row("hand-eye 15 st., known K (<=0.02)", "same captures, true camera", "deg", known_deg);
  Row("hand-eye 15 st., known K (<=0.15)", "same captures, true camera", "mm", known_mm);
  Row("hand-eye end to end: T_H_C alone", "estimated intrinsics", "deg", he_deg);
  Row("hand-eye end to end: T_H_C alone", "estimated intrinsics", "mm", he_mm);
  Row("hand-eye end to end: lines of sight", "T_H_C with its camera", "deg", sight_deg);
  Row("homography residual (<=0.1)", m, "px", homography);
  Row("homography captures (<=5)", m, "", captures);
  Row("depth RMS in focus (<=0.1)", "exact model, planes -5..+5 mm", "mm", depth);
  Row("depth RMS in focus", "paper's affine model", "mm", affine);
  Row("chain compute (<2 s)", m, "s", compute);
  Row("simulated hardware (not compute)", "render, IR, depth engine, IK", "s", hardware);
}
#endif

}  // namespace
}  // namespace romunect::calib

int main(int argc, char** argv) {
  std::vector<char*> rest;
  for (int i = 0; i < argc; ++i) {
    if (std::strncmp(argv[i], "--trials=", 9) == 0) {
      romunect::calib::g_trials = std::max(1, std::atoi(argv[i] + 9));
    } else if (std::strncmp(argv[i], "--loop-trials=", 14) == 0) {
      romunect::calib::g_loop_trials = std::max(0, std::atoi(argv[i] + 14));
    } else {
      rest.push_back(argv[i]);
    }
  }
  std::printf("calib accuracy over %d seeded trials (synthetic truth, corner noise %.1f px per coordinate)\n",
              romunect::calib::g_trials, romunect::calib::kNoisePx);
  std::printf("| %-34s | %-34s | %8s | %8s | %8s | %-4s |\n", "step", "method", "median", "p95", "max", "unit");
  std::printf("|%s|%s|%s|%s|%s|%s|\n", std::string(36, '-').c_str(), std::string(36, '-').c_str(),
              std::string(10, '-').c_str(), std::string(10, '-').c_str(), std::string(10, '-').c_str(),
              std::string(6, '-').c_str());
  romunect::calib::IntrinsicsTable();
  romunect::calib::HandEyeTable("rolls +-46 deg", 0.8);
  romunect::calib::HandEyeTable("rolls +-150 deg (>120 pairs)", 150 * M_PI / 180);
  romunect::calib::HomographyTable();
  romunect::calib::DepthTable();
#ifdef ROMUNECT_CALIB_LOOP
  std::fflush(stdout);
  if (romunect::calib::g_loop_trials > 0) romunect::calib::LoopTable();
#endif
  std::fflush(stdout);
  int rest_argc = static_cast<int>(rest.size());
  benchmark::Initialize(&rest_argc, rest.data());
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
