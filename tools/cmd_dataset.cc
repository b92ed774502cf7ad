// romunect dataset: BOP-format ground-truth datasets (jobs/dataset.h), and `dataset check`.
#include <cstdio>
#include <memory>
#include <stdexcept>

#include "commands.h"
#include "romunect/tools/jobs/dataset.h"

namespace romunect::tools {

void AddDatasetCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "dataset", "Ground-truth datasets in the BOP format (IR, sensor and ideal depth, masks, object poses)");
  auto o = std::make_shared<jobs::DatasetOptions>();
  cmd->add_option("OUT_DIR", o->out, "The dataset's folder (created; a rerun resumes it)");
  cmd->add_option("--scenes", o->scenes, "Scenes to write")->capture_default_str();
  cmd->add_option("--first-scene", o->first_scene, "Id of the first scene (to extend a dataset)")
      ->capture_default_str();
  cmd->add_option("--shard", o->shard, "I/N: write only the scenes with id % N == I (I from 0), e.g. a Slurm task's")
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "Seed of the whole dataset: scene i depends on (seed, i) alone")
      ->capture_default_str();
  cmd->add_option("--rig", o->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")->capture_default_str();
  cmd->add_option("--kinds", o->kinds, "Object kinds: key, pill_box, puzzle, lego, gear")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--objects", o->objects, "Objects per scene, A-B (drawn per scene)")->capture_default_str();
  cmd->add_option("--variants", o->variants, "Meshes per kind (sizes vary a few percent): one obj_id each")
      ->capture_default_str();
  cmd->add_option("--views", o->views, "approach (the arm's 30 Hz trajectory), random (reachable views) or both")
      ->capture_default_str();
  cmd->add_option("--views-per-scene", o->views_per_scene, "Random views per scene")->capture_default_str();
  cmd->add_option("--every", o->every, "Every k-th frame of the approach")->capture_default_str();
  cmd->add_option("--threads", o->threads, "Threads for rendering and imaging")->capture_default_str();
  cmd->add_flag("--quiet", o->quiet, "No progress lines");

  auto* check = cmd->add_subcommand("check", "Validate a dataset: files, masks, and models against depth_gt");
  auto dir = std::make_shared<std::string>();
  auto threads = std::make_shared<int>(2);
  check->add_option("OUT_DIR", *dir, "The dataset's folder")->required();
  check->add_option("--threads", *threads, "Render threads")->capture_default_str();
  check->callback([dir, threads] {
    const jobs::DatasetCheckSummary summary = jobs::CheckDataset(*dir, *threads);
    std::printf("%s", summary.Text().c_str());
    if (!summary.problems.empty()) throw std::runtime_error(std::to_string(summary.problems.size()) + " problems");
  });
  cmd->callback([cmd, check, o] {
    if (check->parsed()) return;
    if (o->out.empty()) throw CLI::RequiredError("OUT_DIR");
    std::printf("%s", jobs::RunDataset(*o).Text().c_str());
  });
}

}  // namespace romunect::tools
