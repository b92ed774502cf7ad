#include "romunect/tools/jobs/fuse.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include "bop_scene_source.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/openni2/open_source.h"
#include "romunect/sensor/world_box.h"
#include "romunect/tools/jobs/fusion_loop.h"
#include "romunect/tools/jobs/output_folder.h"
#include "romunect/tools/jobs/run_folder.h"
#include "romunect/tools/jobs/perturbation.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

// "--box xmin,ymin,zmin,xmax,ymax,zmax" in metres.
void ParseBox(const std::string& text, fusion::GridOptions* options) {
  std::vector<double> values;
  std::stringstream s(text);
  std::string item;
  if (text.empty() || text.back() == ',') {
    throw InputError("--box", "",
                     "'" + text + "': expected 6 comma-separated numbers xmin,ymin,zmin,xmax,ymax,zmax (metres)");
  }
  while (std::getline(s, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InputError("--box", "",
                       "'" + item + "' is not a number (expected xmin,ymin,zmin,xmax,ymax,zmax in metres)");
    }
  }
  if (values.size() != 6) {
    throw InputError("--box", "",
                     "expected 6 comma-separated numbers xmin,ymin,zmin,xmax,ymax,zmax (metres), got " +
                         std::to_string(values.size()) + " in '" + text + "'");
  }
  options->min_W = Eigen::Vector3d(values[0], values[1], values[2]);
  options->max_W = Eigen::Vector3d(values[3], values[4], values[5]);
}

// One voxel across an axis fuses nothing there: a voxel that large is a unit mistake (the grid
// itself allows it).
void CheckVoxelFitsBox(const fusion::GridOptions& options) {
  const Eigen::Vector3i n = options.Dims();
  for (int a = 0; a < 3; ++a) {
    if (n[a] >= 2) continue;
    std::ostringstream s;
    s << options.voxel_m << " m: the box's "
      << "xyz"[a] << " extent " << (options.max_W[a] - options.min_W[a])
      << " m holds fewer than 2 voxels (the voxel is in metres: 0.00025 is 0.25 mm)";
    throw InputError("--voxel", "", s.str());
  }
}

// The grid the options ask for (the box may still come from a frame directory).
fusion::GridOptions GridFromOptions(const FuseOptions& o) {
  fusion::GridOptions grid;
  if (o.box_given) ParseBox(o.box, &grid);
  if (!std::isfinite(o.voxel_m) || !(o.voxel_m > 0.0)) {
    throw InputError("--voxel", "", std::to_string(o.voxel_m) + ": must be a positive size in metres");
  }
  grid.voxel_m = o.voxel_m;
  // Up to 1 TB: beyond that the byte count leaves the size_t the grid compares with.
  if (!(o.max_memory_mb > 0.0 && o.max_memory_mb <= 1e6)) {
    throw InputError("--max-memory-mb", "", std::to_string(o.max_memory_mb) + ": expected 0 < MB <= 1000000");
  }
  grid.max_memory_bytes = static_cast<size_t>(o.max_memory_mb * 1e6);
  if (const std::string problem = grid.Problem(); !problem.empty()) {
    // A sound box leaves the voxel (too many per axis) as the field at fault.
    const bool box_sound = WorldBox{grid.min_W, grid.max_W}.Problem().empty();
    throw InputError(box_sound ? "--voxel" : "--box", "", problem);
  }
  CheckVoxelFitsBox(grid);
  fusion::InserterOptions inserter;
  inserter.threads = o.threads;
  if (const std::string p = inserter.Problem(); !p.empty()) throw InputError("--threads", "", p);
  return grid;
}

// Default output folder: beside a directory or .oni file; a device has no place of its own.
fs::path DefaultOutput(const FuseOptions& o) {
  // The source's own name, without trailing separators ("scan1/" is "scan1", "." the folder's
  // name): the output lies beside it, never inside.
  fs::path source = WithoutTrailingSeparators(o.source);
  if (source.empty() || source.filename() == "." || source.filename() == "..") {
    source = fs::absolute(source).lexically_normal().parent_path();
  }
  switch (openni2::ClassifySource(o.source)) {
    case openni2::SourceKind::kFrameDirectory: return fs::path(source.string() + "_fused");
    case openni2::SourceKind::kOniFile: return fs::path(source).replace_extension().string() + "_fused";
    case openni2::SourceKind::kDevice: break;
  }
  throw InputError("--out", "", "missing: fusing a live device (" + o.source + ") needs an output folder");
}

