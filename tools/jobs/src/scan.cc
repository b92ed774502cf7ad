#include "romunect/tools/jobs/scan.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "romunect/calib/calibration_file.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/frame_pipeline.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sim/objects.h"
#include "romunect/sim/pick.h"
#include "romunect/sim/pile.h"
#include "romunect/sim/scanner.h"
#include "romunect/sim/sensor_imager.h"
#include "romunect/tools/jobs/fusion_loop.h"
#include "romunect/tools/jobs/rig_argument.h"
#include "romunect/tools/jobs/run_folder.h"
#include "scan_resume.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

std::string Mm(double m) { return std::to_string(static_cast<int>(std::lround(m * 1e3))) + " mm"; }

std::string DefaultRunDir() {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof(name), "runs/scan-%Y%m%d-%H%M%S", std::localtime(&now));
  return name;
}

// The checks that need no file read: before the run folder is looked at.
void CheckOptionValues(const ScanJobOptions& o) {
  if (o.objects < 0 || o.objects > 60) {
    throw InputError("--objects", "", std::to_string(o.objects) + " is outside 0..60");
  }
  if (o.objects == 0 && o.meshes.empty() && o.saved_scene.empty()) {
    throw InputError("--objects", "", "0 needs at least one --mesh (an empty bin has nothing to scan)");
  }
  for (const std::string& kind : o.kinds) sim::GeneratedKindFromName(kind, "--kinds");
  if (o.threads < 1 || o.threads > 64) {
    throw InputError("--threads", "", std::to_string(o.threads) + " is outside 1..64");
  }
  if (o.samples != 1 && o.samples != 4) {
    throw InputError("--samples", "", std::to_string(o.samples) + " is not 1 or 4");
  }
  if (!(o.voxel_m >= 0.05e-3 && o.voxel_m <= 5e-3)) {
    throw InputError("--voxel", "", "expected 0.00005 .. 0.005 metres");
  }
  ParsePerturbation(o.perturb);  // before any work
  if (o.resume && !o.perturb.empty()) {
    throw InputError("--resume", "", "not with --perturb: the frames on disk hold the perturbed depth");
  }
  for (const std::string* file : {&o.scene, &o.saved_scene, &o.calibration}) {
    if (!file->empty() && !fs::exists(*file)) throw InputError(*file, "", "file not found");
  }
}

// The simulator's options from the job's; with a calibration, the projector's pre-warp is the
// calibrated one.
sim::ScanOptions SimulatorOptions(const ScanJobOptions& o, std::optional<calib::Calibration>* calibration) {
  sim::ScanOptions options;
  options.scene_file = o.scene;
  options.saved_scene = o.saved_scene;
  options.rig = LoadRigArgument(o.rig);
  options.pile.num_objects = o.objects;
  for (const std::string& kind : o.kinds) options.pile.kinds.push_back(sim::GeneratedKindFromName(kind, "--kinds"));
  options.pile.seed = o.seed;
  options.pile.one_layer = o.one_layer;
  options.seed = o.seed;
  options.threads = o.threads;
  options.samples_per_pixel = o.samples;
  if (o.sweep != "coverage" && o.sweep != "columns" && o.sweep != "levels") {
    throw InputError("--sweep", "", "'" + o.sweep + "' is not coverage, columns or levels");
  }
  options.approach.sweep = o.sweep == "levels"    ? sim::ApproachOptions::Sweep::kLevels
                           : o.sweep == "columns" ? sim::ApproachOptions::Sweep::kColumns
                                                  : sim::ApproachOptions::Sweep::kCoverage;
  // A calibration replaces the simulator's truth wherever the real system would use it: the
  // projector's pre-warp, the depth correction, the camera model and the hand-eye pose that
  // fusion uses. The simulated hardware itself stays the rig.
  if (!o.calibration.empty()) {
    *calibration = calib::LoadCalibration(o.calibration);
    if ((*calibration)->camera.width != options.rig.camera.width ||
        (*calibration)->camera.height != options.rig.camera.height) {
      throw InputError(o.calibration, "image_width/image_height", "do not match the rig's camera");
    }
    options.rig.H_P_rec = (*calibration)->H_P_rec;
  }
  if (o.mesh_material != "bright" && o.mesh_material != "dark" && o.mesh_material != "shiny") {
    throw InputError("--mesh-material", "", "'" + o.mesh_material + "' is not bright, dark or shiny");
  }
  const IrMaterial mesh_material = o.mesh_material == "dark"    ? sim::DarkMaterial()
                                   : o.mesh_material == "shiny" ? sim::ShinyMaterial()
                                                                : sim::BrightMaterial();
  for (const std::string& mesh : o.meshes) {
    options.extra_objects.push_back(sim::MakeUserMeshObject(mesh, o.mesh_unit_m, mesh_material));
  }
  if (const std::string problem = options.Problem(); !problem.empty()) {
    throw InputError("romunect scan", "options", problem);
  }
  return options;
}

