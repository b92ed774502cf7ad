// What `romunect scan` reports and writes into its run folder (besides frames/, written as the
// scan goes): fused_depth.exr/.png, fused_points.ply, gt_height.exr, figure2.png (two single
// depth maps beside the fused one, like the paper's figure 2), overview.png, completeness.png,
// report.json and report.html (self-contained: pictures inlined, no network).
#pragma once

#include <ctime>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/frame.h"
#include "romunect/sim/pick.h"
#include "romunect/sim/scanner.h"
#include "romunect/tools/jobs/perturbation.h"

namespace romunect::jobs {

// The scan's options (defaults as `romunect scan --help` shows them): the report records them,
// so a run says how to repeat it.
struct ScanJobOptions {
  std::string scene, saved_scene, rig = "romunect", calibration, out;  // out "": runs/scan-<date>-<time>
  uint32_t seed = 1;
  int objects = 12;                // 0 only with meshes
  std::vector<std::string> kinds;  // the pile's kinds (GeneratedKindFromName); empty: all five
  bool one_layer = false;          // the pile in one layer (sim::PileOptions::one_layer)
  int threads = 2;
  int samples = 1;
  double voxel_m = 0.25e-3;
  bool ideal_depth = false;
  bool compress_frames = false;
  bool write_frames = true;  // false: no frames/ (experiments that only need the report)
  std::string sweep = "coverage";
  std::vector<std::string> meshes;  // user meshes added to the pile, one object each
  double mesh_unit_m = 1e-3;
  std::string mesh_material = "bright";
  std::string perturb;  // injected calibration errors (perturbation.h); "" none
  // Continue the interrupted run in `out` (its <out>.incomplete) from its last complete frame:
  // the same bytes as an uninterrupted run, with the finished frames' images read, not imaged.
  bool resume = false;
};

// Keeps two single depth maps of the scan for figure 2: the first one with a useful share of
// valid pixels (far frames lie outside the focused depth range and hold almost nothing) and the
// latest one.
struct SampleDepths {
  static constexpr double kMinValidFraction = 0.05;
  cv::Mat first_m, last_m;
  int first_index = -1, last_index = -1;
  void Offer(const Frame& frame, double valid_fraction) {
    if (first_index < 0 && valid_fraction >= kMinValidFraction) {
      first_m = frame.depth_m.clone();
      first_index = frame.index;
    } else if (first_index >= 0) {
      last_m = frame.depth_m;  // a scanned frame's images are its own (sim/scanner.h, ScanWork)
      last_index = frame.index;
    }
  }
};

struct ScanReport {
  ScanJobOptions options;
  std::time_t started_at = 0;
  std::string scan_description, rig_name, depth_correction;
  uint32_t seed = 0;
  int objects = 0, samples = 0;

  // The fusion part as `romunect fuse` reports it (fusion/outputs.h): frames, bad frames,
  // threads, the grid's geometry, insert and extract times, stats, completeness per frame,
  // the metrics against ground truth (always set by the scan) and memory.
  fusion::FusionReport fusion;
  std::vector<double> completeness_each_ms, valid_fraction_per_frame;
  SampleDepths sample_depths;
  // write_s: the frame directory's writer thread; wait_s: fusion waiting for the simulator;
  // loop_cpu_s: the process's CPU time (all threads) during the loop: with loop_wall_s it says
  // how busy the cores were.
  double write_s = 0.0, wait_s = 0.0, loop_wall_s = 0.0, loop_cpu_s = 0.0, total_wall_s = 0.0;

  // What fusion believed against the truth: the injected errors (perturbation.h) and the
  // resulting calibration's errors against the rig's truth, beside the map's errors (fusion).
  std::string perturbation = "none";
  CalibrationErrors calibration_errors;

  // The fusion box's heights (W z, m) and, from ground truth, the cells whose surface lies above
  // or below it (what fusion could not hold): the report warns when any does.
  double box_min_z_m = 0.0, box_max_z_m = 0.0;
  int cells_above_box = 0, cells_below_box = 0;
  std::optional<double> pile_top_m;  // the pile's top as the approach measured it (above the bin floor)

  cv::Mat height_m, gt_height_m, overview;
  sim::ScanStats scan_stats;
  sim::PickResult pick;
};

// Cells of a ground-truth height map (CV_32F, W z in m, NaN: nothing) whose surface lies above
// max_z_m or below min_z_m: what a fusion box of those heights cannot hold.
void CountCellsOutsideBox(const cv::Mat& gt_height_m, double min_z_m, double max_z_m, int* above, int* below);

// Writes every output file of the run into dir (each atomically).
void WriteScanOutputs(const std::filesystem::path& dir, const ScanReport& report);

// The report as JSON text.
std::string ScanReportJson(const ScanReport& report);
// The options that repeat a scan (the report's "options"), as a JSON object text.
std::string ScanOptionsJson(const ScanJobOptions& options);

// What RunScan returns: the finished run folder and its report.
struct ScanSummary {
  std::filesystem::path run_dir;
  ScanReport report;
};

// The paper's table 1 counts completeness after 1, 20 and 50 frames, from the first frame that
// holds depth (>= 5 % valid pixels: the pile in the measurable range) over the whole region.
inline constexpr int kTable1Frames[] = {1, 20, 50};
int Table1FirstFrame(const ScanReport& report);
// The completeness after `frames` frames so counted; nothing when the scan had fewer.
std::optional<double> Table1Completeness(const ScanReport& report, int frames);

// A few lines for the terminal: the paper's table 1, accuracy, pick, timings, where files are.
std::string ScanSummaryText(const ScanSummary& summary);

}  // namespace romunect::jobs