// What fuse reads: the source, and for a device or recording with a calibrated depth model, the
// model that turns the chip's raw shifts into depth (as the simulated pipeline applies it).
struct FuseSource {
  std::unique_ptr<FrameSource> source;
  std::optional<DepthCorrection> depth_model;
  ChipGeometry chip;
  std::string depth_from;  // for the report
};

// A frame directory's frames.json holds camera and poses: the options for streams do not apply
// (a frame directory may take --calibration for its depth model alone: `calibration_allowed`).
void RefuseStreamOptions(const FuseOptions& o, bool calibration_allowed = false) {
  for (const auto& [flag, given] : {std::pair<const char*, bool>{"--poses", !o.poses.empty()},
                                    {"--calibration", !o.calibration.empty() && !calibration_allowed},
                                    {"--camera", !o.camera.empty()},
                                    {"--pose-offset", o.pose_offset_given},
                                    {"--device-depth", o.device_depth},
                                    {"--timeout", o.timeout_given}}) {
    if (given) {
      throw InputError(flag, "",
                       std::string("applies to .oni files and devices; ") + o.source +
                           " is a frame directory, whose frames.json holds the camera and the poses");
    }
  }
}

// A calibration's per-pixel depth maps must be the frames' camera's size.
void CheckDepthModelSize(const std::string& file, const DepthCorrection& model, const CameraModel& camera) {
  if (model.a.cols != camera.width || model.a.rows != camera.height) {
    throw InputError(file, "depth_model",
                     "maps are " + std::to_string(model.a.cols) + " x " + std::to_string(model.a.rows) +
                         ", the camera is " + std::to_string(camera.width) + " x " + std::to_string(camera.height));
  }
}

// The source as OpenSource opens it for fusion: a frame directory as is (its frames.json holds
// camera and poses); an .oni file or a device with a pose log for T_B_H and a calibration for
// T_H_C, the camera and the depth model (then raw shifts are read), no IR.
FuseSource OpenFuseSource(const FuseOptions& o) {
  openni2::OpenSourceOptions options;
  options.invalid_depth = InvalidDepthPolicy::kSkip;
  if (IsBopScene(o.source)) {
    RefuseStreamOptions(o);  // scene_camera.json holds the poses, camera.json the camera
    return {OpenBopScene(o.source), std::nullopt, {}, "the BOP scene's sensor depth (depth/)"};
  }
  if (openni2::ClassifySource(o.source) == openni2::SourceKind::kFrameDirectory) {
    RefuseStreamOptions(o, true);
    FuseSource fuse{openni2::OpenSource(o.source, options), std::nullopt, {}, "the frame directory's depth"};
    if (!o.calibration.empty()) {
      // The directory's own camera and poses; the calibration's depth model on its raw images.
      const calib::Calibration calibration = calib::LoadDeviceCalibration(o.calibration);
      if (!calibration.depth) {
        throw InputError(o.calibration, "depth_model",
                         "missing: with a frame directory, --calibration gives the depth model applied to its raw "
                         "images (the directory's frames.json holds the camera and the poses)");
      }
      CheckDepthModelSize(o.calibration, *calibration.depth, fuse.source->camera());
      fuse.depth_model = calibration.depth;
      fuse.chip = calibration.chip;
      fuse.depth_from = std::string("the calibration's depth model (") +
                        DepthCorrectionModelName(calibration.depth->model) + ") on the frame directory's raw images";
    }
    return fuse;
  }
  if (o.poses.empty()) {
    throw InputError("--poses", "",
                     "missing: " + o.source +
                         " carries no robot poses; give the robot's pose log (CSV of T_B_H with times)");
  }
  if (o.calibration.empty()) {
    throw InputError("--calibration", "",
                     "missing: turning the pose log's flange poses into camera poses needs "
                     "the calibration file's hand-eye pose T_H_C");
  }
  const calib::Calibration calibration = calib::LoadDeviceCalibration(o.calibration);
  if (const std::string warning = calib::HandEyeWarning(calibration, o.calibration); !warning.empty()) {
    std::fprintf(stderr, "romunect: warning: %s\n", warning.c_str());
  }
  options.pose_log = o.poses;
  options.pose.time_offset_s = o.pose_offset_s;
  options.pose.T_H_C = calibration.T_H_C;  // world = robot base
  options.openni2.camera = o.camera.empty() ? calibration.camera : CameraModel::Load(o.camera);
  options.openni2.ir = false;  // fusion reads depth only
  options.openni2.timeout_s = o.timeout_s;
  FuseSource fuse;
  if (calibration.depth && !o.device_depth) {
    CheckDepthModelSize(o.calibration, *calibration.depth, *options.openni2.camera);
    options.openni2.raw = true;  // the model reads the chip's raw shifts
    fuse.depth_model = calibration.depth;
    fuse.chip = calibration.chip;
    fuse.depth_from = std::string("the calibration's depth model (") +
                      DepthCorrectionModelName(calibration.depth->model) + ") on the device's raw shifts";
  } else {
    fuse.depth_from = "the device's metric depth";
  }
  fuse.source = openni2::OpenSource(o.source, options);
  return fuse;
}