// Imaging: the sensor model (IR synthesis, depth engine) and the depth correction, or none
// (ideal depth); the first `reused` frames read back from `frames_dir` (--resume). Returns what
// the report says the depth correction is.
std::string SetUpImaging(const ScanJobOptions& o, const std::optional<calib::Calibration>& calibration,
                         const fs::path& frames_dir, int reused, sim::Scanner* scanner) {
  if (o.ideal_depth) return "none: ideal depth (ground truth), --ideal-depth";
  sim::SensorImagerOptions imager_options;
  // IR synthesis and the depth engine run on stages of their own beside rendering and fusion
  // (FuseApproach): they do not split well (2 threads cost 15-35 % more CPU than one).
  imager_options.threads = std::max(1, o.threads - 1);
  if (calibration) {
    if (!calibration->depth) {
      throw InputError(o.calibration, "depth_model.kind", "is none; scanning needs a depth model (run the depth step)");
    }
    imager_options.correction = calibration->depth;
    imager_options.correction_source = "calibration file " + o.calibration;
  }
  std::fprintf(stderr, "scan: preparing the depth correction (%s)...\n",
               o.calibration.empty() ? "ground truth of the rig" : o.calibration.c_str());
  auto imager = std::make_unique<sim::SensorImager>(scanner->options().rig, imager_options);
  std::string source = imager->correction_source();
  if (reused == 0) {
    scanner->SetImager(std::move(imager));
  } else {
    scanner->SetImager(MakeResumingImager(std::move(imager), frames_dir, reused));
  }
  return source;
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

// The scan's part of the fusion loop: calibrated camera poses (which the frame directory then
// records), the valid share and sample depths per frame, and the progress line.
class ScanHooks : public FrameHooks {
 public:
  ScanHooks(ScanReport* report, const std::optional<calib::Calibration>& calibration,
            const CalibrationPerturbation& perturbation, const Pose& T_W_B, const sim::Scanner& scanner)
      : report_(report), calibration_(calibration), perturbation_(perturbation), T_W_B_(T_W_B), scanner_(scanner) {}

  // Once per frame: the descent's frames are prepared when they are held (the frame directory
  // records what fusion believes) and pass here again when they are fused.
  void Prepare(size_t, Frame* frame) override {
    if (frame->index <= prepared_through_) return;
    prepared_through_ = frame->index;
    if (calibration_) frame->T_W_C = T_W_B_ * *frame->T_B_H * calibration_->T_H_C;
    if (!perturbation_.empty()) {  // --perturb: what fusion believes, never the simulated truth
      frame->T_W_C = *frame->T_W_C * perturbation_.T_C_Cp();
      perturbation_.ApplyToDepth(&frame->depth_m);
    }
  }

  void OnFused(size_t, const Frame& frame, const FusionSummary& summary) override {
    report_->valid_fraction_per_frame.push_back(static_cast<double>(cv::countNonZero(frame.depth_m)) /
                                                frame.depth_m.total());
    report_->sample_depths.Offer(frame, report_->valid_fraction_per_frame.back());
    // One updating line on a terminal; a line every 10 frames in a log.
    const int total = scanner_.frame_count();  // grows when the coverage leg is planned
    if (interactive_ || (frame.index + 1) % 10 == 0 || frame.index + 1 == total) {
      std::fprintf(stderr, "%sscan: frame %3d/%d  valid %5.1f %%  fused completeness %5.1f %%  (%.1f s)%s",
                   interactive_ ? "\r" : "", frame.index + 1, total, 100.0 * report_->valid_fraction_per_frame.back(),
                   100.0 * summary.report.completeness_per_frame.back(), loop_.seconds(), interactive_ ? "" : "\n");
    }
  }

  bool interactive() const { return interactive_; }

 private:
  ScanReport* report_;
  const std::optional<calib::Calibration>& calibration_;
  const CalibrationPerturbation perturbation_;
  const Pose T_W_B_;
  const sim::Scanner& scanner_;
  const bool interactive_ = isatty(fileno(stderr));
  const Stopwatch loop_;
  int prepared_through_ = -1;
};

// The approach: frames fused as they arrive, the frame directory written beside.
void FuseApproach(const ScanJobOptions& o, sim::Scanner& scanner, const std::optional<calib::Calibration>& calibration,
                  const fs::path& work_dir, ScanReport* report) {
  // What fusion believes: the calibrated camera and hand-eye pose, or the simulator's truth,
  // with the injected errors; and how far that is from the truth.
  const CalibrationPerturbation perturbation = ParsePerturbation(o.perturb);
  const CameraModel camera = perturbation.Apply(calibration ? calibration->camera : scanner.camera());
  const Pose T_H_C_truth = scanner.world().T_H_C();
  report->perturbation = perturbation.Text();
  report->calibration_errors = CompareCalibration(
      (calibration ? calibration->T_H_C : T_H_C_truth) * perturbation.T_C_Cp(), camera, T_H_C_truth, scanner.camera());
  // Uncompressed frame files keep up with the 30 Hz loop (image_io.h).
  std::optional<FrameDirectoryWriter> writer;
  if (o.write_frames) {
    writer.emplace(work_dir / "frames", camera,
                   o.compress_frames ? ImageCompression::kCompact : ImageCompression::kFast);
  }
  const Stopwatch loop;
  const double cpu_loop = ProcessCpuSeconds();
  ScanHooks hooks(report, calibration, perturbation, scanner.world().T_W_B(), scanner);
  // The fusion box follows the pile the descent measured (sim/coverage.h): the descent's frames
  // wait (their images are their own) until the coverage leg is planned, then the grid is made.
  fusion::GridOptions box;
  std::unique_ptr<fusion::VotingGrid> grid;
  std::unique_ptr<FrameFuser> fuser;
  std::vector<Frame> held;
  auto start_fusion = [&] {
    box = FusionBox(scanner.world(), scanner.options().approach, o.voxel_m);
    grid = std::make_unique<fusion::VotingGrid>(box);
    if (writer) writer->SetRegion({box.min_W, box.max_W});  // `romunect fuse` re-runs the scan over the same box
    const std::optional<double> top = scanner.measured_pile_top_m();
    std::string levels;
    for (double level_m : scanner.plan().levels_m) levels += (levels.empty() ? "" : ", ") + Mm(level_m);
    std::fprintf(stderr,
                 "scan: approach of %d frames (%.2f s at %.0f Hz; pile top measured at %s; levels %s above the bin "
                 "floor), fusing into %d x %d x %d voxels of %.2f mm\n",
                 scanner.frame_count(), scanner.plan().duration_s(), scanner.options().rig.frame_rate_hz,
                 top ? Mm(*top).c_str() : "-", levels.c_str(), grid->nx(), grid->ny(), grid->nz(),
                 grid->voxel_m() * 1e3);
    // Fusion runs beside the simulator, which keeps every core busy: one thread fewer (at least
    // one) costs the least CPU per frame (threads owning slabs walk the rays that cross them
    // twice: on 2 cores 16 ms CPU per frame at 1 thread, 17-20 ms at 2, scan_benchmark).
    fuser = std::make_unique<FrameFuser>(camera, *grid, std::max(1, o.threads - 1), hooks);
    for (Frame& frame : held) fuser->Fuse(&frame);
    held.clear();
  };
  auto fuse = [&](Frame* frame) {
    if (!fuser && frame->index < scanner.descent_frames()) {
      hooks.Prepare(0, frame);  // the frame directory records the calibrated pose
      held.push_back(*frame);   // shares the images, which nobody writes any more
      return;
    }
    if (!fuser) start_fusion();
    fuser->Fuse(frame);
  };
  FramePipeline<sim::ScanWork> pipeline;
  sim::AddScanStages(&scanner, &pipeline);
  pipeline.AddStage({"fuse", 2}, [&fuse](sim::ScanWork* work) { fuse(&work->frame); });
  // The writer may lag up to 16 frames (~60 MB of images) at a lower priority: it runs on what
  // rendering, imaging and fusion leave (steadier loop times on 2 cores).
  if (writer) pipeline.AddStage({"write", 16, 10}, [&writer](sim::ScanWork* work) { writer->Add(work->frame); });
  pipeline.Run();
  if (!fuser) start_fusion();
  report->loop_wall_s = loop.seconds();
  report->loop_cpu_s = ProcessCpuSeconds() - cpu_loop;
  if (hooks.interactive()) std::fprintf(stderr, "\n");
  for (const PipelineStageTiming& stage : pipeline.timings()) {
    if (stage.name == "write") report->write_s = stage.busy_s;
    if (stage.name == "fuse") report->wait_s = stage.wait_s;
  }
  if (writer) writer->Finish();
  FusionSummary fused = std::move(fuser->summary());

  report->fusion = std::move(fused.report);
  report->completeness_each_ms = std::move(fused.completeness_ms);
  const Stopwatch extract;
  report->height_m = fusion::ExtractHeightMap(*grid, Isa::kAuto, o.threads);
  report->fusion.extract_ms = extract.milliseconds();
  report->fusion.geometry = grid->geometry();
  report->box_min_z_m = box.min_W.z();
  report->box_max_z_m = box.max_W.z();
  report->fusion.max_x_m = box.max_W.x();
  report->fusion.max_y_m = box.max_W.y();
  report->fusion.max_z_m = box.max_W.z();
  report->fusion.grid_mb = grid->memory_bytes() / 1e6;
}

// Ground truth, metrics, the pick and the figures of the finished approach.
void CompleteReport(const ScanJobOptions& o, sim::Scanner& scanner, ScanReport* report) {
  report->fusion.input = "simulation (" + o.rig + " rig, seed " + std::to_string(o.seed) + ")";
  const HeightMapGeometry& layout = report->fusion.geometry;
  report->gt_height_m = sim::GroundTruthHeightMap(scanner.world(), layout);
  report->fusion.metrics = fusion::CompareHeightMaps(report->height_m, report->gt_height_m);
  report->fusion.completeness = report->fusion.metrics->completeness;
  // What the box leaves out: cells whose true surface lies above or below it.
  CountCellsOutsideBox(report->gt_height_m, report->box_min_z_m, report->box_max_z_m, &report->cells_above_box,
                       &report->cells_below_box);
  if (report->cells_above_box + report->cells_below_box > 0) {
    std::fprintf(stderr, "scan: warning: %d cells lie above and %d below the fusion box (ground truth)\n",
                 report->cells_above_box, report->cells_below_box);
  }
  report->overview = sim::OverviewPicture(scanner.world());

  std::fprintf(stderr, "scan: picking from the fused height map...\n");
  report->pick = sim::Pick(&scanner.world(), report->height_m, layout);
  std::fprintf(stderr, "scan: %s\n", report->pick.BriefReport().c_str());

  report->scan_stats = scanner.stats();
  report->pile_top_m = scanner.measured_pile_top_m();
  report->scan_description = scanner.Describe();
  report->rig_name = scanner.options().rig.name;
  report->seed = o.seed;
  report->objects = scanner.world().num_objects();  // the saved scene's with --saved-scene
  report->samples = o.samples;
  report->fusion.peak_rss_mb = fusion::PeakRssMb();
}

}  // namespace

