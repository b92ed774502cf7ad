#include "romunect/calib/calibration_file.h"

#include <chrono>
#include <cmath>
#include <ctime>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/core/persistence.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/input_limits.h"

namespace romunect::calib {
namespace fs = std::filesystem;
namespace {

std::string NowUtc() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

cv::Mat PoseToMat(const Pose& T) {
  cv::Mat m(4, 4, CV_64F);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) m.at<double>(r, c) = T.matrix()(r, c);
  }
  return m;
}

cv::Mat ReadMat(const cv::FileNode& root, const std::string& key, int rows, int cols, const std::string& source) {
  const cv::FileNode node = root[key];
  if (node.empty()) throw InputError(source, key, "missing");
  CheckMatrixNode(node, rows, cols, source, key);
  cv::Mat m;
  try {
    node >> m;
  } catch (const cv::Exception&) {
    throw InputError(source, key, "not an OpenCV matrix (opencv-matrix with rows, cols, dt, data)");
  }
  if (m.rows != rows || m.cols != cols || m.channels() != 1) {
    throw InputError(source, key,
                     "must be a " + std::to_string(rows) + "x" + std::to_string(cols) + " matrix; got " +
                         std::to_string(m.rows) + "x" + std::to_string(m.cols));
  }
  m.convertTo(m, CV_64F);
  if (!cv::checkRange(m)) throw InputError(source, key, "holds a non-finite value");
  return m;
}

Pose ReadPose(const cv::FileNode& root, const std::string& key, const std::string& source) {
  const cv::Mat m = ReadMat(root, key, 4, 4, source);
  Eigen::Matrix4d e;
  std::array<double, 16> row_major;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) e(r, c) = row_major[r * 4 + c] = m.at<double>(r, c);
  }
  if (const std::string p = RigidityProblem(e, 1e-6); !p.empty()) throw InputError(source, key, p);
  return PoseFromRowMajor(row_major);
}

double ReadReal(const cv::FileNode& root, const std::string& key, const std::string& source, const std::string& path) {
  const cv::FileNode node = root[key];
  if (node.empty()) throw InputError(source, path, "missing");
  if (!node.isReal() && !node.isInt()) throw InputError(source, path, "must be a number");
  const double v = static_cast<double>(node);
  if (!std::isfinite(v)) throw InputError(source, path, "must be finite");
  return v;
}

std::string ReadString(const cv::FileNode& root, const std::string& key, const std::string& source,
                       const std::string& path) {
  const cv::FileNode node = root[key];
  if (node.empty()) throw InputError(source, path, "missing");
  if (!node.isString()) throw InputError(source, path, "must be a string");
  return static_cast<std::string>(node);
}

cv::Mat ReadMap(const cv::FileNode& depth, const std::string& name, const fs::path& file, const CameraModel& camera) {
  const std::string source = file.string();
  const std::string field = "depth_model." + name;
  cv::Mat map;
  if (!depth[name + "_exr"].empty()) {
    const fs::path exr = file.parent_path() / ReadString(depth, name + "_exr", source, field + "_exr");
    try {
      map = ReadDepthExr(exr, cv::Size(camera.width, camera.height));
    } catch (const InputError& e) {
      throw InputError(source, field + "_exr", e.what());
    }
  } else {
    const cv::FileNode node = depth[name];
    if (node.empty()) throw InputError(source, field, "missing (neither " + name + " nor " + name + "_exr)");
    // OpenCV allocates rows x cols before it reads the data: check the size it will take first.
    const cv::FileNode rows = node["rows"], cols = node["cols"];
    if (!rows.isInt() || !cols.isInt() || static_cast<int>(rows) != camera.height ||
        static_cast<int>(cols) != camera.width) {
      throw InputError(source, field,
                       "must be an OpenCV matrix of the image size " + std::to_string(camera.width) + "x" +
                           std::to_string(camera.height) + " (rows and cols)");
    }
    try {
      node >> map;
    } catch (const cv::Exception&) {
      throw InputError(source, field, "not an OpenCV matrix");
    }
  }
  if (map.type() != CV_32FC1 || map.cols != camera.width || map.rows != camera.height) {
    throw InputError(source, field,
                     "must be a float map of the image size " + std::to_string(camera.width) + "x" +
                         std::to_string(camera.height) + "; got " + std::to_string(map.cols) + "x" +
                         std::to_string(map.rows) + " " + cv::typeToString(map.type()));
  }
  for (int r = 0; r < map.rows; ++r) {
    for (int c = 0; c < map.cols; ++c) {
      if (std::isinf(map.at<float>(r, c))) {
        throw InputError(source, field,
                         "infinite at pixel (" + std::to_string(c) + ", " + std::to_string(r) +
                             "); NaN marks an unfitted pixel");
      }
    }
  }
  return map;
}

