// The hand-eye step on real-data input at 1920 x 1080: rendered 9x6 board images (4x
// supersampled, true camera known) and a pose file, through `calibrate hand-eye --images --poses
// --refine-intrinsics` in-process, with an intrinsics file whose focal length is 0.1 % short (what
// weakly tilted intrinsics views give). Sets of 15 and 30 stations, one with a station pair
// rotated past 120 deg, one with weak tilt. Prints the error against the truth (goal: 0.01 deg,
// 0.3 mm) and the held-out error (fit on even stations, reproject odd) beside OpenCV's five
// calibrateHandEye solvers on the same corners. Then the time of one step.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>

#include <opencv2/imgcodecs.hpp>

#include "romunect/calib/calibration_file.h"
#include "romunect/calib/hand_eye_check.h"
#include "romunect/calib/intrinsics.h"
#include "romunect/tools/jobs/calibrate.h"
#include "synthetic.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using namespace romunect::calib;
constexpr double kDeg = M_PI / 180.0;

CameraModel Camera1080p() {
  CameraModel c;
  c.width = 1920, c.height = 1080;
  c.fx = 1450.0, c.fy = 1450.0, c.cx = 958.3, c.cy = 543.1;  // distortion-free: the renderer is a homography
  return c;
}

struct SetSpec {
  const char* label;
  int stations;
  double max_tilt_rad, max_roll_rad;
  unsigned seed;
};

fs::path WriteSet(const SetSpec& spec, const CameraModel& camera, const BoardSpec& board, testing::HandEyeRig* rig) {
  *rig = testing::MakeHandEyeRig(camera, board, spec.stations, 0.0, spec.max_tilt_rad, spec.max_roll_rad, spec.seed);
  const fs::path dir = fs::temp_directory_path() / ("romunect_he1080_" + std::to_string(spec.seed));
  fs::remove_all(dir);
  fs::create_directories(dir / "images");
  std::ofstream poses(dir / "poses.txt");
  for (size_t i = 0; i < rig->stations.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "img_%02zu.png", i);
    cv::imwrite((dir / "images" / name).string(), testing::RenderBoardImage(camera, board, rig->T_C_K_truth[i]));
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) poses << std::setprecision(17) << rig->stations[i].T_B_H.matrix()(r, c) << ' ';
    }
    poses << '\n';
  }
  Calibration intrinsics;
  intrinsics.camera = camera;
  intrinsics.camera.fx *= 0.999, intrinsics.camera.fy *= 0.999;  // weak views: focal 0.1 % short
  intrinsics.residuals.intrinsics_rms_px = 0.05;
  SaveCalibration(dir / "intrinsics.yaml", intrinsics);
  return dir;
}

double HeldOutRms(const std::vector<HandEyeStation>& stations, const HandEyeResult& fit, const BoardSpec& board) {
  double sum = 0.0;
  const std::vector<double> per = HandEyeStationRmsPx(stations, fit, board);
  for (double v : per) sum += v * v;
  return std::sqrt(sum / per.size());
}

void Table() {
  const CameraModel camera = Camera1080p();
  const BoardSpec board{9, 6, 0.02};  // fits the 1080-row image at any roll from 0.3 m
  const SetSpec sets[] = {{"15 stations", 15, 0.5, 0.8, 31},
                          {"30 stations", 30, 0.5, 0.8, 32},
                          {"20 st., pair > 120 deg", 20, 0.5, 150 * kDeg, 33},
                          {"20 st., weak tilt", 20, 0.15, 0.8, 34}};
  std::printf("%-24s %9s %9s %10s | held-out RMS px: %8s %8s %8s %8s %8s %8s\n", "set", "err deg", "err mm", "max pair",
              "ours", "tsai", "park", "horaud", "andreff", "daniil.");
  for (const SetSpec& spec : sets) {
    testing::HandEyeRig rig;
    const fs::path dir = WriteSet(spec, camera, board, &rig);
    jobs::HandEyeStepOptions o;
    o.images = (dir / "images").string();
    o.poses.log = (dir / "poses.txt").string();
    o.intrinsics = (dir / "intrinsics.yaml").string();
    o.file.output = (dir / "out.yaml").string();
    o.square_m = board.square_m;
    o.refine_intrinsics = true;
    std::fflush(stdout);
    const Calibration c = jobs::RunHandEyeStep(o);
    const PoseError e = ComparePoses(c.T_H_C, rig.T_H_C);
    // held out: the detected corners of the images, fit on even, reprojected on odd
    const CameraModel start = LoadCalibration(o.intrinsics).camera;
    HandEyeCaptures even, odd;
    const std::vector<fs::path> files = ListBoardImages(o.images);
    for (size_t i = 0; i < files.size(); ++i) {
      std::string reason;
      auto corners = DetectBoard(cv::imread(files[i].string(), cv::IMREAD_UNCHANGED), board, &reason);
      HandEyeCaptures& into = i % 2 == 0 ? even : odd;
      into.T_B_H.push_back(rig.stations[i].T_B_H);
      into.views.push_back(corners ? std::optional<BoardView>(BoardView{files[i].filename(), *corners}) : std::nullopt);
    }
    HandEyeCheckOptions options;
    options.hand_eye.refine_intrinsics = true;
    options.intrinsics_rms_px = 0.05;
    const CheckedHandEye ours = CalibrateHandEyeChecked(even, start, board, options);
    double max_pair_rad = 0.0;  // over all stations of the set
    for (const HandEyeStation& a : rig.stations) {
      for (const HandEyeStation& b : rig.stations) {
        max_pair_rad = std::max(max_pair_rad,
                                Eigen::AngleAxisd(a.T_B_H.linear().transpose() * b.T_B_H.linear()).angle());
      }
    }
    std::printf("%-24s %9.4f %9.4f %9.1f  | %26.4f", spec.label, e.angle_rad / kDeg, e.translation_m * 1e3,
                max_pair_rad / kDeg, HeldOutRms(odd.Stations(), ours.fit, board));
    for (const OpenCvHandEyeResult& r : OpenCvHandEyeAll(even.Stations(), start, board)) {
      std::printf(" %8.4f", HeldOutRms(odd.Stations(), r.fit, board));
    }
    std::printf("\n");
    fs::remove_all(dir);
  }
}

void BM_HandEyeStep1080p20Images(benchmark::State& state) {
  const CameraModel camera = Camera1080p();
  const BoardSpec board{9, 6, 0.02};  // fits the 1080-row image at any roll from 0.3 m
  testing::HandEyeRig rig;
  const fs::path dir = WriteSet({"bench", 20, 0.5, 0.8, 40}, camera, board, &rig);
  jobs::HandEyeStepOptions o;
  o.images = (dir / "images").string();
  o.poses.log = (dir / "poses.txt").string();
  o.intrinsics = (dir / "intrinsics.yaml").string();
  o.file.output = (dir / "out.yaml").string();
  o.file.overwrite_worse = true;
  o.square_m = board.square_m;
  o.refine_intrinsics = true;
  for (auto _ : state) benchmark::DoNotOptimize(jobs::RunHandEyeStep(o));
  fs::remove_all(dir);
}
BENCHMARK(BM_HandEyeStep1080p20Images)->Unit(benchmark::kSecond)->Iterations(1);

}  // namespace
}  // namespace romunect

int main(int argc, char** argv) {
  romunect::Table();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
