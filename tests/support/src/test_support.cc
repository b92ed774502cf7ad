#include "romunect/testing/test_support.h"

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

namespace romunect::testing {
namespace fs = std::filesystem;

ScratchDir::ScratchDir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string test = info ? std::string(info->test_suite_name()) + "." + info->name() : "none";
  for (char& c : test) {
    if (c == '/') c = '_';
  }
  path_ = fs::path(ROMUNECT_BINARY_DIR) / "test_scratch" / test / name;
  fs::remove_all(path_);
  fs::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  if (info == nullptr || !info->result()->Failed()) {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
}

::testing::AssertionResult ImagesBitEqual(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) {
    return ::testing::AssertionFailure() << "size/type differ: " << a.cols << "x" << a.rows << " "
                                         << cv::typeToString(a.type()) << " vs " << b.cols << "x" << b.rows << " "
                                         << cv::typeToString(b.type());
  }
  const size_t row_bytes = a.cols * a.elemSize();
  for (int r = 0; r < a.rows; ++r) {
    if (std::memcmp(a.ptr(r), b.ptr(r), row_bytes) != 0) {
      return ::testing::AssertionFailure() << "bytes differ in row " << r;
    }
  }
  return ::testing::AssertionSuccess();
}

::testing::AssertionResult PosesNear(const Pose& a, const Pose& b, double angle_rad, double translation_m) {
  const PoseError e = ComparePoses(a, b);
  if (e.angle_rad <= angle_rad && e.translation_m <= translation_m) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "poses differ by " << e.angle_rad << " rad (max " << angle_rad << ") and "
                                       << e.translation_m << " m (max " << translation_m << ")";
}

fs::path RomunectBinary() { return fs::path(ROMUNECT_BINARY_DIR) / "bin" / "romunect"; }

CommandResult RunRomunect(const std::string& arguments) { return RunShell(RomunectBinary().string() + " " + arguments); }

CommandResult RunShell(const std::string& command_line) {
  const std::string command = "(" + command_line + ") 2>&1";
  CommandResult result;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return result;
  std::array<char, 4096> buffer;
  size_t n;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0) result.output.append(buffer.data(), n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

void WriteText(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace romunect::testing

#include <random>

#include "romunect/sensor/frame_io.h"

namespace romunect::testing {

CameraModel SmallCamera() {
  CameraModel c;
  c.width = 80;
  c.height = 60;
  c.fx = c.fy = 300.0;
  c.cx = 39.5;
  c.cy = 29.5;
  c.distortion = {-0.1, 0.05, 0.001, -0.001, 0.0};
  return c;
}

std::vector<Frame> SampleFrames(const CameraModel& camera, int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> depth(0.18f, 0.22f);
  std::uniform_int_distribution<int> ir(0, 1023), raw(0, 2047);
  std::bernoulli_distribution hole(0.3);
  std::vector<Frame> frames;
  for (int i = 0; i < count; ++i) {
    Frame f;
    f.index = i;
    f.time_s = i / 30.0;
    f.depth_m.create(camera.height, camera.width, CV_32F);
    f.gt_depth_m.create(camera.height, camera.width, CV_32F);
    f.ir.create(camera.height, camera.width, CV_16U);
    f.raw.create(camera.height, camera.width, CV_16U);
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) {
        const float d = depth(rng);
        f.gt_depth_m.at<float>(v, u) = d;
        f.depth_m.at<float>(v, u) = hole(rng) ? 0.0f : d;
        f.ir.at<uint16_t>(v, u) = static_cast<uint16_t>(ir(rng));
        f.raw.at<uint16_t>(v, u) = static_cast<uint16_t>(raw(rng));
      }
    }
    // Looking down (z_C = -z_W) from 0.4 m, descending 1 cm per frame, slightly rotated.
    const Eigen::Matrix3d R_W_C = (Eigen::AngleAxisd(0.01 * i, Eigen::Vector3d::UnitZ()) *
                                   Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()))
                                      .toRotationMatrix();
    f.T_W_C = MakePose(R_W_C, Eigen::Vector3d(0.001 * i, -0.002 * i, 0.4 - 0.01 * i));
    if (i % 2 == 0) f.T_B_H = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.5, 0.0, 0.3 + 0.01 * i));
    frames.push_back(std::move(f));
  }
  return frames;
}

void WriteSampleFrameDirectory(const std::filesystem::path& dir, const CameraModel& camera, int count, uint32_t seed) {
  FrameDirectoryWriter writer(dir, camera);
  for (const Frame& f : SampleFrames(camera, count, seed)) writer.Add(f);
  writer.Finish();
}

}  // namespace romunect::testing