// Residual fields by name, for WorseThan and the file.
struct ResidualField {
  const char* name;
  double CalibrationResiduals::*member;
};
constexpr ResidualField kResidualFields[] = {
    {"intrinsics_rms_px", &CalibrationResiduals::intrinsics_rms_px},
    {"intrinsics_holdout_rms_px", &CalibrationResiduals::intrinsics_holdout_rms_px},
    {"hand_eye_rms_px", &CalibrationResiduals::hand_eye_rms_px},
    {"homography_rms_px", &CalibrationResiduals::homography_rms_px},
    {"depth_rms_m", &CalibrationResiduals::depth_rms_m},
};

// Opens a calibration file and checks its format and version.
cv::FileStorage OpenCalibrationFile(const fs::path& path) {
  const std::string source = path.string();
  cv::FileStorage fs = OpenFileStorage(path, "calibration file");
  const cv::FileNode root = fs.root();
  if (ReadString(root, "format", source, "format") != kCalibrationFormat) {
    throw InputError(source, "format", std::string("must be \"") + kCalibrationFormat + "\"");
  }
  // Exactly the version: 1.9 is not 1, and a cast of 1e300 to int would be undefined.
  if (ReadReal(root, "version", source, "version") != static_cast<double>(kCalibrationVersion)) {
    throw InputError(source, "version", "must be " + std::to_string(kCalibrationVersion));
  }
  return fs;
}

}  // namespace

std::string WorseThan(const Calibration& candidate, const Calibration& existing) {
  std::string worse;
  for (const ResidualField& f : kResidualFields) {
    const double mine = candidate.residuals.*(f.member), theirs = existing.residuals.*(f.member);
    if (theirs < 0.0) continue;  // the existing file lacks this step
    if (mine < 0.0) {
      worse += std::string(worse.empty() ? "" : "; ") + f.name + " missing (existing " + std::to_string(theirs) + ")";
    } else if (mine > 1.01 * theirs) {
      worse += std::string(worse.empty() ? "" : "; ") + f.name + " " + std::to_string(mine) + " > existing " +
               std::to_string(theirs);
    }
  }
  return worse;
}

