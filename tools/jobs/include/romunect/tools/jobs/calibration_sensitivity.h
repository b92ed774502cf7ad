// `romunect experiment calibration-sensitivity`: how much calibration error a map tolerates.
// One scan with the rig's true calibration (or a given scan run folder), then its frames
// re-fused with each injected error of each sweep (perturbation.h: every error it injects acts
// where fusion uses the calibration, so the frames themselves do not change and are scanned
// once). Each map is also picked from, in a fresh copy of the scan's settled pile (when the scan
// folder has its scene.json). Writes OUT/sensitivity.md (the table and the tolerances), OUT/sensitivity.csv and one
// plot per sweep (OUT/<name>.svg: MAE and share within 1 mm against the injected error).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace romunect::jobs {

struct SensitivityOptions {
  std::string out = "calibration-sensitivity";
  std::string scan;  // an existing scan run folder (frames/, gt_height.exr); "" scans first
  uint32_t seed = 1;
  int objects = 12;
  int threads = 2;
  // Sweeps, each NAME=V1:V2:... (names of perturbation.h); empty: the default sweeps.
  std::vector<std::string> sweeps;
};

struct SensitivityPoint {
  std::string name;
  double value = 0.0;
  double mae_mm = 0.0, rmse_mm = 0.0, within_1mm = 0.0, completeness = 0.0;
  int pick = -1;  // the pick from this map in the scan's settled pile: 1 succeeded, 0 failed, -1 not tried
};

// The largest injected error that keeps the map's MAE within `mm` of the unperturbed map's
// (linear between the swept values); the largest value swept when all do, -1 when none does.
struct SensitivityTolerance {
  std::string name;
  double within_0_1mm = -1.0, within_1mm = -1.0;
};

struct SensitivitySummary {
  std::filesystem::path out;
  SensitivityPoint baseline;
  std::vector<SensitivityPoint> points;
  std::vector<SensitivityTolerance> tolerances;
  std::string table;  // Markdown
};

SensitivitySummary RunCalibrationSensitivity(const SensitivityOptions& options);

// The tolerance of one sweep's points (sorted by value) against the baseline MAE.
SensitivityTolerance ToleranceOf(const std::string& name, const std::vector<SensitivityPoint>& sweep,
                                 double baseline_mae_mm);

}  // namespace romunect::jobs