ScanSummary RunScan(const ScanJobOptions& o) {
  const Stopwatch total;
  // Validate every option before any work or any file.
  CheckOptionValues(o);
  RunFolder run(o.out.empty() ? DefaultRunDir() : o.out, "--out", "scan");
  ScanSummary summary;
  ScanReport& report = summary.report;
  report.options = o;
  report.started_at = std::time(nullptr);
  std::optional<calib::Calibration> calibration;
  const sim::ScanOptions options = SimulatorOptions(o, &calibration);
  // The run folder is taken before the pile settles: a second run into the same --out is
  // refused before it does any work.
  int reused = 0;
  if (!o.resume) {
    run.Begin();
  } else if (run.Resume()) {
    reused = PrepareResume(o, run.work_dir());
    std::fprintf(stderr, "scan: resuming %s: %d finished frames are read back, the simulation replays from the start\n",
                 run.work_dir().c_str(), reused);
  } else {
    std::fprintf(stderr, "scan: --resume: no interrupted run in %s; starting afresh\n", run.work_dir().c_str());
  }
  WriteTextAtomically(run.work_dir() / kScanOptionsFile, ScanOptionsFileText(o));

  if (o.saved_scene.empty()) {
    std::fprintf(stderr, "scan: loading the scene, dropping %d objects (seed %u) and settling the pile...\n",
                 o.objects + static_cast<int>(o.meshes.size()), o.seed);
  } else {
    std::fprintf(stderr, "scan: loading the scene and the settled pile of %s...\n", o.saved_scene.c_str());
  }
  sim::Scanner scanner(options);
  std::fprintf(stderr, "scan: %s\n", scanner.stats().settle.BriefReport().c_str());
  report.depth_correction = SetUpImaging(o, calibration, run.work_dir() / "frames", reused, &scanner);

  // The settled pile, before the pick moves it: `--saved-scene` reloads it without settling.
  sim::SaveSettledScene(scanner.world(), run.work_dir() / "scene.json");
  FuseApproach(o, scanner, calibration, run.work_dir(), &report);
  CompleteReport(o, scanner, &report);
  report.total_wall_s = total.seconds();
  WriteScanOutputs(run.work_dir(), report);
  fs::remove(run.work_dir() / kScanOptionsFile);  // the report holds the options
  run.Commit();  // complete: the run under its final name
  summary.run_dir = run.dir();
  return summary;
}

}  // namespace romunect::jobs
