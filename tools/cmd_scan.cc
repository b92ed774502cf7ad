// romunect scan: the main job (jobs/scan.h). Arguments -> ScanJobOptions -> RunScan -> summary.
#include <cstdio>
#include <memory>

#include "commands.h"
#include "romunect/tools/jobs/scan.h"

namespace romunect::tools {

void AddScanCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "scan", "The main job: a simulated arm scans a bin while approaching, fuses every frame, then picks");
  auto o = std::make_shared<jobs::ScanJobOptions>();
  auto* scene = cmd->add_option("--scene", o->scene,
                                "MJCF scene with the arm and a bin (default: scenes/default/scene.xml)");
  auto* objects = cmd->add_option("--objects", o->objects, "Objects in the random pile, 0..60 (0 only with --mesh)")
                      ->capture_default_str();
  auto* kinds = cmd->add_option("--kinds", o->kinds,
                                "Kinds the pile is drawn from, comma-separated: key, pillbox, puzzle, lego, gear "
                                "(default: all five; one kind: the paper's table 1 row beside the report's)")
                    ->delimiter(',');
  auto* one_layer = cmd->add_flag("--one-layer", o->one_layer,
                                  "Lay the objects on the bin floor side by side, each on its broadest face, "
                                  "as in the paper's bins (those that find no room land on the others; the "
                                  "report says how many)");
  auto* saved =
      cmd->add_option("--saved-scene", o->saved_scene,
                      "A run folder's scene.json (its scene and settled pile): the same pile without settling");
  auto* meshes = cmd->add_option(
      "--mesh", o->meshes, "A user mesh (.stl, .obj) dropped into the pile besides the --objects; repeat for more");
  // A saved scene names its MJCF scene and objects itself.
  saved->excludes(scene)->excludes(objects)->excludes(meshes)->excludes(kinds)->excludes(one_layer);
  cmd->add_option("--mesh-unit", o->mesh_unit_m, "Metres per --mesh file unit (0.001: millimetres)")
      ->capture_default_str();
  cmd->add_option("--mesh-material", o->mesh_material, "IR material of the --mesh objects: bright, dark or shiny")
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "Seed of the pile and of the sensor noise")->capture_default_str();
  cmd->add_option("--rig", o->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")->capture_default_str();
  cmd->add_option("--calibration", o->calibration,
                  "Calibration file from `romunect calibrate` (default: the rig's ground truth)");
  cmd->add_option("--out", o->out, "Run folder (default: runs/scan-<date>-<time>)");
  cmd->add_option("--threads", o->threads, "Threads for rendering, imaging and fusion, 1..64")->capture_default_str();
  cmd->add_option("--samples", o->samples, "Render samples per pixel: 1 (pinhole) or 4 (thin lens)")
      ->capture_default_str();
  cmd->add_option("--voxel", o->voxel_m, "Fusion voxel size, metres, 0.00005..0.005")->capture_default_str();
  cmd->add_option("--sweep", o->sweep,
                  "How the approach visits the stand-off levels: coverage (down over the bin, then the levels "
                  "the measured pile needs, serpentines, and again with the hand turned), columns (through all "
                  "levels at each pass centre) or levels (a serpentine per level)")
      ->capture_default_str();
  cmd->add_option("--perturb", o->perturb,
                  "Inject calibration errors into what fusion uses (never the simulated truth): NAME=VALUE[,...] with "
                  "hand_eye_deg[_x|_y|_z], hand_eye_mm[_x|_y|_z], focal_pct, principal_px[_x|_y], depth_scale_pct, "
                  "depth_offset_mm");
  cmd->add_flag("--ideal-depth", o->ideal_depth, "Fuse ground-truth depth instead of the sensor's (debugging)");
  cmd->add_flag("--compress-frames", o->compress_frames,
                "Compress the frame directory's files (PNG, EXR ZIP: 2-5x smaller, ~50 ms of CPU per frame)");
  cmd->add_flag("--resume", o->resume,
                "Continue the run in --out that was interrupted (its .incomplete folder) from its last finished "
                "frame, with the same options: the same bytes as an uninterrupted run");
  cmd->callback([o] { std::printf("%s", jobs::ScanSummaryText(jobs::RunScan(*o)).c_str()); });
}

}  // namespace romunect::tools
