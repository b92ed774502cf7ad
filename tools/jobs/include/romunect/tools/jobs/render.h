// `romunect render OUT_DIR`: renders a rig (preset or JSON file) looking at a built-in target or
// a mesh file with the Embree renderer, synthesizes the IR image, runs the depth engine, and
// writes a frame directory (IR, raw, metric depth, ground-truth depth) plus pictures.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

namespace romunect::jobs {

struct RenderJobOptions {
  std::string out_dir;
  std::string rig = "romunect";  // preset name or JSON file
  std::string target = "plane";
  std::string mesh;  // a mesh file instead of a target (vertices in C, metres)
  double mesh_unit_m = 1.0;
  double distance_m = 0.0;    // 0: the camera's focus distance
  double size_m = 0.0;        // 0: 1.5 x the view's width at the distance
  std::string samples = "1";  // 1, 4 (thin lens at every pixel) or adaptive (4 at edges only)
  int threads = 2;
  uint64_t seed = 1;
  double albedo = 0.6;
};

// Measured minus true depth where both exist: median, RMS, 95th percentile of |error| (m).
struct DepthErrors {
  double median = 0.0, rms = 0.0, p95 = 0.0;
  size_t pixels = 0;
};

struct RenderSummary {
  std::filesystem::path out_dir, pictures;
  std::string rig_name, what;  // the target's name or the mesh file
  int width = 0, height = 0;
  double distance_m = 0.0;
  size_t triangles = 0;
  std::string render_stats, synthesis_stats, depth_stats;  // their BriefReport()s
  double valid_fraction = 0.0;
  double lo_m = 0.0, hi_m = 0.0, gt_lo_m = 0.0, gt_hi_m = 0.0;  // reported and true depth ranges
  bool stock = false;  // the rig is the stock device: the chip's depth is metric
  DepthErrors metric, chip;
  double error_scale_m = 0.0;  // error.png's full colour (ErrorPictureScaleM)
  double code_step_m = 0.0;    // one raw code's depth step at the median true depth
};

// error.png's full-colour error: the 95th percentile of |error| (outliers at edges do not wash
// it out), but never below one raw code's depth step at the median true depth, Z^2 / (8 f b) for
// the rig's camera focal length f (px) and baseline b (m): a frame whose pixels mostly hit the
// exact code has a 95th percentile of 0 and would saturate on its first miss.
double ErrorPictureScaleM(double p95_abs_error_m, double median_true_depth_m, double focal_px, double baseline_m);

// Validates the options (InputError naming the option), renders and writes the frame directory
// (refusing one that holds frames.json before anything is rendered) and its pictures.
RenderSummary Render(const RenderJobOptions& options);

// The lines for the terminal: the stats of each stage, the depth ranges and errors.
std::string RenderSummaryText(const RenderSummary& summary);

}  // namespace romunect::jobs