// "[xmin, xmax] x [ymin, ymax] x [zmin, zmax] m".
std::string BoxText(const fusion::GridOptions& box) {
  std::ostringstream s;
  s.precision(4);
  for (int a = 0; a < 3; ++a) s << (a > 0 ? " x [" : "[") << box.min_W[a] << ", " << box.max_W[a] << "]";
  s << " m";
  return s.str();
}

// The ground truth (--gt), when given, must lie on the grid's cells.
void CheckGroundTruth(const FuseOptions& o, const cv::Mat& gt, const fusion::VotingGrid& grid,
                      const std::string& box_text) {
  if (gt.empty()) return;
  if (gt.rows != grid.ny() || gt.cols != grid.nx()) {
    throw InputError(o.gt, "size",
                     std::to_string(gt.cols) + " x " + std::to_string(gt.rows) + " cells, expected the grid's " +
                         std::to_string(grid.nx()) + " x " + std::to_string(grid.ny()) + " (same box and voxel)");
  }
  // A map that records where its cells lie (romunect writes that) must lie on the grid's cells:
  // one of the same size over another box would be compared cell by cell with the wrong ground.
  if (const std::optional<HeightMapGeometry> g = ReadHeightMapGeometry(o.gt)) {
    const HeightMapGeometry mine = grid.geometry();
    constexpr double kSameM = 1e-9;  // both are doubles from the same numbers: only rounding
    if (std::abs(g->min_x_m - mine.min_x_m) > kSameM || std::abs(g->min_y_m - mine.min_y_m) > kSameM ||
        std::abs(g->voxel_m - mine.voxel_m) > kSameM) {
      std::ostringstream s;
      s << "its cells start at (" << g->min_x_m << ", " << g->min_y_m << ") m with " << g->voxel_m * 1e3
        << " mm voxels; the grid's at (" << mine.min_x_m << ", " << mine.min_y_m << ") m with " << mine.voxel_m * 1e3
        << " mm (box " << box_text << "): give the box and voxel the ground truth was made for";
      const bool voxel = std::abs(g->voxel_m - mine.voxel_m) > kSameM;
      throw InputError(o.gt, voxel ? "romunect.voxel_m" : "romunect.min_W", s.str());
    }
  }
}

// fuse's part of the fusion loop: a broken frame directory is bad input, a stream's bad frame is
// skipped, a device that is gone keeps what was fused; the depth model applies to raw shifts.
class FuseHooks : public FrameHooks {
 public:
  FuseHooks(const FuseOptions& o, const FuseSource& opened, const FrameDirectorySource* directory,
            const CalibrationPerturbation& perturbation)
      : opened_(opened),
        perturbation_(perturbation),
        directory_(directory),
        where_(directory != nullptr ? (fs::path(o.source) / "frames.json").string() : o.source),
        camera_(opened.source->camera()),
        frame_count_(directory != nullptr ? directory->manifest().frames.size() : 0) {}

  bool KeepAfterSourceError(const InputError&) override { return directory_ == nullptr; }

  void OnBadFrame(size_t i, const Frame& frame, const std::string& error) override {
    if (directory_ != nullptr) throw InputError(where_, Field(i, frame), error);
    // A stream's frame outside the pose log (before or after the robot's log): skip it.
    std::fprintf(stderr, "\nromunect: warning: %s: %s, skipped\n", Field(i, frame).c_str(), error.c_str());
  }

