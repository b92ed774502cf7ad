// romunect scan: the main job. A MuJoCo arm approaches a bin with a settled random pile at
// 0.3 m/s, the simulated sensor delivers 30 Hz frames, each frame is fused as it arrives, then
// the robot picks from the fused height map. Wiring only: sim/ (Scanner, pick), the sensor model
// (imaging), fusion/ (grid, metrics, outputs) and the report (scan_report.h).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <unistd.h>

#include "commands.h"
#include "output_folder.h"
#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/frame_pipeline.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/objects.h"
#include "romunect/sim/pick.h"
#include "romunect/sim/pile.h"
#include "romunect/sim/scanner.h"
#include "romunect/sim/sensor_imager.h"
#include "scan_report.h"

namespace romunect::tools {
namespace {
namespace fs = std::filesystem;

// CPU time of all of the process's threads.
double ProcessCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

std::string DefaultRunDir() {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof(name), "runs/scan-%Y%m%d-%H%M%S", std::localtime(&now));
  return name;
}

// The fusion box: the scan's region (the paper's 150 x 80 mm around the bin) and heights.
fusion::GridOptions FusionBox(const sim::World& world, const sim::ApproachOptions& approach, double voxel_m) {
  const sim::ScanBox region = sim::ScanRegionBox(world, approach);
  fusion::GridOptions box;
  box.min_W = region.min_W;
  box.max_W = region.max_W;
  box.voxel_m = voxel_m;
  box.prefault = true;  // before the 30 Hz loop, not in it
  return box;
}

void RunScan(const ScanArguments& args) {
  const auto t_start = std::chrono::steady_clock::now();
  // Validate every argument before any work or any file.
  if (args.objects < 1 || args.objects > 60) {
    throw InputError("--objects", "", std::to_string(args.objects) + " is outside 1..60");
  }
  if (args.threads < 1 || args.threads > 64) {
    throw InputError("--threads", "", std::to_string(args.threads) + " is outside 1..64");
  }
  if (args.samples != 1 && args.samples != 4) {
    throw InputError("--samples", "", std::to_string(args.samples) + " is not 1 or 4");
  }
  if (!(args.voxel_m >= 0.05e-3 && args.voxel_m <= 5e-3)) {
    throw InputError("--voxel", "", "expected 0.00005 .. 0.005 metres");
  }
  for (const std::string* file : {&args.scene, &args.saved_scene, &args.calibration}) {
    if (!file->empty() && !fs::exists(*file)) throw InputError(*file, "", "file not found");
  }
  const fs::path run_dir = OutputFolder(args.out.empty() ? DefaultRunDir() : args.out, "--out");
  if (fs::exists(run_dir / "report.json")) {
    throw InputError(run_dir.string(), "", "holds a finished scan (report.json); choose another --out");
  }
  // The run replaces at most an empty folder: nothing a user put there is ever removed.
  if (fs::exists(run_dir) && !(fs::is_directory(run_dir) && fs::is_empty(run_dir))) {
    throw InputError(run_dir.string(), "", "exists and is not an empty folder; choose another --out");
  }
  CheckFolderCanBeCreated(run_dir, "--out");
  // The run is built in <run>.incomplete and renamed at the very end, so a folder under the
  // final name is always complete.
  const fs::path work_dir = run_dir.string() + ".incomplete";
  if (fs::exists(work_dir)) fs::remove_all(work_dir);

  ScanReport report;
  report.args = args;
  report.started_at = std::time(nullptr);
  sim::ScanOptions options;
  options.scene_file = args.scene;
  options.saved_scene = args.saved_scene;
  options.rig = LoadRigArgument(args.rig);
  options.pile.num_objects = args.objects;
  options.pile.seed = args.seed;
  options.seed = args.seed;
  options.threads = args.threads;
  options.samples_per_pixel = args.samples;
  if (args.sweep != "columns" && args.sweep != "levels") {
    throw InputError("--sweep", "", "'" + args.sweep + "' is not columns or levels");
  }
  options.approach.sweep =
      args.sweep == "levels" ? sim::ApproachOptions::Sweep::kLevels : sim::ApproachOptions::Sweep::kColumns;
  // A calibration replaces the simulator's truth wherever the real system would use it: the
  // projector's pre-warp, the depth correction, the camera model and the hand-eye pose that
  // fusion uses. The simulated hardware itself stays the rig.
  std::optional<calib::Calibration> calibration;
  if (!args.calibration.empty()) {
    calibration = calib::LoadCalibration(args.calibration);
    if (calibration->camera.width != options.rig.camera.width ||
        calibration->camera.height != options.rig.camera.height) {
      throw InputError(args.calibration, "image_width/image_height", "do not match the rig's camera");
    }
    options.rig.H_P_rec = calibration->H_P_rec;
  }
  if (args.mesh_material != "bright" && args.mesh_material != "dark" && args.mesh_material != "shiny") {
    throw InputError("--mesh-material", "", "'" + args.mesh_material + "' is not bright, dark or shiny");
  }
  const IrMaterial mesh_material = args.mesh_material == "dark"    ? sim::DarkMaterial()
                                   : args.mesh_material == "shiny" ? sim::ShinyMaterial()
                                                                   : sim::BrightMaterial();
  for (const std::string& mesh : args.meshes) {
    options.extra_objects.push_back(sim::MakeUserMeshObject(mesh, args.mesh_unit_m, mesh_material));
  }
  if (const std::string problem = options.Problem(); !problem.empty()) {
    throw InputError("romunect scan", "options", problem);
  }

  if (args.saved_scene.empty()) {
    std::fprintf(stderr, "scan: loading the scene, dropping %d objects (seed %u) and settling the pile...\n",
                 args.objects + static_cast<int>(args.meshes.size()), args.seed);
  } else {
    std::fprintf(stderr, "scan: loading the scene and the settled pile of %s...\n", args.saved_scene.c_str());
  }
  sim::Scanner scanner(options);
  std::fprintf(stderr, "scan: %s\n", scanner.stats().settle.BriefReport().c_str());

  // Imaging: the sensor model (IR synthesis, depth engine) and the depth correction.
  std::unique_ptr<sim::SensorImager> imager;
  if (!args.ideal_depth) {
    sim::SensorImagerOptions imager_options;
    // Imaging runs on threads of its own beside rendering and fusion (the scan pipeline's IR and
    // depth stages): its stages do not split well (2 threads cost 15-35 % more CPU than one).
    imager_options.threads = std::max(1, args.threads - 1);
    if (calibration) {
      if (!calibration->depth) {
        throw InputError(args.calibration, "depth_model.kind", "is none; scanning needs a depth model (run the depth step)");
      }
      imager_options.correction = calibration->depth;
      imager_options.correction_source = "calibration file " + args.calibration;
    }
    std::fprintf(stderr, "scan: preparing the depth correction (%s)...\n",
                 args.calibration.empty() ? "ground truth of the rig" : args.calibration.c_str());
    imager = std::make_unique<sim::SensorImager>(options.rig, imager_options);
    report.depth_correction = imager->correction_source();
    scanner.SetImager(std::move(imager));
  } else {
    report.depth_correction = "none: ideal depth (ground truth), --ideal-depth";
  }

  fs::create_directories(work_dir);
  // The settled pile, before the pick moves it: `--saved-scene` reloads it without settling.
  sim::SaveSettledScene(scanner.world(), work_dir / "scene.json");
  // What fusion believes: the calibrated camera and hand-eye pose, or the simulator's truth.
  const CameraModel camera = calibration ? calibration->camera : scanner.camera();
  const Pose T_W_B = scanner.world().T_W_B();
  // Uncompressed frame files keep up with the 30 Hz loop (image_io.h).
  FrameDirectoryWriter writer(work_dir / "frames", camera,
                              args.compress_frames ? ImageCompression::kCompact : ImageCompression::kFast);
  const fusion::GridOptions box = FusionBox(scanner.world(), scanner.options().approach, args.voxel_m);
  fusion::VotingGrid grid(box);
  writer.SetRegion({box.min_W, box.max_W});  // `romunect fuse` re-runs the scan over the same box
  // Fusion runs beside the simulator, which keeps every core busy: one thread fewer (at least
  // one) costs the least CPU per frame (threads owning slabs walk the rays that cross them
  // twice: on 2 cores 16 ms CPU per frame at 1 thread, 17-20 ms at 2, scan_benchmark).
  fusion::FrameInserter inserter(&grid, fusion::InserterOptions{std::max(1, args.threads - 1)});
  fusion::InsertStats insert_stats;

  const int total = scanner.frame_count();
  std::fprintf(stderr, "scan: approach of %d frames (%.2f s at %.0f Hz), fusing into %d x %d x %d voxels of %.2f mm\n",
               total, scanner.plan().duration_s(), options.rig.frame_rate_hz, grid.nx(), grid.ny(), grid.nz(),
               grid.voxel_m() * 1e3);
  const bool interactive = isatty(fileno(stderr));
  const auto t_loop = std::chrono::steady_clock::now();
  const double cpu_loop = ProcessCpuSeconds();
  // A pipeline on the cores (frame_pipeline.h): the simulator renders frame k on one thread while
  // frame k - 1's IR is synthesized and frame k - 2's depth computed on two more, a fourth fuses
  // and a fifth writes the frame directory. Frames keep their order and content, so a seed gives
  // the same bytes.
  fusion::CompletenessTracker completeness(grid);  // the curve, without extracting every frame
  FramePipeline<sim::ScanWork> pipeline;  // after what its stages use: its threads end first
  sim::AddScanStages(&scanner, &pipeline);
  pipeline.AddStage({"fuse", 2}, [&](sim::ScanWork* work) {
    Frame& frame = work->frame;
    if (calibration) frame.T_W_C = T_W_B * *frame.T_B_H * calibration->T_H_C;
    auto t = std::chrono::steady_clock::now();
    inserter.Insert(camera, frame.depth_m, *frame.T_W_C, &insert_stats);
    report.fusion.insert_ms.push_back(1e3 * Seconds(t));
    ++report.fusion.frames;
    t = std::chrono::steady_clock::now();
    report.fusion.completeness_per_frame.push_back(completeness.Update(inserter.changed_columns()));
    report.completeness_each_ms.push_back(1e3 * Seconds(t));
    report.valid_fraction_per_frame.push_back(static_cast<double>(cv::countNonZero(frame.depth_m)) /
                                              frame.depth_m.total());
    report.sample_depths.Offer(frame, report.valid_fraction_per_frame.back());

    // One updating line on a terminal; a line every 10 frames in a log.
    if (interactive || (frame.index + 1) % 10 == 0 || frame.index + 1 == total) {
      std::fprintf(stderr, "%sscan: frame %3d/%d  valid %5.1f %%  fused completeness %5.1f %%  (%.1f s)%s",
                   interactive ? "\r" : "", frame.index + 1, total, 100.0 * report.valid_fraction_per_frame.back(),
                   100.0 * report.fusion.completeness_per_frame.back(), Seconds(t_loop), interactive ? "" : "\n");
    }
  });
  // The writer may lag up to 16 frames (~60 MB of images) at a lower priority: it runs on what
  // rendering, imaging and fusion leave (steadier loop times on 2 cores).
  pipeline.AddStage({"write", 16, 10}, [&writer](sim::ScanWork* work) { writer.Add(work->frame); });
  pipeline.Run();
  report.loop_wall_s = Seconds(t_loop);
  report.loop_cpu_s = ProcessCpuSeconds() - cpu_loop;
  if (interactive) std::fprintf(stderr, "\n");
  for (const PipelineStageTiming& stage : pipeline.timings()) {
    if (stage.name == "write") report.write_s = stage.busy_s;
    if (stage.name == "fuse") report.wait_s = stage.wait_s;
  }
  writer.Finish();

  auto t = std::chrono::steady_clock::now();
  report.height_m = fusion::ExtractHeightMap(grid, Isa::kAuto, args.threads);
  report.fusion.extract_ms = 1e3 * Seconds(t);
  report.fusion.input = "simulation (" + args.rig + " rig, seed " + std::to_string(args.seed) + ")";
  report.fusion.geometry = grid.geometry();
  report.fusion.max_x_m = box.max_W.x();
  report.fusion.max_y_m = box.max_W.y();
  report.fusion.max_z_m = box.max_W.z();
  const HeightMapGeometry& layout = report.fusion.geometry;
  report.gt_height_m = sim::GroundTruthHeightMap(scanner.world(), layout);
  report.fusion.metrics = fusion::CompareHeightMaps(report.height_m, report.gt_height_m);
  report.fusion.completeness = report.fusion.metrics->completeness;
  report.overview = sim::OverviewPicture(scanner.world());

  std::fprintf(stderr, "scan: picking from the fused height map...\n");
  report.pick = sim::Pick(&scanner.world(), report.height_m, layout);
  std::fprintf(stderr, "scan: %s\n", report.pick.BriefReport().c_str());

  report.scan_stats = scanner.stats();
  report.fusion.stats = insert_stats;
  report.scan_description = scanner.Describe();
  report.rig_name = options.rig.name;
  report.seed = args.seed;
  report.objects = scanner.world().num_objects();  // the saved scene's with --saved-scene
  report.fusion.threads = inserter.threads();
  report.samples = args.samples;
  report.fusion.peak_rss_mb = fusion::PeakRssMb();
  report.fusion.grid_mb = grid.memory_bytes() / 1e6;
  report.total_wall_s = Seconds(t_start);
  WriteScanOutputs(work_dir, report);

  // Complete: move the run under its final name.
  if (fs::exists(run_dir)) {
    if (!fs::is_directory(run_dir) || !fs::is_empty(run_dir)) {
      throw InputError(run_dir.string(), "", "was filled while the scan ran; the finished run is in " + work_dir.string());
    }
    fs::remove(run_dir);  // the empty folder the run replaces
  }
  fs::create_directories(run_dir.parent_path().empty() ? fs::path(".") : run_dir.parent_path());
  fs::rename(work_dir, run_dir);
  std::printf("%s", ScanSummary(report, run_dir).c_str());
}

}  // namespace

void AddScanCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "scan", "The main job: a simulated arm scans a bin while approaching, fuses every frame, then picks");
  auto args = std::make_shared<ScanArguments>();
  auto* scene = cmd->add_option("--scene", args->scene, "MJCF scene with the arm and a bin (default: scenes/default/scene.xml)");
  auto* objects = cmd->add_option("--objects", args->objects, "Objects in the random pile")->capture_default_str();
  auto* saved = cmd->add_option("--saved-scene", args->saved_scene,
                                "A run folder's scene.json (its scene and settled pile): the same pile without settling");
  auto* meshes = cmd->add_option("--mesh", args->meshes,
                                 "A user mesh (.stl, .obj) dropped into the pile besides the --objects; repeat for more");
  // A saved scene names its MJCF scene and objects itself.
  saved->excludes(scene)->excludes(objects)->excludes(meshes);
  cmd->add_option("--mesh-unit", args->mesh_unit_m, "Metres per --mesh file unit (0.001: millimetres)")
      ->capture_default_str();
  cmd->add_option("--mesh-material", args->mesh_material, "IR material of the --mesh objects: bright, dark or shiny")
      ->capture_default_str();
  cmd->add_option("--seed", args->seed, "Seed of the pile and of the sensor noise")->capture_default_str();
  cmd->add_option("--rig", args->rig, "Rig preset (romunect, kinect-v1) or rig JSON file")->capture_default_str();
  cmd->add_option("--calibration", args->calibration,
                  "Calibration file from `romunect calibrate` (default: the rig's ground truth)");
  cmd->add_option("--out", args->out, "Run folder (default: runs/scan-<date>-<time>)");
  cmd->add_option("--threads", args->threads, "Threads for rendering, imaging and fusion")->capture_default_str();
  cmd->add_option("--samples", args->samples, "Render samples per pixel: 1, or 4 (thin lens)")->capture_default_str();
  cmd->add_option("--voxel", args->voxel_m, "Fusion voxel size, metres")->capture_default_str();
  cmd->add_option("--sweep", args->sweep,
                  "How the approach visits the stand-off levels: columns (through all levels at each pass "
                  "centre) or levels (a serpentine per level)")
      ->capture_default_str();
  cmd->add_flag("--ideal-depth", args->ideal_depth, "Fuse ground-truth depth instead of the sensor's (debugging)");
  cmd->add_flag("--compress-frames", args->compress_frames,
                "Compress the frame directory's files (PNG, EXR ZIP: 2-5x smaller, ~50 ms of CPU per frame)");
  cmd->callback([args] { RunScan(*args); });
}

}  // namespace romunect::tools
