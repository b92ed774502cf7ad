// The depth engine: a model of the PrimeSense chip (Konolige and Mihelich, "Technical
// description of Kinect calibration"; libfreenect). Frames: C, the camera; images are the
// chip's size (640 x 480); pixel centres at integer coordinates.
//
// RAW DEPTH (the one place it is documented; frames.h points here). The chip stores a reference
// image of its pattern on a plane at Z_ref, seen in its stock geometry (rig.h, ChipGeometry:
// focal length f px, baseline b m, projector at +b along x). For each pixel it finds the shift
// s (px) along the row at which its window matches the reference: the pixel at column x
// matches the reference at column x - s (s > 0: nearer than Z_ref). With D_ref = f b / Z_ref,
//   raw = round(raw_offset - 8 D_ref) - round(8 s)        (1/8 px steps; raw_offset = "doff")
// so raw = raw_offset - 8 f b / Z on the stock device, and the chip reports
//   Z_chip = 8 f b / (raw_offset - raw)   metres.
// raw is 11 bits, CV_16U; 2047 marks "no measurement" (reported depth 0). Raw increases with
// depth. On modified hardware (another f, b, the pattern through H_P_rec) the true depth obeys
// 1/Z = alpha + beta raw per pixel (exact for a pinhole camera with the projector centre on
// the camera's x axis), while Z_chip is off; DepthCorrection turns either into metres.
//
// Matching: both images are prefiltered (local mean removed, divided by the local standard
// deviation, 8 bits), each window_px x window_px window's sum of absolute differences against
// the reference is computed for every integer shift in [min_shift, min_shift + range), the
// best is refined to 1/8 px (parabola through the neighbouring costs; the rig's disparity
// distortion, disparity_distortion.h, is added before the rounding), and the pixel is
// invalid when the window is flat (raw standard deviation < min_texture DN), the match weak
// (mean difference > max_cost), ambiguous (another shift > 1 px away within `uniqueness` of the
// best), at the end of the search range, or the raw value leaves 11 bits. At the image's sides
// the window is clipped to the image's columns (the weak test to its area); at the top and
// bottom both images' rows are reflected alike; the chip's right-hand kChipBorderColumns columns
// report nothing, as a PS1080's do. Edge fattening, shadows and quantization come out of this
// process. The fast path keeps the search range in
// signed 16-bit SIMD lanes and slides the window with running column and row sums (the cost per
// pixel does not depend on the window size); flat pixels skip the search. It runs on `threads`
// threads over row bands, on the widest instruction set the CPU has (Isa, cpu_features.h; the
// engine implements scalar, SSE2, AVX2 and AVX-512); results are the same bytes at any thread
// count and on every instruction set.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/rig.h"

namespace romunect {

inline constexpr uint16_t kRawInvalid = 2047;
// The chip reports no depth in its right-hand columns (8 on a PS1080 at 640 x 480).
inline constexpr int kChipBorderColumns = 8;

struct DepthEngineStats {
  int valid = 0;
  int flat = 0;          // texture too low (dark, saturated or unlit)
  int weak = 0;          // best cost too high
  int ambiguous = 0;     // second best too close
  int out_of_range = 0;  // best at the end of the search range, or raw outside 11 bits
  int border = 0;        // the chip's right-hand columns (kChipBorderColumns)
  double seconds = 0.0;  // wall time of Compute
  // CPU time of the busiest thread (prefilter and search): at `threads` = 1 the frame's CPU time.
  double busiest_thread_cpu_s = 0.0;
  std::string BriefReport() const;
};

struct DepthEngineOutput {
  cv::Mat raw;       // CV_16U, 11-bit raw depth, kRawInvalid where no match
  cv::Mat depth_m;   // CV_32F, the chip's reported depth (metres), 0 where invalid
  cv::Mat shift_px;  // CV_32F, the matched shift s in 1/8 px, NaN where invalid
  DepthEngineStats stats;
};

// The reference image the chip stores: the pattern on a white plane at reference_distance_m in
// the stock geometry, without noise (CV_16U, 10 bits). It is wider than the camera's image by
// the search's shifts (ReferenceMarginsPx), so that every shift of every pixel has a reference
// column, as on the real chip: no band of the image is lost near or far.
cv::Mat ChipReferenceImage(const DepthEngineOptions& options);
// Columns of the reference left of the camera's column 0 (the largest shift) and right of its
// last column (minus the smallest shift), each at least 0.
std::pair<int, int> ReferenceMarginsPx(const DepthEngineOptions& options);

class DepthEngine {
 public:
  // Renders the chip's reference image once (ChipReferenceImage).
  explicit DepthEngine(const DepthEngineOptions& options);
  // Uses a given reference image (CV_16U): ChipReferenceImage's size, or the camera's (a
  // reference cropped to the image: shifts that leave it count as mismatches).
  DepthEngine(const DepthEngineOptions& options, const cv::Mat& reference_ir);

  // One frame: ir is CV_16U of the chip camera's size. A wrong size or type is bad input from
  // outside and throws InputError("depth engine", "ir", ...); nothing else throws.
  void Compute(const cv::Mat& ir, DepthEngineOutput* out);