  void Prepare(size_t i, Frame* frame) override {
    const std::string field = Field(i, *frame);
    if (opened_.depth_model && !frame->raw.empty()) {
      frame->depth_m = ApplyDepthCorrection(*opened_.depth_model, frame->raw, opened_.chip);
    } else if (opened_.depth_model && directory_ != nullptr) {
      throw InputError(where_, field + ".raw", "missing: the calibration's depth model reads the raw image");
    }
    if (frame->depth_m.empty()) throw InputError(where_, field + ".depth", "missing: fuse needs depth");
    if (!frame->T_W_C) throw InputError(where_, field + ".T_W_C", "missing: fuse needs the camera pose");
    if (frame->depth_m.rows != camera_.height || frame->depth_m.cols != camera_.width) {
      throw InputError(where_, field + ".depth",
                       "is " + std::to_string(frame->depth_m.cols) + " x " + std::to_string(frame->depth_m.rows) +
                           ", the camera is " + std::to_string(camera_.width) + " x " + std::to_string(camera_.height));
    }
    // --perturb: the calibration's pose and depth model as if wrong by the injected errors
    if (!perturbation_.empty()) {
      *frame->T_W_C = *frame->T_W_C * perturbation_.T_C_Cp();
      perturbation_.ApplyToDepth(&frame->depth_m);
    }
  }

  void OnFused(size_t i, const Frame&, const FusionSummary& summary) override {
    const fusion::FusionReport& r = summary.report;
    // One updating line on a terminal; in a log a line every 10 frames and at the last.
    if (!interactive_ && (i + 1) % 10 != 0 && i + 1 != frame_count_) return;
    std::fprintf(stderr, "%sfuse: frame %zu", interactive_ ? "\r" : "", i + 1);
    if (frame_count_ > 0) std::fprintf(stderr, "/%zu", frame_count_);
    std::fprintf(stderr, ", insert %.1f ms, completeness %.1f %%%s", r.insert_ms.back(),
                 100.0 * r.completeness_per_frame.back(), interactive_ ? "   " : "\n");
  }

 private:
  // A frame directory's frames are named by their frames.json entry; a stream's by its index.
  std::string Field(size_t i, const Frame& frame) const {
    return directory_ != nullptr ? "frames[" + std::to_string(i) + "]" : "frame " + std::to_string(frame.index);
  }

  const FuseSource& opened_;
  const bool interactive_ = isatty(fileno(stderr));
  const CalibrationPerturbation perturbation_;
  const FrameDirectorySource* directory_;
  const std::string where_;
  const CameraModel camera_;
  const size_t frame_count_;
};

// No frame fused, no valid depth pixel, or no ray into the box: every output would be an empty
// map, so none is written (a rerun into --out stays open).
void CheckSomethingFused(const FuseOptions& o, const FusionSummary& fused, bool directory,
                         const std::string& depth_from, const std::string& box_text) {
  const fusion::FusionReport& report = fused.report;
  const std::string stopped = fused.stopped ? "; it stopped: " + *fused.stopped : "";
  if (report.frames == 0) {
    const std::string why = directory ? "frames.json lists no frame"
                            : report.bad_frames > 0
                                ? "all " + std::to_string(report.bad_frames) + " frames were skipped (" +
                                      report.bad_frame_messages.front() + ")"
                                : "the source delivered no frame";
    throw InputError(o.source, "", "nothing to fuse: " + why + stopped);
  }
  // Frames without one valid depth pixel (a dark scene, a depth model that fits no pixel).
  if (report.stats.rays == 0) {
    throw InputError(o.source, "",
                     "nothing to fuse: no frame has a valid depth pixel: of the " +
                         std::to_string(report.stats.pixels) + " pixels of the " + std::to_string(report.frames) +
                         " frames, " + std::to_string(report.stats.no_measurement) + " have no measurement and " +
                         std::to_string(report.stats.invalid_depth) + " NaN, inf or negative depth (depth from " +
                         depth_from + ")" + stopped);
  }
  // Depth that never reaches the box, or reaches it only on the way to points beyond it, is a
  // box that misses the scene, not an empty scene.
  if (report.stats.hits == 0) {
    const Eigen::AlignedBox3d& c = fused.cameras_W;
    std::ostringstream where_cameras;
    where_cameras.precision(3);
    where_cameras << "x " << c.min().x() << ".." << c.max().x() << ", y " << c.min().y() << ".." << c.max().y()
                  << ", z " << c.min().z() << ".." << c.max().z();
    const std::string what = report.stats.rays == report.stats.rays_missing_box
                                 ? " enters the box "
                                 : " ends inside the box (" +
                                       std::to_string(report.stats.rays - report.stats.rays_missing_box) +
                                       " cross it to points beyond, " + std::to_string(report.stats.rays_missing_box) +
                                       " miss it) ";
    throw InputError(o.box_given ? "--box" : o.source, "",
                     "none of the " + std::to_string(report.stats.rays) + " depth rays of the " +
                         std::to_string(report.frames) + " frames" + what + box_text + "; the cameras were at " +
                         where_cameras.str() +
                         " m (world). Give the scene's region as --box xmin,ymin,zmin,xmax,ymax,zmax (metres)");
  }
}

