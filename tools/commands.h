// Subcommands of the romunect CLI. Each Add*Command registers one subcommand on the app; its
// callback may throw InputError (bad input), which main() reports with a non-zero exit.
#pragma once

#include <CLI/CLI.hpp>

namespace romunect::tools {

void AddInfoCommand(CLI::App& app);
void AddFuseCommand(CLI::App& app);        // cmd_fuse.cc (jobs/fuse.h)
void AddRecordCommand(CLI::App& app);      // cmd_record.cc (jobs/record.h)
void AddRenderCommand(CLI::App& app);      // cmd_render.cc (jobs/render.h)
void AddCalibrateCommand(CLI::App& app);   // cmd_calibrate.cc (jobs/calibrate.h)
void AddScanCommand(CLI::App& app);        // cmd_scan.cc (the main job: jobs/scan.h)
void AddDatasetCommand(CLI::App& app);     // cmd_dataset.cc (jobs/dataset.h)
void AddExperimentCommand(CLI::App& app);  // cmd_experiment.cc (the `experiment` group; table1: jobs/table1.h)
// cmd_experiment_calibration.cc (jobs/calibration_sensitivity.h)
void AddCalibrationSensitivityExperiment(CLI::App& experiment);

}  // namespace romunect::tools