  const DepthEngineOptions& options() const { return options_; }
  // The instruction set of the search Compute runs: ResolveIsa() of the one set (kAuto unless
  // set). set_isa needs kAuto or one the engine implements and the CPU supports; every one gives
  // the same bytes (tests/sensor compare them).
  Isa isa() const { return isa_; }
  void set_isa(Isa isa);
  const cv::Mat& reference_ir() const { return reference_ir_; }
  // The raw value of shift s = 0 (the reference plane), unrounded: raw_offset - 8 f b / Z_ref.
  double RawAtReference() const;
  // Chip depth of a raw value (0 for kRawInvalid or raw >= raw_offset).
  double ChipDepthM(int raw) const;
  // Shift (px) of a raw value: inverse of the raw formula.
  double ShiftOfRaw(int raw) const;

  // The prefilter, public for the tests: from ir (CV_16U), the CV_8U normalized image and the
  // raw local standard deviation (CV_32F, DN) used for the flat test, in exact integer box sums
  // (the bytes of cv::boxFilter on float images, tested).
  static void Prefilter(const cv::Mat& ir, int window_px, cv::Mat* normalized, cv::Mat* local_sigma);

 private:
  DepthEngineOptions options_;
  Isa isa_;  // resolved
  cv::Mat reference_ir_;
  cv::Mat frame_norm_, frame_sigma_;
  int raw_at_reference_rounded_ = 0;
  std::vector<float> chip_depth_lut_;  // ChipDepthM per raw value
  // Tables of the search (depth_engine_kernel.h): the prefiltered reference rows reversed and
  // padded (rows x reference_row_length_), where each padded index has no reference column, and
  // the columns that always have one; the search range padded to 32 lanes.
  int search_lanes_ = 0;
  int reference_row_length_ = 0;
  std::vector<uint8_t> reference_reversed_, reference_outside_;
  int clean_begin_ = 0, clean_end_ = 0;
  std::vector<int16_t> ambiguous_below_;  // per best window cost that is not weak
  std::vector<int> max_best_cost_of_columns_;  // the weak test of a window clipped to n columns
  DisparityDistortionMaps distortion_beta_;  // the disparity distortion's maps; empty: none
};

// Per-pixel conversion of the chip's output to metric depth (paper eqs. 2-3). The one
// representation: the calibration fits a and b (calib/depth_correction.h), its file stores them
// (calib/calibration_file.h), and the pipeline applies them here.
enum class DepthCorrectionModel {
  kAffineInChipDepth,   // Z = a * Z_chip + b  (the paper's correction)
  kInverseAffineInRaw,  // 1/Z = a * raw + b   (exact for a pinhole camera)
};
const char* DepthCorrectionModelName(DepthCorrectionModel model);  // "affine_in_chip_depth", ...

struct DepthCorrection {
  DepthCorrectionModel model = DepthCorrectionModel::kInverseAffineInRaw;
  cv::Mat a, b;  // CV_64F, camera size; NaN where the pixel has no correction
};

// The chip's reported depth of a raw value, Z_chip = 8 f b / (raw_offset - raw) metres; 0 for
// kRawInvalid or raw >= raw_offset (at or beyond infinity).
double ChipDepthM(const ChipGeometry& chip, double raw);

// One pixel: metres, 0 where raw is invalid, the pixel uncorrected (NaN), the chip depth (read
// by kAffineInChipDepth only) not positive, or the result not positive.
double ApplyDepthCorrectionPixel(const DepthCorrection& correction, int row, int col, uint16_t raw,
                                 double chip_depth_m);

// Metric depth (CV_32F, metres, 0 where invalid or uncorrected) from the engine's output.
cv::Mat ApplyDepthCorrection(const DepthCorrection& correction, const DepthEngineOutput& output);
// The same from raw alone (CV_16U; recorded frames), the chip depth from the chip geometry.
cv::Mat ApplyDepthCorrection(const DepthCorrection& correction, const cv::Mat& raw, const ChipGeometry& chip);

struct DepthFitOptions {
  int min_samples = 2;              // per pixel, else NaN
  double min_depth_spread_m = 0.0;  // per pixel, max - min truth depth, else NaN (a blind fit)
};

// The per-pixel least-squares fit of a and b from raw images (CV_16U), the chip's depth of them
// (CV_32F metres; a sample needs it positive) and ground-truth depth (CV_32F metres, 0 = none).
// kInverseAffineInRaw weighs each sample by Z^4 so that it minimizes depth error, not 1/Z
// error. Pixels with too few samples, too little spread or one distinct value get NaN.
DepthCorrection FitDepthCorrection(DepthCorrectionModel model, const std::vector<cv::Mat>& raw,
                                   const std::vector<cv::Mat>& chip_depth_m, const std::vector<cv::Mat>& truth_depth_m,
                                   const DepthFitOptions& options);
// The same from the engine's outputs.
DepthCorrection FitDepthCorrection(DepthCorrectionModel model, const std::vector<DepthEngineOutput>& outputs,
                                   const std::vector<cv::Mat>& truth_depth_m, int min_samples = 2);

}  // namespace romunect