// The fused map and its files.
void WriteFuseOutputs(const fs::path& out, const FuseJobSummary& s, const cv::Mat& height) {
  WriteHeightMapExr(out / "fused_depth.exr", height, s.report.geometry);
  fusion::WriteHeightMapPicture(out / "fused_depth.png", height, s.report.geometry);
  fusion::WriteHeightMapPly(out / "fused_points.ply", height, s.report.geometry);
  fusion::WriteCompletenessPlot(out / "completeness.png", s.report.completeness_per_frame);
  // The fusion's report, plus whether the source ended or stopped early (and why).
  nlohmann::ordered_json json = nlohmann::ordered_json::parse(fusion::FusionReportJson(s.report));
  json["depth_from"] = s.depth_from;
  json["box_from"] = s.box_from;
  json["dropped_frames"] = s.dropped_frames;
  json["stopped_early"] = s.stopped.has_value();
  if (s.stopped) json["stop_reason"] = *s.stopped;
  WriteTextAtomically(out / "report.json", json.dump(2) + "\n");
}

}  // namespace

FuseJobSummary RunFuse(const FuseOptions& o) {
  // Options first: a bad option fails before any file is read.
  fusion::GridOptions grid_options = GridFromOptions(o);
  const CalibrationPerturbation perturbation = ParsePerturbation(o.perturb);
  FuseJobSummary s;
  // The outputs are built in <out>.incomplete and renamed when all are written (RunFolder).
  RunFolder run(o.out.empty() ? DefaultOutput(o).string() : o.out, "--out", "fusion");
  s.out = run.dir();
  s.perturbation = perturbation.Text();
  const FuseSource opened = OpenFuseSource(o);  // validates frames.json
  s.depth_from = opened.depth_from;
  const FrameDirectorySource* directory = openni2::FindFrameDirectorySource(opened.source.get());
  // The box: --box, else the region the frame directory records, else the default.
  s.box_from = o.box_given ? "--box" : "the default box";
  if (!o.box_given && directory != nullptr && directory->manifest().region_W) {
    grid_options.min_W = directory->manifest().region_W->min_W;
    grid_options.max_W = directory->manifest().region_W->max_W;
    s.box_from = "frames.json's region_W";
    if (const std::string problem = grid_options.Problem(); !problem.empty()) {
      throw InputError((fs::path(o.source) / "frames.json").string(), "region_W", problem);
    }
    CheckVoxelFitsBox(grid_options);
  }
  if (!o.box_given && IsBopScene(o.source)) {
    if (const std::optional<WorldBox> region = BopSceneRegion(o.source)) {
      grid_options.min_W = region->min_W;
      grid_options.max_W = region->max_W;
      s.box_from = "scene_info.json's region_W";
      if (const std::string problem = grid_options.Problem(); !problem.empty()) {
        throw InputError((fs::path(o.source) / "scene_info.json").string(), "region_W", problem);
      }
      CheckVoxelFitsBox(grid_options);
    }
  }
  const cv::Mat gt = o.gt.empty() ? cv::Mat() : ReadDepthExr(o.gt);
  fusion::VotingGrid grid(grid_options);  // throws with the size needed when it does not fit
  const std::string box_text = BoxText(grid_options) + " (" + s.box_from + ")";
  CheckGroundTruth(o, gt, grid, box_text);
  const double grid_mb = grid.memory_bytes() / 1e6;
  std::fprintf(stderr, "fuse: %s, box %s, grid %d x %d x %d at %.3g mm (%.1f MB), %d thread(s)\n",
               opened.source->Describe().c_str(), box_text.c_str(), grid.nx(), grid.ny(), grid.nz(),
               grid.voxel_m() * 1e3, grid_mb, o.threads);
  if (const openni2::OpenNI2Source* d = openni2::FindOpenNI2Source(opened.source.get());
      d != nullptr && !opened.depth_model) {  // metric depth on the wire, not raw shifts
    s.depth_unit_warning = DepthUnitWarning(d->depth_unit() == openni2::DepthUnit::k1mm ? 1e-3 : 1e-4, grid.voxel_m());
    if (s.depth_unit_warning)
      std::fprintf(stderr, "romunect: warning: %s: %s\n", o.source.c_str(), s.depth_unit_warning->c_str());
  }
  run.Begin();  // a second run into the same --out is refused here, before any frame is fused
  FuseHooks hooks(o, opened, directory, perturbation);
  FusionSummary fused = FuseFrames(*opened.source, perturbation.Apply(opened.source->camera()), grid, o.threads, hooks);
  if (isatty(fileno(stderr))) std::fprintf(stderr, "\n");  // ends the updating line
  // A device that skipped frame numbers lost frames fuse could not keep up with (or the link
  // dropped): the map misses them, so the report counts them.
  const openni2::OpenNI2Source* device = openni2::FindOpenNI2Source(opened.source.get());
  s.dropped_frames = device != nullptr ? device->stats().dropped_frames : 0;
  if (s.dropped_frames > 0) {
    std::fprintf(stderr,
                 "romunect: warning: %s dropped %d frame(s) (gaps in its frame numbers): fusion was too slow "
                 "for its rate, or the link lost them\n",
                 o.source.c_str(), s.dropped_frames);
  }
  CheckSomethingFused(o, fused, directory != nullptr, opened.depth_from, box_text);

  s.report = std::move(fused.report);
  s.stopped = fused.stopped;
  fusion::FusionReport& report = s.report;
  report.input = perturbation.empty() ? o.source : o.source + " (calibration perturbed: " + s.perturbation + ")";
  report.geometry = grid.geometry();
  report.max_x_m = grid_options.max_W.x();
  report.max_y_m = grid_options.max_W.y();
  report.max_z_m = grid_options.max_W.z();
  report.grid_mb = grid_mb;
  const Stopwatch extract;
  const cv::Mat height = fusion::ExtractHeightMap(grid, Isa::kAuto, o.threads);
  report.extract_ms = extract.milliseconds();
  report.completeness = fusion::Completeness(height);
  report.skipped_pixels = directory != nullptr ? directory->skipped_pixels() : 0;
  if (!gt.empty()) report.metrics = fusion::CompareHeightMaps(height, gt);
  report.peak_rss_mb = fusion::PeakRssMb();
  WriteFuseOutputs(run.work_dir(), s, height);
  run.Commit();
  return s;
}

