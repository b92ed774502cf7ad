// Projector images (rig.h, PatternSpec): the Kinect-like pseudo-random dot pattern, intensity
// modulated dot grids, calibration patterns (feature-point grid, checkerboard), uniform light,
// off; and the pre-warp H_P_rec that maps pattern pixels to projector pixels before projection.
// Images are CV_32F in [0, 1]; pixel centres at integer coordinates (OpenCV).
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/rig.h"

namespace romunect {

// The pattern image of a spec (spec.height x spec.width). The same spec gives the same bytes.
// Kinect dots: one seeded sub-pattern of width/3 x height/3 with a share dot_fill of lit
// pixels (dot_level), tiled 3 x 3 as on the real device, each tile with a brighter 2 x 2 centre
// spot (centre_spot_level).
cv::Mat MakePattern(const PatternSpec& spec);

// The image the projector displays: pattern warped by H_P_rec (x_P ~ H_P_rec x_pattern) to the
// projector's resolution, bilinear, black outside the pattern. H_P_rec = I copies exactly.
cv::Mat PrewarpPattern(const cv::Mat& pattern, const Eigen::Matrix3d& H_P_rec, const ProjectorModel& projector);

// MakePattern then PrewarpPattern for a rig.
cv::Mat ProjectorImage(const Rig& rig);

// The feature points of a kFeatureGrid pattern, or the inner corners of a kCheckerboard, in
// pattern pixels, row by row: what calibration detects in the camera image.
std::vector<Eigen::Vector2d> PatternFeaturePoints(const PatternSpec& spec);

// A deterministic 64-bit hash (splitmix64) of a seed and a counter: the one source of
// randomness of the sensor model, so results do not depend on the standard library.
uint64_t HashCounter(uint64_t seed, uint64_t counter);
// Uniform in [0, 1) from HashCounter.
double UniformFromHash(uint64_t seed, uint64_t counter);

}  // namespace romunect
