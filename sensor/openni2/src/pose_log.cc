#include "romunect/sensor/openni2/pose_log.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect::openni2 {
namespace {

constexpr double kQuaternionNormTolerance = 1e-3;  // a logged unit quaternion, rounded to ~4 digits
constexpr const char* kColumns[] = {"time_s", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz"};

std::string Trim(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\r");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t\r") - a + 1);
}

}  // namespace

PoseLog::PoseLog(std::vector<TimedPose> poses) : poses_(std::move(poses)) {
  ROMUNECT_CHECK_MSG(!poses_.empty(), "a pose log needs at least one pose");
  for (size_t i = 1; i < poses_.size(); ++i) ROMUNECT_CHECK(poses_[i].time_s > poses_[i - 1].time_s);
}

PoseLog PoseLog::Load(const std::filesystem::path& path) {
  const std::string source = path.string();
  std::ifstream in(path);
  if (!in) throw InputError(source, "", "cannot open the pose log");
  std::vector<TimedPose> poses;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    line = Trim(line);
    if (line.empty()) continue;
    std::stringstream cells(line);
    // A header (a first line whose first cell is not a number) must name the columns in their
    // order: a log written elsewhere (w last, say) would otherwise be read as w-first unnoticed.
    const std::string first = Trim(line.substr(0, line.find(',')));
    char* first_end = nullptr;
    std::strtod(first.c_str(), &first_end);
    if (poses.empty() && (first.empty() || *first_end != '\0')) {
      std::string cell, expected, found;
      bool same = true;
      int n = 0;
      while (std::getline(cells, cell, ',')) {
        cell = Trim(cell);
        same = same && n < 8 && cell == kColumns[n];
        if (n > 0) found += ',';
        found += cell;
        ++n;
      }
      for (int k = 0; k < 8; ++k) {
        if (k > 0) expected += ',';
        expected += kColumns[k];
      }
      if (!same || n != 8) {
        throw InputError(source, "line " + std::to_string(line_number),
                         "header '" + found + "' is not '" + expected + "' (quaternion w first)");
      }
      continue;
    }
    std::string cell;
    double v[8];
    int n = 0;
    const std::string where = "line " + std::to_string(line_number);
    while (std::getline(cells, cell, ',')) {
      if (n >= 8) throw InputError(source, where, "more than 8 columns (time_s, x_m, y_m, z_m, qw, qx, qy, qz)");
      cell = Trim(cell);
      char* end = nullptr;
      v[n] = std::strtod(cell.c_str(), &end);
      if (cell.empty() || *end != '\0' || !std::isfinite(v[n])) {
        throw InputError(source, where + ": " + kColumns[n], "'" + cell + "' is not a finite number");
      }
      ++n;
    }
    if (n != 8) {
      throw InputError(source, where,
                       std::to_string(n) + " columns, expected 8 (time_s, x_m, y_m, z_m, qw, qx, qy, qz)");
    }
    if (!poses.empty() && !(v[0] > poses.back().time_s)) {
      throw InputError(source, where + ": time_s",
                       std::to_string(v[0]) + " does not follow " + std::to_string(poses.back().time_s) +
                           " (times must strictly increase)");
    }
    const double norm = std::sqrt(v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]);
    if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
      throw InputError(source, where + ": qw..qz",
                       "quaternion norm " + std::to_string(norm) + " is not 1 (within 1e-3)");
    }
    TimedPose p;
    p.time_s = v[0];
    p.T_B_H = MakePoseWxyz({v[4] / norm, v[5] / norm, v[6] / norm, v[7] / norm}, Eigen::Vector3d(v[1], v[2], v[3]));
    poses.push_back(p);
  }
  if (poses.empty()) throw InputError(source, "", "the pose log holds no poses");
  return PoseLog(std::move(poses));
}

std::optional<Pose> PoseLog::At(double t_s) const {
  if (!(t_s >= begin_s() && t_s <= end_s())) return std::nullopt;
  // First entry later than t_s; the pair (i-1, i) brackets it.
  const auto it = std::upper_bound(poses_.begin(), poses_.end(), t_s,
                                   [](double t, const TimedPose& p) { return t < p.time_s; });
  if (it == poses_.end()) return poses_.back().T_B_H;
  const TimedPose& b = *it;
  const TimedPose& a = *(it - 1);
  const double alpha = (t_s - a.time_s) / (b.time_s - a.time_s);
  return InterpolatePose(a.T_B_H, b.T_B_H, alpha);
}

void PoseLog::Save(const std::filesystem::path& path) const {
  std::ostringstream out;
  out << "# romunect pose log: T_B_H (hand in robot base), quaternion w first\n";
  out << "time_s,x_m,y_m,z_m,qw,qx,qy,qz\n";
  char buffer[512];
  for (const TimedPose& p : poses_) {
    const Eigen::Quaterniond q(p.T_B_H.rotation());
    const Eigen::Vector3d t = p.T_B_H.translation();
    std::snprintf(buffer, sizeof(buffer), "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n", p.time_s, t.x(), t.y(),
                  t.z(), q.w(), q.x(), q.y(), q.z());
    out << buffer;
  }
  WriteTextAtomically(path, out.str());
}

std::string PoseLogSourceOptions::Problem() const {
  if (!std::isfinite(time_offset_s)) return "time_offset_s = " + std::to_string(time_offset_s) + ": must be finite";
  return "";
}

PoseLogSource::PoseLogSource(std::unique_ptr<FrameSource> inner, PoseLog log, const PoseLogSourceOptions& options)
    : inner_(std::move(inner)), log_(std::move(log)), options_(options) {
  ROMUNECT_CHECK(inner_ != nullptr);
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("pose log options", "", problem);
}

std::string PoseLogSource::Describe() const {
  std::ostringstream d;
  d << inner_->Describe() << ", poses from a log of " << log_.poses().size() << " entries (" << log_.begin_s() << " .. "
    << log_.end_s() << " s)";
  return d.str();
}

FrameStatus PoseLogSource::Next(Frame* frame, std::string* error) {
  const FrameStatus status = inner_->Next(frame, error);
  if (status != FrameStatus::kOk) return status;
  const double t_log_s = frame->time_s + options_.time_offset_s;
  const std::optional<Pose> T_B_H = log_.At(t_log_s);
  if (!T_B_H) {
    ++stats_.outside_log;
    std::ostringstream e;
    e << "frame " << frame->index << " at " << t_log_s << " s lies outside the pose log [" << log_.begin_s() << ", "
      << log_.end_s() << "] s";
    *error = e.str();
    return FrameStatus::kBadFrame;
  }
  frame->T_B_H = *T_B_H;
  if (options_.T_H_C) frame->T_W_C = options_.T_W_B * *T_B_H * *options_.T_H_C;
  ++stats_.frames;
  return FrameStatus::kOk;
}

}  // namespace romunect::openni2
