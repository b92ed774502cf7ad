// Camera intrinsics by Zhang's method from views of a checkerboard (paper, section 3.2, [9]):
// detection on real images, OpenCV's calibrateCamera, error estimates (RMS, per view, held
// out), a coverage measure and a planner that proposes views covering the image and the tilts.
// Frames: K board (board.h), C camera (OpenCV axes). Pixels: centres at integer coordinates.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/calib/board.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib {

// Finds the board's inner corners in an 8-bit or 16-bit grey (or BGR) image and refines them
// to sub-pixel precision. nullopt (with *reason) when the board is not found completely. With
// cols + rows odd (9x6) the order starts at the end whose outer corner square is dark, in every
// view, so that K is the same board frame in all (board.h).
std::optional<std::vector<cv::Point2f>> DetectBoard(const cv::Mat& image, const BoardSpec& board, std::string* reason);

struct DetectedViews {
  cv::Size image_size;
  std::vector<BoardView> views;                               // views where the board was found
  std::vector<std::pair<std::string, std::string>> rejected;  // (file, reason)
};

// The image files of `dir` (png, jpg, jpeg, bmp, tif, tiff), in name order. Throws InputError
// if the folder is missing or holds no images.
std::vector<std::filesystem::path> ListBoardImages(const std::filesystem::path& dir);

// Detects the board in every image file of `dir` (png, jpg, jpeg, bmp, tif, tiff), in name
// order. Throws InputError if the folder is missing or holds no images, or if image sizes
// differ. Images where detection fails are listed in `rejected`, not fatal.
DetectedViews DetectBoardInFolder(const std::filesystem::path& dir, const BoardSpec& board);

// Which parameters calibrateCamera estimates.
enum class DistortionModel {
  kK1K2P1P2,    // k3 fixed at 0: the default, stable with few or weakly tilted views
  kK1K2P1P2K3,  // all five
};

struct IntrinsicsOptions {
  DistortionModel model = DistortionModel::kK1K2P1P2;
  int min_views = 4;         // fewer usable views: error (Zhang needs >= 3; 4 leaves a check)
  int holdout_folds = 5;     // k-fold held-out error; 0 = skip (faster)
  int coverage_cells_x = 8;  // coverage grid over the image
  int coverage_cells_y = 6;
  std::string Problem() const;  // "" when valid
};

// How well a set of views covers the image and the tilts (coverage, not the RMS, decides the
// error away from the image centre).
struct Coverage {
  double cell_fraction = 0.0;      // fraction of coverage cells holding at least one corner
  double tilt_x_spread_rad = 0.0;  // max - min board tilt about the camera x axis
  double tilt_y_spread_rad = 0.0;  // max - min board tilt about the camera y axis
  double max_tilt_rad = 0.0;       // largest angle between board normal and optical axis
};

struct IntrinsicsResult {
  CameraModel camera;
  double rms_px = 0.0;                  // reprojection RMS over all corners (calibrateCamera)
  std::vector<double> per_view_rms_px;  // one per view, same order as the input
  std::vector<Pose> T_C_K;              // board pose per view
  double holdout_rms_px = -1.0;         // k-fold: RMS on views left out of the fit; -1 = skipped
  Coverage coverage;
  std::string BriefReport() const;
};

// Calibrates from board views of one camera with image size `image_size`. Throws InputError
// (source "intrinsics") with too few views, or views with a wrong corner count.
IntrinsicsResult CalibrateIntrinsics(const std::vector<BoardView>& views, const BoardSpec& board, cv::Size image_size,
                                     const IntrinsicsOptions& options = {});

// Coverage of views given their corners and board poses T_C_K.
Coverage MeasureCoverage(const std::vector<BoardView>& views, const std::vector<Pose>& T_C_K, cv::Size image_size,
                         int cells_x, int cells_y);

// The full-image mapping error between an estimated and a true camera: for pixels on a grid
// of step `step_px` over the whole image, the distance between the pixel and where the
// estimate projects the true camera's ray through it. RMS and max, in pixels. With
// compensate_rotation, the rays are first aligned by the best rotation (Kabsch): a rotation
// of the camera frame is absorbed by the extrinsics (as in Hagemann et al. 2021, "Inferring
// bias and uncertainty in camera calibration"), so only the part that bends rays counts.
struct MappingError {
  double rms_px = 0.0;
  double max_px = 0.0;
};
MappingError FullImageMappingError(const CameraModel& estimate, const CameraModel& truth, int step_px = 8,
                                   bool compensate_rotation = true);

struct ViewPlanOptions {
  int view_count = 20;
  double distance_m = 0.25;   // camera to board centre along the optical axis
  double max_tilt_rad = 0.8;  // tilts of the board about camera x and y, up to this (tilt
                              // spread pins the focal length down)
  double margin_px = 10.0;    // every corner this far inside the image
  unsigned seed = 1;          // jitter of the targets and tilts
  std::string Problem() const;
};

// Proposes camera poses relative to the board, T_K_C, so that the views together cover the
// whole image (the board centre visits a grid of image positions, corners included) and a
// spread of tilts about both axes. Every proposed view keeps all corners on the image.
// Throws InputError (source "view planner") when the board cannot fit the image at that
// distance.
std::vector<Pose> PlanViews(const CameraModel& camera, const BoardSpec& board, const ViewPlanOptions& options = {});

}  // namespace romunect::calib