SaveReport SaveCalibration(const fs::path& path, Calibration calibration, const SaveOptions& options) {
  SaveReport report;
  if (fs::exists(path)) {
    report.replaced_existing = true;
    std::string worse;
    try {
      worse = WorseThan(calibration, LoadCalibration(path));
    } catch (const InputError& e) {
      worse = std::string("the existing file does not load (") + e.what() + ")";
    }
    if (!worse.empty() && !options.overwrite_worse) {
      throw InputError(path.string(), "",
                       "exists and the new calibration is worse (" + worse +
                           "); not overwritten: write elsewhere or pass the explicit overwrite flag");
    }
    report.worse_than_existing = worse;
  }
  if (calibration.date.empty()) calibration.date = NowUtc();
  const Calibration& c = calibration;
  const bool has_maps = c.depth.has_value();
  cv::Mat a32, b32;  // the file's maps are CV_32F
  if (has_maps) {
    ROMUNECT_CHECK(c.depth->a.size() == c.depth->b.size() && !c.depth->a.empty());
    c.depth->a.convertTo(a32, CV_32F);
    c.depth->b.convertTo(b32, CV_32F);
  }
  const std::string stem = path.stem().string();
  if (has_maps && options.maps_as_exr) {
    WriteDepthExr(path.parent_path() / (stem + "_depth_a.exr"), a32);
    WriteDepthExr(path.parent_path() / (stem + "_depth_b.exr"), b32);
  }
  WriteAtomically(path, [&](const fs::path& tmp) {
    // FileStorage picks the format from the name: keep ".yaml" on the temporary.
    const fs::path tmp_yaml = tmp.string() + ".yaml";
    {
      cv::FileStorage fs(tmp_yaml.string(), cv::FileStorage::WRITE);
      if (!fs.isOpened()) throw InputError(path.string(), "", "cannot be written");
      fs << "format" << kCalibrationFormat;
      fs << "version" << kCalibrationVersion;
      fs << "date" << c.date;
      c.camera.Write(fs);
      cv::Mat H(3, 3, CV_64F);
      for (int r = 0; r < 3; ++r) {
        for (int col = 0; col < 3; ++col) H.at<double>(r, col) = c.H_P_rec(r, col);
      }
      fs.writeComment("Projector pre-warp homography (paper eq. 1), projector pixels.");
      fs << "H_P_rec" << H;
      fs.writeComment("Camera in hand and board in base: 4x4, metres, p_H = T_H_C * p_C.");
      fs << "T_H_C" << PoseToMat(c.T_H_C);
      fs << "T_B_K" << PoseToMat(c.T_B_K);
      fs << "depth_model"
         << "{";
      fs << "kind" << (has_maps ? DepthCorrectionModelName(c.depth->model) : "none");
      fs << "chip_focal_px" << c.chip.camera.fx;
      fs << "chip_baseline_m" << c.chip.baseline_m;
      fs << "chip_raw_offset" << c.chip.raw_offset;
      if (has_maps) {
        if (options.maps_as_exr) {
          fs << "a_exr" << stem + "_depth_a.exr";
          fs << "b_exr" << stem + "_depth_b.exr";
        } else {
          fs << "a" << a32;
          fs << "b" << b32;
        }
      }
      fs << "}";
      fs << "residuals"
         << "{";
      for (const ResidualField& f : kResidualFields) fs << f.name << c.residuals.*(f.member);
      fs << "}";
    }
    fs::rename(tmp_yaml, tmp);
  });
  return report;
}

