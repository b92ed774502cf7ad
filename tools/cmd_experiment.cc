// romunect experiment: the experiments that produce docs/performance.md's figures.
#include "commands.h"

namespace romunect::tools {

void AddExperimentCommand(CLI::App& app) {
  auto* experiment = app.add_subcommand("experiment", "Experiments behind the documented figures");
  experiment->require_subcommand(1);
  AddCalibrationSensitivityExperiment(*experiment);
}

}  // namespace romunect::tools
