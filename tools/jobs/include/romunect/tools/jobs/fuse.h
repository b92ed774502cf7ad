// `romunect fuse SOURCE`: fuses the depth maps of a frame directory, an .oni recording or a live
// OpenNI2 device (sources as OpenSource reads them; the last two with a pose log and a
// calibration for the camera poses and, when it has one, the depth model applied to the chip's
// raw shifts) into one height map (fusion/) and writes fused_depth.exr, fused_depth.png,
// fused_points.ply, completeness.png and report.json. A device that stops mid-scan ends the
// run after the outputs of the frames fused so far are written (FuseJobSummary::stopped).
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "romunect/fusion/outputs.h"

namespace romunect::jobs {

struct FuseOptions {
  std::string source, out, gt, box;  // out "": beside the source (SOURCE_fused)
  bool box_given = false;            // --box "" is a bad box, not the default
  double voxel_m = 0.25e-3;
  int threads = 1;
  double max_memory_mb = 16384.0;
  // OpenNI2 sources (.oni files, devices) only.
  std::string poses, calibration, camera;
  double pose_offset_s = 0.0;
  double timeout_s = 2.0;
  bool device_depth = false;  // fuse the device's metric depth even with a depth model
  bool pose_offset_given = false, timeout_given = false;
  std::string perturb;  // injected calibration errors (perturbation.h); "" none
};

struct FuseJobSummary {
  std::filesystem::path out;
  fusion::FusionReport report;
  std::string depth_from, box_from;
  std::string perturbation = "none";             // the injected calibration errors (perturbation.h)
  int dropped_frames = 0;                         // gaps in a device's frame numbers
  std::optional<std::string> depth_unit_warning;  // an OpenNI2 source's depth unit is coarse for the voxel
  std::optional<std::string> stopped;             // why the source stopped before its end
};

// Validates the options (InputError naming the option, file or field, before any file is read),
// fuses and writes the outputs. Nothing is written when no frame fused, no depth was valid or no
// ray reached the box. Progress and warnings go to stderr.
FuseJobSummary RunFuse(const FuseOptions& options);

// The lines for the terminal: frames, completeness, errors against ground truth, timings.
std::string FuseSummaryText(const FuseJobSummary& summary);

// The warning for an OpenNI2 source whose depth unit (the wire's step, 1e-3 or 1e-4 m) is coarser than half the
// voxel: depths arrive rounded to it, so cells a finer voxel would tell apart merge (a 1 mm
// recording at 0.25 mm voxels). nullopt when the unit is fine enough.
std::optional<std::string> DepthUnitWarning(double depth_unit_m, double voxel_m);

// Throws InputError when the source stopped early (after the outputs were written).
void CheckSourceEnded(const FuseJobSummary& summary, const FuseOptions& options);

}  // namespace romunect::jobs
