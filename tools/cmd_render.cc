// romunect render OUT_DIR: a rig looking at a built-in target or a mesh, rendered into a frame
// directory with pictures (jobs/render.h). Arguments -> RenderJobOptions -> Render -> summary.
#include <cstdio>
#include <memory>
#include <string>

#include "commands.h"
#include "romunect/sensor/mesh.h"
#include "romunect/tools/jobs/render.h"

namespace romunect::tools {

void AddRenderCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand("render",
                                 "Render a rig looking at a built-in target or a mesh into a frame directory");
  auto o = std::make_shared<jobs::RenderJobOptions>();
  cmd->add_option("OUT_DIR", o->out_dir, "Output frame directory (must not hold frames.json)")->required();
  cmd->add_option("--rig", o->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")->capture_default_str();
  std::string targets;
  for (const auto& n : BuiltinTargetNames()) targets += (targets.empty() ? "" : ", ") + n;
  cmd->add_option("--target", o->target, "Built-in target: " + targets)->capture_default_str();
  cmd->add_option("--mesh", o->mesh, "Mesh file (.stl, .obj) in camera coordinates, instead of a target");
  cmd->add_option("--mesh-unit", o->mesh_unit_m, "Metres per mesh file unit (0.001 for mm)")->capture_default_str();
  cmd->add_option("--distance", o->distance_m, "Target distance in m (default: camera focus distance)");
  cmd->add_option("--size", o->size_m, "Target size in m (default: 1.5 x the view width)");
  cmd->add_option(
         "--samples", o->samples,
         "Samples per pixel: 1, 4 (thin lens), or adaptive (4 only where depth or defocus changes within the pixel)")
      ->capture_default_str();
  cmd->add_option("--threads", o->threads, "Threads")->capture_default_str();
  cmd->add_option("--seed", o->seed, "Noise seed")->capture_default_str();
  cmd->add_option("--albedo", o->albedo, "Target albedo in [0, 1]")->capture_default_str();
  cmd->callback([o] { std::printf("%s", jobs::RenderSummaryText(jobs::Render(*o)).c_str()); });
}

}  // namespace romunect::tools
