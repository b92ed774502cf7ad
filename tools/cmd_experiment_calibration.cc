// romunect experiment calibration-sensitivity (jobs/calibration_sensitivity.h).
#include <cstdio>
#include <memory>

#include "commands.h"
#include "romunect/tools/jobs/calibration_sensitivity.h"

namespace romunect::tools {

void AddCalibrationSensitivityExperiment(CLI::App& experiment) {
  auto o = std::make_shared<jobs::SensitivityOptions>();
  auto* cmd = experiment.add_subcommand(
      "calibration-sensitivity", "Map accuracy against injected calibration errors: one scan, re-fused per error");
  cmd->add_option("--out", o->out, "Output folder")->capture_default_str();
  cmd->add_option("--scan", o->scan, "A scan run folder to re-fuse (default: scan first, true calibration)");
  cmd->add_option("--seed", o->seed, "Seed of the scan's pile and noise")->capture_default_str();
  cmd->add_option("--objects", o->objects, "Objects in the scan's pile")->capture_default_str();
  cmd->add_option("--threads", o->threads, "Threads")->capture_default_str();
  cmd->add_option("--sweep", o->sweeps,
                  "NAME=V1:V2:... (names as scan --perturb); repeat for more; default: hand_eye_deg, hand_eye_mm, "
                  "focal_pct, principal_px, depth_scale_pct, depth_offset_mm");
  cmd->callback([o] {
    const jobs::SensitivitySummary s = jobs::RunCalibrationSensitivity(*o);
    std::printf("%s\nwrote %s/ (sensitivity.md, sensitivity.csv, one .svg plot per sweep)\n", s.table.c_str(),
                s.out.c_str());
  });
}

}  // namespace romunect::tools