std::string FuseSummaryText(const FuseJobSummary& s) {
  const fusion::FusionReport& r = s.report;
  std::string text = Format("fused %zu frames into %s: completeness %.1f %%", r.frames, s.out.string().c_str(),
                            100.0 * r.completeness);
  if (s.perturbation != "none") text = "injected calibration errors: " + s.perturbation + "\n" + text;
  if (r.metrics && r.metrics->compared_cells == 0) {
    text += ", no fused cell where the ground truth has a value (no error to report)";
  } else if (r.metrics) {
    text += Format(", RMSE %.3f mm, MAE %.3f mm, within 1 mm %.1f %%", r.metrics->rmse_mm, r.metrics->mae_mm,
                   100.0 * r.metrics->within_1mm);
  }
  text += Format("\ninsert %.2f ms per frame (median), extract %.2f ms, peak memory %.0f MB; %zu pixels skipped "
                 "(NaN/inf/negative), %zu frames skipped, %d dropped by the device\n",
                 fusion::Quantile(r.insert_ms, 0.5), r.extract_ms, r.peak_rss_mb, r.skipped_pixels, r.bad_frames,
                 s.dropped_frames);
  return text + r.stats.BriefReport() + "\n";
}

std::optional<std::string> DepthUnitWarning(double depth_unit_m, double voxel_m) {
  if (depth_unit_m <= 0.5 * voxel_m) return std::nullopt;
  std::ostringstream s;
  s << "depth arrives in " << (depth_unit_m >= 1e-3 ? "1 mm" : "100 um") << " steps, coarser than half the "
    << voxel_m * 1e3 << " mm voxel: the map rounds depths to it (record in 100 um: `record --depth-unit 100um`)";
  return s.str();
}

void CheckSourceEnded(const FuseJobSummary& s, const FuseOptions& o) {
  if (!s.stopped) return;
  // Exit non-zero with the device's message, after the outputs of the frames so far.
  throw InputError(o.source, "",
                   "stopped early after " + std::to_string(s.report.frames) + " fused frames (outputs written to " +
                       s.out.string() + "): " + *s.stopped);
}

}  // namespace romunect::jobs
