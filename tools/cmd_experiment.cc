// romunect experiment: the paper's experiments, one subcommand each (Add...Experiment registers
// one on the `experiment` group).
#include <cstdio>
#include <memory>

#include "commands.h"
#include "romunect/tools/jobs/table1.h"

namespace romunect::tools {
namespace {

// `experiment table1`: the paper's table 1 (jobs/table1.h).
void AddTable1Experiment(CLI::App& experiment) {
  auto* cmd = experiment.add_subcommand(
      "table1", "The paper's table 1: completeness after 1, 20 and 50 frames for bins of one kind of object");
  auto o = std::make_shared<jobs::Table1Options>();
  cmd->add_option("--seeds", o->seeds, "Seeds (piles) per kind, 1..20")->capture_default_str();
  cmd->add_option("--out", o->out, "Output folder (default: runs/table1-<date>-<time>)");
  cmd->add_option("--threads", o->threads, "Threads per scan, 1..64")->capture_default_str();
  cmd->add_option("--rig", o->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")->capture_default_str();
  cmd->callback([o] {
    const jobs::Table1Summary summary = jobs::RunTable1(*o);
    std::printf("%swrote %s/ (table1.md, table1.json, table1.html, one run folder per scan)\n",
                summary.markdown.c_str(), summary.dir.string().c_str());
  });
}

}  // namespace

void AddExperimentCommand(CLI::App& app) {
  auto* experiment = app.add_subcommand("experiment", "The paper's experiments and the calibration sweeps, reproduced on the twin");
  experiment->require_subcommand(1);
  AddTable1Experiment(*experiment);
  AddCalibrationSensitivityExperiment(*experiment);
}

}  // namespace romunect::tools
