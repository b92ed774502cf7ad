// romunect fuse DIR: fuses the depth maps of a frame directory into one height map (fusion/)
// and writes fused_depth.exr, fused_depth.png, fused_points.ply, completeness.png, report.json.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "commands.h"
#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"

namespace romunect::tools {
namespace {

namespace fs = std::filesystem;

struct FuseArguments {
  std::string dir, out, gt, box;
  double voxel_m = 0.25e-3;
  int threads = 1;
  double max_memory_mb = 16384.0;
};

double NowMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// "--box xmin,ymin,zmin,xmax,ymax,zmax" in metres.
void ParseBox(const std::string& text, fusion::GridOptions* options) {
  std::vector<double> values;
  std::stringstream s(text);
  std::string item;
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

void RunFuse(const FuseArguments& args) {
  // Options first: a bad option fails before any file is read.
  fusion::GridOptions grid_options;
  if (!args.box.empty()) ParseBox(args.box, &grid_options);
  if (!std::isfinite(args.voxel_m) || !(args.voxel_m > 0.0)) {
    throw InputError("--voxel", "", std::to_string(args.voxel_m) + ": must be a positive size in metres");
  }
  grid_options.voxel_m = args.voxel_m;
  if (!(args.max_memory_mb > 0.0)) throw InputError("--max-memory-mb", "", "must be positive");
  grid_options.max_memory_bytes = static_cast<size_t>(args.max_memory_mb * 1e6);
  const std::string box_problem = grid_options.Problem();
  if (!box_problem.empty()) {
    throw InputError(box_problem.rfind("voxel", 0) == 0 ? "--voxel" : "--box", "", box_problem);
  }
  fusion::InserterOptions inserter_options;
  inserter_options.threads = args.threads;
  if (const std::string p = inserter_options.Problem(); !p.empty()) throw InputError("--threads", "", p);

  const fs::path dir = args.dir;
  FrameDirectorySource source(dir, InvalidDepthPolicy::kSkip);  // validates frames.json
  const CameraModel camera = source.camera();
  const size_t frame_count = source.manifest().frames.size();
  cv::Mat gt;
  if (!args.gt.empty()) gt = ReadDepthExr(args.gt);

  fusion::VotingGrid grid(grid_options);  // throws with the size needed when it does not fit
  if (!gt.empty() && (gt.rows != grid.ny() || gt.cols != grid.nx())) {
    throw InputError(args.gt, "size",
                     std::to_string(gt.cols) + " x " + std::to_string(gt.rows) + " cells, expected the grid's " +
                         std::to_string(grid.nx()) + " x " + std::to_string(grid.ny()) + " (same box and voxel)");
  }
  fusion::FrameInserter inserter(&grid, inserter_options);
  const fs::path out = args.out.empty() ? fs::path(dir.string() + "_fused") : fs::path(args.out);

  fusion::FusionReport report;
  report.input = dir.string();
  report.threads = args.threads;
  report.geometry = grid.geometry();
  report.max_x_m = grid_options.max_W.x();
  report.max_y_m = grid_options.max_W.y();
  report.max_z_m = grid_options.max_W.z();
  report.grid_mb = grid.memory_bytes() / 1e6;
  std::fprintf(stderr, "fuse: %s, grid %d x %d x %d at %.3g mm (%.1f MB), %d thread(s)\n",
               source.Describe().c_str(), grid.nx(), grid.ny(), grid.nz(), grid.voxel_m() * 1e3,
               report.grid_mb, args.threads);

  Frame frame;
  std::string error;
  const fs::path manifest = dir / "frames.json";
  for (size_t i = 0;; ++i) {
    const FrameStatus status = source.Next(&frame, &error);
    if (status == FrameStatus::kEndOfStream) break;
    const std::string field = "frames[" + std::to_string(i) + "]";
    if (status == FrameStatus::kBadFrame) throw InputError(manifest.string(), field, error);
    if (frame.depth_m.empty()) throw InputError(manifest.string(), field + ".depth", "missing: fuse needs depth");
    if (!frame.T_W_C) throw InputError(manifest.string(), field + ".T_W_C", "missing: fuse needs the camera pose");
    if (frame.depth_m.rows != camera.height || frame.depth_m.cols != camera.width) {
      throw InputError(manifest.string(), field + ".depth",
                       "is " + std::to_string(frame.depth_m.cols) + " x " + std::to_string(frame.depth_m.rows) +
                           ", the camera is " + std::to_string(camera.width) + " x " + std::to_string(camera.height));
    }
    const double t0 = NowMs();
    inserter.Insert(camera, frame.depth_m, *frame.T_W_C, &report.stats);
    report.insert_ms.push_back(NowMs() - t0);
    const double completeness = fusion::Completeness(fusion::ExtractHeightMap(grid));
    report.completeness_per_frame.push_back(completeness);
    ++report.frames;
    std::fprintf(stderr, "\rfuse: frame %zu/%zu, insert %.1f ms, completeness %.1f %%   ", i + 1, frame_count,
                 report.insert_ms.back(), 100.0 * completeness);
  }
  std::fprintf(stderr, "\n");

  const double t0 = NowMs();
  const cv::Mat height = fusion::ExtractHeightMap(grid);
  report.extract_ms = NowMs() - t0;
  report.completeness = fusion::Completeness(height);
  report.skipped_pixels = source.skipped_pixels();
  if (!gt.empty()) report.metrics = fusion::CompareHeightMaps(height, gt);
  report.peak_rss_mb = fusion::PeakRssMb();

  fs::create_directories(out);
  fusion::WriteHeightMapExr(out / "fused_depth.exr", height);
  fusion::WriteHeightMapPicture(out / "fused_depth.png", height, grid.geometry());
  fusion::WriteHeightMapPly(out / "fused_points.ply", height, grid.geometry());
  fusion::WriteCompletenessPlot(out / "completeness.png", report.completeness_per_frame);
  fusion::WriteFusionReport(out / "report.json", report);

  std::printf("fused %zu frames into %s: completeness %.1f %%", report.frames, out.string().c_str(),
              100.0 * report.completeness);
  if (report.metrics) {
    std::printf(", RMSE %.3f mm, MAE %.3f mm, within 1 mm %.1f %%", report.metrics->rmse_mm,
                report.metrics->mae_mm, 100.0 * report.metrics->within_1mm);
  }
  std::printf("\ninsert %.2f ms per frame (median), extract %.2f ms, peak memory %.0f MB; %zu pixels skipped "
              "(NaN/inf/negative)\n%s\n",
              fusion::Quantile(report.insert_ms, 0.5), report.extract_ms, report.peak_rss_mb, report.skipped_pixels,
              report.stats.BriefReport().c_str());
}

}  // namespace

void AddFuseCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand("fuse", "Fuse the depth maps of a frame directory into one height map");
  auto args = std::make_shared<FuseArguments>();
  cmd->add_option("DIR", args->dir, "Frame directory (frames.json with depth and T_W_C per frame)")->required();
  cmd->add_option("--out", args->out, "Output folder (default: DIR_fused beside the input)");
  cmd->add_option("--gt", args->gt, "Ground-truth height map (EXR, same box and voxel) for RMSE/MAE");
  cmd->add_option("--box", args->box,
                  "Fusion box in world metres: xmin,ymin,zmin,xmax,ymax,zmax (default "
                  "-0.075,-0.04,-0.004,0.075,0.04,0.06)");
  cmd->add_option("--voxel", args->voxel_m, "Voxel size in metres (default 0.00025)");
  cmd->add_option("--threads", args->threads, "Insertion threads (default 1)");
  cmd->add_option("--max-memory-mb", args->max_memory_mb, "Refuse grids larger than this (default 16384)");
  cmd->callback([args] { RunFuse(*args); });
}

}  // namespace romunect::tools
