#include "romunect/sensor/pattern.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"

namespace romunect {

uint64_t HashCounter(uint64_t seed, uint64_t counter) {
  uint64_t z = seed * 0x9E3779B97F4A7C15ULL + counter + 0x632BE59BD9B4E019ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  z = z ^ (z >> 31);
  // A second round decorrelates neighbouring counters of nearby seeds.
  z += 0x9E3779B97F4A7C15ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

double UniformFromHash(uint64_t seed, uint64_t counter) {
  return static_cast<double>(HashCounter(seed, counter) >> 11) * (1.0 / 9007199254740992.0);
}

cv::Mat MakePattern(const PatternSpec& spec) {
  ROMUNECT_CHECK_MSG(spec.Problem().empty(), spec.Problem().c_str());
  cv::Mat out(spec.height, spec.width, CV_32F, cv::Scalar(0));
  switch (spec.kind) {
    case PatternKind::kKinectDots: {
      const int tw = spec.width / 3, th = spec.height / 3;
      cv::Mat tile(th, tw, CV_32F, cv::Scalar(0));
      for (int y = 0; y < th; ++y) {
        for (int x = 0; x < tw; ++x) {
          if (UniformFromHash(spec.seed, static_cast<uint64_t>(y) * tw + x) < spec.dot_fill) {
            tile.at<float>(y, x) = static_cast<float>(spec.dot_level);
          }
        }
      }
      // The registration spot of each tile: brighter and larger than the ordinary dots.
      for (int y = th / 2 - 1; y <= th / 2; ++y) {
        for (int x = tw / 2 - 1; x <= tw / 2; ++x) tile.at<float>(y, x) = static_cast<float>(spec.centre_spot_level);
      }
      for (int ty = 0; ty < 3; ++ty) {
        for (int tx = 0; tx < 3; ++tx) tile.copyTo(out(cv::Rect(tx * tw, ty * th, tw, th)));
      }
      break;
    }
    case PatternKind::kDotGrid: {
      const int p = spec.pitch_px;
      uint64_t k = 0;
      for (int y = p / 2; y < spec.height; y += p) {
        for (int x = p / 2; x < spec.width; x += p) {
          const double level = spec.min_level + (1.0 - spec.min_level) * UniformFromHash(spec.seed, k++);
          out.at<float>(y, x) = static_cast<float>(level);
        }
      }
      break;
    }
    case PatternKind::kFeatureGrid: {
      const double radius = spec.pitch_px / 6.0;
      for (const Eigen::Vector2d& c : PatternFeaturePoints(spec)) {
        for (int y = static_cast<int>(c.y() - radius - 1); y <= c.y() + radius + 1; ++y) {
          for (int x = static_cast<int>(c.x() - radius - 1); x <= c.x() + radius + 1; ++x) {
            if (x < 0 || y < 0 || x >= spec.width || y >= spec.height) continue;
            if ((Eigen::Vector2d(x, y) - c).norm() <= radius) out.at<float>(y, x) = 1.0f;
          }
        }
      }
      break;
    }
    case PatternKind::kCheckerboard:
      for (int y = 0; y < spec.height; ++y) {
        for (int x = 0; x < spec.width; ++x) {
          out.at<float>(y, x) = ((x / spec.pitch_px + y / spec.pitch_px) % 2 == 0) ? 1.0f : 0.0f;
        }
      }
      break;
    case PatternKind::kUniform: out.setTo(1.0f); break;
    case PatternKind::kOff: break;
  }
  return out;
}

cv::Mat PrewarpPattern(const cv::Mat& pattern, const Eigen::Matrix3d& H_P_rec, const ProjectorModel& projector) {
  ROMUNECT_CHECK(pattern.type() == CV_32F);
  if (H_P_rec.isIdentity(0.0) && pattern.cols == projector.width && pattern.rows == projector.height) {
    return pattern.clone();
  }
  cv::Matx33d H;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) H(r, c) = H_P_rec(r, c);
  }
  cv::Mat out;
  cv::warpPerspective(pattern, out, cv::Mat(H), cv::Size(projector.width, projector.height), cv::INTER_LINEAR,
                      cv::BORDER_CONSTANT, cv::Scalar(0));
  return out;
}

cv::Mat ProjectorImage(const Rig& rig) { return PrewarpPattern(MakePattern(rig.pattern), rig.H_P_rec, rig.projector); }

std::vector<Eigen::Vector2d> PatternFeaturePoints(const PatternSpec& spec) {
  std::vector<Eigen::Vector2d> points;
  const int p = spec.pitch_px;
  if (spec.kind == PatternKind::kFeatureGrid) {
    for (int y = p; y + p / 2 <= spec.height - 1; y += p) {
      for (int x = p; x + p / 2 <= spec.width - 1; x += p) points.emplace_back(x, y);
    }
  } else if (spec.kind == PatternKind::kCheckerboard) {
    // Inner corners lie between pixels p-1 and p: at p - 0.5 in pixel-centre coordinates.
    for (int y = p; y < spec.height; y += p) {
      for (int x = p; x < spec.width; x += p) points.emplace_back(x - 0.5, y - 0.5);
    }
  }
  return points;
}

}  // namespace romunect
