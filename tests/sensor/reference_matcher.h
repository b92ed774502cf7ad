// The slow, obvious block matcher: the depth engine's rules (depth_engine.h) by full search,
// one pixel at a time, no cost slabs, no shortcuts. The oracle for DepthEngine's fast path.
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

#include "romunect/sensor/depth_engine.h"

namespace romunect::testing {

// The prefilter spelled out with cv::boxFilter on float images (the oracle for
// DepthEngine::Prefilter's exact integer box sums): CV_8U normalized image, CV_32F sigma (DN).
void ReferencePrefilter(const cv::Mat& ir, int window_px, cv::Mat* normalized, cv::Mat* local_sigma);

// Raw value (11 bits, kRawInvalid when rejected) of pixel (x, y) of `ir` against the engine's
// reference image and options.
uint16_t ReferenceMatchRaw(const DepthEngine& engine, const cv::Mat& ir_normalized, const cv::Mat& ir_sigma,
                           const cv::Mat& reference_normalized, int x, int y);

}  // namespace romunect::testing