namespace {

// Every field of an opened calibration file's root (LoadCalibration).
Calibration ReadWholeCalibration(const cv::FileNode& root, const fs::path& path) {
  const std::string source = path.string();
  Calibration c;
  c.date = ReadString(root, "date", source, "date");
  c.camera = CameraModel::Read(root, source);
  const cv::Mat H = ReadMat(root, "H_P_rec", 3, 3, source);
  for (int r = 0; r < 3; ++r) {
    for (int col = 0; col < 3; ++col) c.H_P_rec(r, col) = H.at<double>(r, col);
  }
  if (std::abs(c.H_P_rec.determinant()) < 1e-12) throw InputError(source, "H_P_rec", "is singular");
  c.T_H_C = ReadPose(root, "T_H_C", source);
  c.T_B_K = ReadPose(root, "T_B_K", source);
  const cv::FileNode depth = root["depth_model"];
  if (depth.empty() || !depth.isMap()) throw InputError(source, "depth_model", "missing or not a map");
  const std::string kind = ReadString(depth, "kind", source, "depth_model.kind");
  const char* affine_name = DepthCorrectionModelName(DepthCorrectionModel::kAffineInChipDepth);
  const char* inverse_name = DepthCorrectionModelName(DepthCorrectionModel::kInverseAffineInRaw);
  if (kind == affine_name) {
    c.depth = DepthCorrection{DepthCorrectionModel::kAffineInChipDepth, {}, {}};
  } else if (kind == inverse_name) {
    c.depth = DepthCorrection{DepthCorrectionModel::kInverseAffineInRaw, {}, {}};
  } else if (kind != "none") {
    throw InputError(source, "depth_model.kind",
                     "'" + kind + "'; must be none, " + affine_name + " or " + inverse_name);
  }
  const double focal_px = ReadReal(depth, "chip_focal_px", source, "depth_model.chip_focal_px");
  if (!(focal_px > 0.0)) throw InputError(source, "depth_model.chip_focal_px", "must be > 0");
  c.chip.camera.fx = c.chip.camera.fy = focal_px;
  c.chip.baseline_m = ReadReal(depth, "chip_baseline_m", source, "depth_model.chip_baseline_m");
  if (!(c.chip.baseline_m > 0.0)) throw InputError(source, "depth_model.chip_baseline_m", "must be > 0");
  c.chip.raw_offset = ReadReal(depth, "chip_raw_offset", source, "depth_model.chip_raw_offset");
  if (!(c.chip.raw_offset > 0.0 && c.chip.raw_offset < kRawInvalid)) {
    throw InputError(source, "depth_model.chip_raw_offset", "must be in (0, " + std::to_string(kRawInvalid) + ")");
  }
  if (c.depth) {
    ReadMap(depth, "a", path, c.camera).convertTo(c.depth->a, CV_64F);
    ReadMap(depth, "b", path, c.camera).convertTo(c.depth->b, CV_64F);
    // NaN marks an unfitted pixel; a model that fits none would turn every frame into no depth.
    const cv::Mat fitted = (c.depth->a == c.depth->a) & (c.depth->b == c.depth->b);
    if (cv::countNonZero(fitted) == 0) throw InputError(source, "depth_model.a", "fits no pixel (every a or b is NaN)");
  }
  const cv::FileNode residuals = root["residuals"];
  if (residuals.empty() || !residuals.isMap()) throw InputError(source, "residuals", "missing or not a map");
  for (const ResidualField& f : kResidualFields) {
    const double v = ReadReal(residuals, f.name, source, std::string("residuals.") + f.name);
    if (v < 0.0 && v != -1.0)
      throw InputError(source, std::string("residuals.") + f.name, "must be >= 0, or -1 for a step not run");
    c.residuals.*(f.member) = v;
  }
  return c;
}

}  // namespace

namespace {

// OpenCV throws when a node is of another kind than asked for (a list where a map is read).
template <typename Read>
Calibration WithOpenCvErrorsAsInputErrors(const fs::path& path, Read read) {
  try {
    return read();
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    throw InputError(path.string(), "", std::string("not a valid calibration file: ") + e.what());
  }
}

Calibration ReadDeviceCalibration(const fs::path& path) {
  const std::string source = path.string();
  const cv::FileStorage fs = OpenCalibrationFile(path);
  const cv::FileNode root = fs.root();
  if (!root["depth_model"].empty()) {
    try {
      return ReadWholeCalibration(root, path);
    } catch (const InputError& e) {
      throw InputError(e.source(), e.field(),
                       e.problem() + " (the file has a depth_model, so it is read as a whole calibration file, "
                                     "as `romunect calibrate` writes one)");
    }
  }
  Calibration c;
  c.camera = CameraModel::Read(root, source);
  c.T_H_C = ReadPose(root, "T_H_C", source);
  return c;
}

}  // namespace

Calibration LoadCalibration(const fs::path& path) {
  return WithOpenCvErrorsAsInputErrors(path,
                                       [&] { return ReadWholeCalibration(OpenCalibrationFile(path).root(), path); });
}

Calibration LoadDeviceCalibration(const fs::path& path) {
  return WithOpenCvErrorsAsInputErrors(path, [&] { return ReadDeviceCalibration(path); });
}

std::string HandEyeWarning(const Calibration& calibration, const std::string& path) {
  if (calibration.residuals.hand_eye_rms_px < 0.0 && calibration.T_H_C.isApprox(Pose::Identity(), 0.0)) {
    return path +
           ": T_H_C is the identity and has no hand-eye residual: not calibrated yet? (`romunect calibrate hand-eye`)";
  }
  if (const double t = calibration.T_H_C.translation().norm(); t > kHandEyeMaxTranslationM) {
    std::ostringstream s;
    s << path << ": T_H_C puts the camera " << t << " m from the flange: millimetres where metres are expected?";
    return s.str();
  }
  return "";
}

}  // namespace romunect::calib
