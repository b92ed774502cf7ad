// romunect fuse SOURCE: fuses the depth maps of a frame directory, an .oni recording or a live
// OpenNI2 device (sources as OpenSource reads them; the last two with a pose log and a
// calibration for the camera poses and, when it has one, the depth model applied to the chip's
// raw shifts) into one height map (fusion/) and writes fused_depth.exr,
// fused_depth.png, fused_points.ply, completeness.png, report.json. A device that stops
// mid-scan ends the run with an error, after the outputs of the frames fused so far are written.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include "commands.h"
#include "output_folder.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/openni2/open_source.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"

namespace romunect::tools {
namespace {

namespace fs = std::filesystem;

struct FuseArguments {
  std::string source, out, gt, box;
  bool box_given = false;
  double voxel_m = 0.25e-3;
  int threads = 1;
  double max_memory_mb = 16384.0;
  // OpenNI2 sources (.oni files, devices) only.
  std::string poses, calibration, camera;
  double pose_offset_s = 0.0;
  double timeout_s = 2.0;
  bool device_depth = false;  // fuse the device's metric depth even with a depth model
  bool pose_offset_given = false, timeout_given = false;
};

double NowMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// "--box xmin,ymin,zmin,xmax,ymax,zmax" in metres.
void ParseBox(const std::string& text, fusion::GridOptions* options) {
  std::vector<double> values;
  std::stringstream s(text);
  std::string item;
  if (text.empty() || text.back() == ',') {
    throw InputError("--box", "", "'" + text + "': expected 6 comma-separated numbers xmin,ymin,zmin,xmax,ymax,zmax (metres)");
  }
  while (std::getline(s, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InputError("--box", "", "'" + item + "' is not a number (expected xmin,ymin,zmin,xmax,ymax,zmax in metres)");
    }
  }
  if (values.size() != 6) {
    throw InputError("--box", "", "expected 6 comma-separated numbers xmin,ymin,zmin,xmax,ymax,zmax (metres), got " +
                                      std::to_string(values.size()) + " in '" + text + "'");
  }
  options->min_W = Eigen::Vector3d(values[0], values[1], values[2]);
  options->max_W = Eigen::Vector3d(values[3], values[4], values[5]);
}

// What fuse reads: the source, and for a device or recording with a calibrated depth model, the
// model that turns the chip's raw shifts into depth (as the simulated pipeline applies it).
struct FuseSource {
  std::unique_ptr<FrameSource> source;
  std::optional<DepthCorrection> depth_model;
  ChipGeometry chip;
  std::string depth_from;  // for the report
};

// The source as OpenSource opens it for fusion: a frame directory as is (its frames.json holds
// camera and poses); an .oni file or a device with a pose log for T_B_H and a calibration for
// T_H_C, the camera and the depth model (then raw shifts are read), no IR.
FuseSource OpenFuseSource(const FuseArguments& args) {
  const openni2::SourceKind kind = openni2::ClassifySource(args.source);
  openni2::OpenSourceOptions options;
  options.invalid_depth = InvalidDepthPolicy::kSkip;
  if (kind == openni2::SourceKind::kFrameDirectory) {
    for (const auto& [flag, given] : {std::pair<const char*, bool>{"--poses", !args.poses.empty()},
                                      {"--calibration", !args.calibration.empty()},
                                      {"--camera", !args.camera.empty()},
                                      {"--pose-offset", args.pose_offset_given},
                                      {"--device-depth", args.device_depth},
                                      {"--timeout", args.timeout_given}}) {
      if (given) {
        throw InputError(flag, "", std::string("applies to .oni files and devices; ") + args.source +
                                       " is a frame directory, whose frames.json holds the camera and the poses");
      }
    }
    return {openni2::OpenSource(args.source, options), std::nullopt, {}, "the frame directory's depth"};
  }
  if (args.poses.empty()) {
    throw InputError("--poses", "", "missing: " + args.source +
                                        " carries no robot poses; give the robot's pose log (CSV of T_B_H with times)");
  }
  if (args.calibration.empty()) {
    throw InputError("--calibration", "", "missing: turning the pose log's flange poses into camera poses needs "
                                          "the calibration file's hand-eye pose T_H_C");
  }
  const calib::Calibration calibration = calib::LoadDeviceCalibration(args.calibration);
  if (const std::string warning = calib::HandEyeWarning(calibration, args.calibration); !warning.empty()) {
    std::fprintf(stderr, "romunect: warning: %s\n", warning.c_str());
  }
  options.pose_log = args.poses;
  options.pose.time_offset_s = args.pose_offset_s;
  options.pose.T_H_C = calibration.T_H_C;  // world = robot base
  options.openni2.camera = args.camera.empty() ? calibration.camera : CameraModel::Load(args.camera);
  options.openni2.ir = false;  // fusion reads depth only
  options.openni2.timeout_s = args.timeout_s;
  FuseSource fuse;
  if (calibration.depth && !args.device_depth) {
    const CameraModel& camera = *options.openni2.camera;
    if (calibration.depth->a.cols != camera.width || calibration.depth->a.rows != camera.height) {
      throw InputError(args.calibration, "depth_model",
                       "maps are " + std::to_string(calibration.depth->a.cols) + " x " +
                           std::to_string(calibration.depth->a.rows) + ", the camera is " + std::to_string(camera.width) +
                           " x " + std::to_string(camera.height));
    }
    options.openni2.raw = true;  // the model reads the chip's raw shifts
    fuse.depth_model = calibration.depth;
    fuse.chip = calibration.chip;
    fuse.depth_from = std::string("the calibration's depth model (") + DepthCorrectionModelName(calibration.depth->model) +
                      ") on the device's raw shifts";
  } else {
    fuse.depth_from = "the device's metric depth";
  }
  fuse.source = openni2::OpenSource(args.source, options);
  return fuse;
}

// Default output folder: beside a directory or .oni file; a device has no place of its own.
fs::path DefaultOutput(const FuseArguments& args) {
  // The source's own name, without trailing separators ("scan1/" is "scan1", "." the folder's
  // name): the output lies beside it, never inside.
  fs::path source = WithoutTrailingSeparators(args.source);
  if (source.empty() || source.filename() == "." || source.filename() == "..") {
    source = fs::absolute(source).lexically_normal().parent_path();
  }
  switch (openni2::ClassifySource(args.source)) {
    case openni2::SourceKind::kFrameDirectory: return fs::path(source.string() + "_fused");
    case openni2::SourceKind::kOniFile: return fs::path(source).replace_extension().string() + "_fused";
    case openni2::SourceKind::kDevice: break;
  }
  throw InputError("--out", "", "missing: fusing a live device (" + args.source + ") needs an output folder");
}

// One voxel across an axis fuses nothing there: a voxel that large is a unit mistake (the grid
// itself allows it).
void CheckVoxelFitsBox(const fusion::GridOptions& options) {
  const Eigen::Vector3i n = options.Dims();
  for (int a = 0; a < 3; ++a) {
    if (n[a] >= 2) continue;
    std::ostringstream s;
    s << options.voxel_m << " m: the box's " << "xyz"[a] << " extent " << (options.max_W[a] - options.min_W[a])
      << " m holds fewer than 2 voxels (the voxel is in metres: 0.00025 is 0.25 mm)";
    throw InputError("--voxel", "", s.str());
  }
}

// "[xmin, xmax] x [ymin, ymax] x [zmin, zmax] m".
std::string BoxText(const fusion::GridOptions& box) {
  std::ostringstream s;
  s.precision(4);
  for (int a = 0; a < 3; ++a) s << (a > 0 ? " x [" : "[") << box.min_W[a] << ", " << box.max_W[a] << "]";
  s << " m";
  return s.str();
}

void RunFuse(const FuseArguments& args) {
  // Options first: a bad option fails before any file is read.
  fusion::GridOptions grid_options;
  if (args.box_given) ParseBox(args.box, &grid_options);
  if (!std::isfinite(args.voxel_m) || !(args.voxel_m > 0.0)) {
    throw InputError("--voxel", "", std::to_string(args.voxel_m) + ": must be a positive size in metres");
  }
  grid_options.voxel_m = args.voxel_m;
  // Up to 1 TB: beyond that the byte count leaves the size_t the grid compares with.
  if (!(args.max_memory_mb > 0.0 && args.max_memory_mb <= 1e6)) {
    throw InputError("--max-memory-mb", "", std::to_string(args.max_memory_mb) + ": expected 0 < MB <= 1000000");
  }
  grid_options.max_memory_bytes = static_cast<size_t>(args.max_memory_mb * 1e6);
  const std::string box_problem = grid_options.Problem();
  if (!box_problem.empty()) {
    throw InputError(box_problem.find("voxel_m") != std::string::npos ? "--voxel" : "--box", "", box_problem);
  }
  CheckVoxelFitsBox(grid_options);
  fusion::InserterOptions inserter_options;
  inserter_options.threads = args.threads;
  if (const std::string p = inserter_options.Problem(); !p.empty()) throw InputError("--threads", "", p);
  const fs::path out = args.out.empty() ? DefaultOutput(args) : OutputFolder(args.out, "--out");
  if (fs::exists(out / "report.json")) {
    throw InputError(out.string(), "", "holds a finished fusion (report.json); refusing to overwrite it: give "
                                       "another --out or remove the folder");
  }
  CheckFolderCanBeCreated(out, "--out");

  const FuseSource opened = OpenFuseSource(args);  // validates frames.json
  const std::unique_ptr<FrameSource>& source = opened.source;
  const FrameDirectorySource* directory = openni2::FindFrameDirectorySource(source.get());
  // The box: --box, else the region the frame directory records, else the default.
  std::string box_from = args.box_given ? "--box" : "the default box";
  if (!args.box_given && directory != nullptr && directory->manifest().region_W) {
    grid_options.min_W = directory->manifest().region_W->min_W;
    grid_options.max_W = directory->manifest().region_W->max_W;
    box_from = "frames.json's region_W";
    if (const std::string problem = grid_options.Problem(); !problem.empty()) {
      throw InputError((fs::path(args.source) / "frames.json").string(), "region_W", problem);
    }
    CheckVoxelFitsBox(grid_options);
  }
  const CameraModel camera = source->camera();
  const size_t frame_count = directory != nullptr ? directory->manifest().frames.size() : 0;
  cv::Mat gt;
  if (!args.gt.empty()) gt = ReadDepthExr(args.gt);

  fusion::VotingGrid grid(grid_options);  // throws with the size needed when it does not fit
  const std::string box_text = BoxText(grid_options) + " (" + box_from + ")";
  if (!gt.empty() && (gt.rows != grid.ny() || gt.cols != grid.nx())) {
    throw InputError(args.gt, "size",
                     std::to_string(gt.cols) + " x " + std::to_string(gt.rows) + " cells, expected the grid's " +
                         std::to_string(grid.nx()) + " x " + std::to_string(grid.ny()) + " (same box and voxel)");
  }
  // A map that records where its cells lie (romunect writes that) must lie on the grid's cells:
  // one of the same size over another box would be compared cell by cell with the wrong ground.
  if (const std::optional<HeightMapGeometry> g = gt.empty() ? std::nullopt : ReadHeightMapGeometry(args.gt)) {
    const HeightMapGeometry mine = grid.geometry();
    constexpr double kSameM = 1e-9;  // both are doubles from the same numbers: only rounding
    if (std::abs(g->min_x_m - mine.min_x_m) > kSameM || std::abs(g->min_y_m - mine.min_y_m) > kSameM ||
        std::abs(g->voxel_m - mine.voxel_m) > kSameM) {
      std::ostringstream s;
      s << "its cells start at (" << g->min_x_m << ", " << g->min_y_m << ") m with " << g->voxel_m * 1e3
        << " mm voxels; the grid's at (" << mine.min_x_m << ", " << mine.min_y_m << ") m with " << mine.voxel_m * 1e3
        << " mm (box " << box_text << "): give the box and voxel the ground truth was made for";
      const bool voxel = std::abs(g->voxel_m - mine.voxel_m) > kSameM;
      throw InputError(args.gt, voxel ? "romunect.voxel_m" : "romunect.min_W", s.str());
    }
  }
  fusion::FrameInserter inserter(&grid, inserter_options);
  fusion::CompletenessTracker tracker(grid);  // the per-frame curve, without extracting every frame

  fusion::FusionReport report;
  report.input = args.source;
  report.threads = args.threads;
  report.geometry = grid.geometry();
  report.max_x_m = grid_options.max_W.x();
  report.max_y_m = grid_options.max_W.y();
  report.max_z_m = grid_options.max_W.z();
  report.grid_mb = grid.memory_bytes() / 1e6;
  std::fprintf(stderr, "fuse: %s, box %s, grid %d x %d x %d at %.3g mm (%.1f MB), %d thread(s)\n",
               source->Describe().c_str(), box_text.c_str(), grid.nx(), grid.ny(), grid.nz(), grid.voxel_m() * 1e3,
               report.grid_mb, args.threads);
  Eigen::AlignedBox3d cameras_W;  // where the cameras were, for a box no ray enters

  // A frame directory's frames are named by their frames.json entry; a stream's by its index.
  const std::string where = directory != nullptr ? (fs::path(args.source) / "frames.json").string() : args.source;
  Frame frame;
  std::string error;
  std::optional<std::string> stopped;  // why the source stopped before its end
  for (size_t i = 0;; ++i) {
    FrameStatus status;
    try {
      status = source->Next(&frame, &error);
    } catch (const InputError& e) {
      if (directory != nullptr) throw;  // a broken directory is bad input, not a stopped device
      stopped = e.what();  // the device is gone: keep what was fused
      break;
    }
    if (status == FrameStatus::kEndOfStream) break;
    const std::string field = directory != nullptr ? "frames[" + std::to_string(i) + "]" : "frame " + std::to_string(frame.index);
    if (status == FrameStatus::kBadFrame) {
      if (directory != nullptr) throw InputError(where, field, error);
      // A stream's frame outside the pose log (before or after the robot's log): skip it.
      ++report.bad_frames;
      report.bad_frame_messages.push_back(error);
      std::fprintf(stderr, "\nromunect: warning: %s: %s, skipped\n", field.c_str(), error.c_str());
      continue;
    }
    if (opened.depth_model && !frame.raw.empty()) frame.depth_m = ApplyDepthCorrection(*opened.depth_model, frame.raw, opened.chip);
    if (frame.depth_m.empty()) throw InputError(where, field + ".depth", "missing: fuse needs depth");
    if (!frame.T_W_C) throw InputError(where, field + ".T_W_C", "missing: fuse needs the camera pose");
    if (frame.depth_m.rows != camera.height || frame.depth_m.cols != camera.width) {
      throw InputError(where, field + ".depth",
                       "is " + std::to_string(frame.depth_m.cols) + " x " + std::to_string(frame.depth_m.rows) +
                           ", the camera is " + std::to_string(camera.width) + " x " + std::to_string(camera.height));
    }
    cameras_W.extend(frame.T_W_C->translation());
    const double t0 = NowMs();
    inserter.Insert(camera, frame.depth_m, *frame.T_W_C, &report.stats);
    report.insert_ms.push_back(NowMs() - t0);
    const double completeness = tracker.Update(inserter.changed_columns());
    report.completeness_per_frame.push_back(completeness);
    ++report.frames;
    if (frame_count > 0) {
      std::fprintf(stderr, "\rfuse: frame %zu/%zu, insert %.1f ms, completeness %.1f %%   ", i + 1, frame_count,
                   report.insert_ms.back(), 100.0 * completeness);
    } else {
      std::fprintf(stderr, "\rfuse: frame %zu, insert %.1f ms, completeness %.1f %%   ", i + 1,
                   report.insert_ms.back(), 100.0 * completeness);
    }
  }
  std::fprintf(stderr, "\n");
  // A device that skipped frame numbers lost frames fuse could not keep up with (or the link
  // dropped): the map misses them, so the report counts them.
  const openni2::OpenNI2Source* device = openni2::FindOpenNI2Source(source.get());
  const int dropped = device != nullptr ? device->stats().dropped_frames : 0;
  if (dropped > 0) {
    std::fprintf(stderr, "romunect: warning: %s dropped %d frame(s) (gaps in its frame numbers): fusion was too slow "
                 "for its rate, or the link lost them\n", args.source.c_str(), dropped);
  }
  // No frame fused: every output would be empty; nothing is written (a rerun into --out stays open).
  if (report.frames == 0) {
    std::string why = directory != nullptr ? "frames.json lists no frame"
                      : report.bad_frames > 0
                          ? "all " + std::to_string(report.bad_frames) + " frames were skipped (" +
                                report.bad_frame_messages.front() + ")"
                          : "the source delivered no frame";
    if (stopped) why += "; it stopped: " + *stopped;
    throw InputError(args.source, "", "nothing to fuse: " + why);
  }
  // Frames without one valid depth pixel (a dark scene, a depth model that fits no pixel): the
  // outputs would be empty maps, so none are written.
  if (report.stats.rays == 0) {
    std::string why = "no frame has a valid depth pixel: of the " + std::to_string(report.stats.pixels) +
                      " pixels of the " + std::to_string(report.frames) + " frames, " +
                      std::to_string(report.stats.no_measurement) + " have no measurement and " +
                      std::to_string(report.stats.invalid_depth) + " NaN, inf or negative depth (depth from " +
                      opened.depth_from + ")";
    if (stopped) why += "; it stopped: " + *stopped;
    throw InputError(args.source, "", "nothing to fuse: " + why);
  }
  // Depth that never reaches the box, or reaches it only on the way to points beyond it, is a
  // box that misses the scene, not an empty scene: the outputs would be empty maps, so none are
  // written.
  if (report.stats.hits == 0) {
    std::ostringstream where_cameras;
    where_cameras.precision(3);
    where_cameras << "x " << cameras_W.min().x() << ".." << cameras_W.max().x() << ", y " << cameras_W.min().y()
                  << ".." << cameras_W.max().y() << ", z " << cameras_W.min().z() << ".." << cameras_W.max().z();
    const std::string what = report.stats.rays == report.stats.rays_missing_box
                                 ? " enters the box "
                                 : " ends inside the box (" +
                                       std::to_string(report.stats.rays - report.stats.rays_missing_box) +
                                       " cross it to points beyond, " +
                                       std::to_string(report.stats.rays_missing_box) + " miss it) ";
    throw InputError(args.box_given ? "--box" : args.source, "",
                     "none of the " + std::to_string(report.stats.rays) + " depth rays of the " +
                         std::to_string(report.frames) + " frames" + what + box_text +
                         "; the cameras were at " + where_cameras.str() +
                         " m (world). Give the scene's region as --box xmin,ymin,zmin,xmax,ymax,zmax (metres)");
  }

  const double t0 = NowMs();
  const cv::Mat height = fusion::ExtractHeightMap(grid, Isa::kAuto, args.threads);
  report.extract_ms = NowMs() - t0;
  report.completeness = fusion::Completeness(height);
  report.skipped_pixels = directory != nullptr ? directory->skipped_pixels() : 0;
  if (!gt.empty()) report.metrics = fusion::CompareHeightMaps(height, gt);
  report.peak_rss_mb = fusion::PeakRssMb();

  fs::create_directories(out);
  WriteHeightMapExr(out / "fused_depth.exr", height, grid.geometry());
  fusion::WriteHeightMapPicture(out / "fused_depth.png", height, grid.geometry());
  fusion::WriteHeightMapPly(out / "fused_points.ply", height, grid.geometry());
  fusion::WriteCompletenessPlot(out / "completeness.png", report.completeness_per_frame);
  // The fusion's report, plus whether the source ended or stopped early (and why).
  nlohmann::ordered_json json = nlohmann::ordered_json::parse(fusion::FusionReportJson(report));
  json["depth_from"] = opened.depth_from;
  json["box_from"] = box_from;
  json["dropped_frames"] = dropped;
  json["stopped_early"] = stopped.has_value();
  if (stopped) json["stop_reason"] = *stopped;
  WriteTextAtomically(out / "report.json", json.dump(2) + "\n");

  std::printf("fused %zu frames into %s: completeness %.1f %%", report.frames, out.string().c_str(),
              100.0 * report.completeness);
  if (report.metrics && report.metrics->compared_cells == 0) {
    std::printf(", no fused cell where the ground truth has a value (no error to report)");
  } else if (report.metrics) {
    std::printf(", RMSE %.3f mm, MAE %.3f mm, within 1 mm %.1f %%", report.metrics->rmse_mm,
                report.metrics->mae_mm, 100.0 * report.metrics->within_1mm);
  }
  std::printf("\ninsert %.2f ms per frame (median), extract %.2f ms, peak memory %.0f MB; %zu pixels skipped "
              "(NaN/inf/negative), %zu frames skipped, %d dropped by the device\n%s\n",
              fusion::Quantile(report.insert_ms, 0.5), report.extract_ms, report.peak_rss_mb, report.skipped_pixels,
              report.bad_frames, dropped, report.stats.BriefReport().c_str());
  if (stopped) {
    std::fflush(stdout);
    // Exit non-zero with the device's message, after the outputs of the frames so far.
    throw InputError(args.source, "",
                     "stopped early after " + std::to_string(report.frames) + " fused frames (outputs written to " +
                         out.string() + "): " + *stopped);
  }
}

}  // namespace

void AddFuseCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "fuse", "Fuse the depth maps of a frame directory, an .oni recording or a live OpenNI2 device into one height map");
  auto args = std::make_shared<FuseArguments>();
  cmd->add_option("SOURCE", args->source,
                  "Frame directory (frames.json with depth and T_W_C per frame), FILE.oni, oni://[URI] or "
                  "romunect:DIR[?...] (the last three with --poses and --calibration)")
      ->required();
  cmd->add_option("--out", args->out, "Output folder (default: SOURCE_fused beside a directory or .oni file)");
  cmd->add_option("--gt", args->gt, "Ground-truth height map (EXR, same box and voxel) for RMSE/MAE");
  auto* box = cmd->add_option("--box", args->box,
                  "Fusion box in world metres: xmin,ymin,zmin,xmax,ymax,zmax (default: the frame directory's "
                  "region_W, as romunect scan records it, else -0.075,-0.04,-0.004,0.075,0.04,0.06)");
  cmd->add_option("--voxel", args->voxel_m, "Voxel size in metres (default 0.00025)");
  cmd->add_option("--threads", args->threads, "Insertion threads (default 1)");
  cmd->add_option("--max-memory-mb", args->max_memory_mb, "Refuse grids larger than this (default 16384)");
  cmd->add_option("--poses,--pose-log", args->poses,
                  ".oni/device: CSV pose log of T_B_H (time_s,x_m,y_m,z_m,qw,qx,qy,qz; docs/openni2.md)");
  auto* pose_offset =
      cmd->add_option("--pose-offset", args->pose_offset_s, ".oni/device: seconds added to frame times to get pose-log times");
  cmd->add_option("--calibration", args->calibration,
                  ".oni/device: romunect calibration file: T_H_C turns flange poses into camera poses (world = robot "
                  "base), and its camera is the frames' camera");
  cmd->add_option("--camera", args->camera, ".oni/device: camera model (OpenCV YAML/JSON) replacing the calibration's");
  cmd->add_flag("--device-depth", args->device_depth,
                ".oni/device: fuse the device's metric depth, not the calibration's depth model applied to raw shifts");
  auto* timeout = cmd->add_option("--timeout", args->timeout_s,
                                  ".oni/device: seconds without a frame before the device counts as gone (default 2)")
                      ->check(CLI::PositiveNumber);
  cmd->callback([args, box, pose_offset, timeout] {
    args->box_given = box->count() > 0;  // --box "" is a bad box, not the default
    args->pose_offset_given = pose_offset->count() > 0;
    args->timeout_given = timeout->count() > 0;
    RunFuse(*args);
  });
}

}  // namespace romunect::tools
