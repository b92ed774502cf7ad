// Helpers shared by romunect's tests: scratch folders, image comparisons, named tolerances.
#pragma once

#include <filesystem>
#include <initializer_list>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/pose.h"

namespace romunect::testing {

// A fresh empty folder under the build tree, removed when the object goes out of scope
// (kept when the test failed, for inspection).
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& name);
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// True when two Mats have the same size, type and bytes (NaN compared by bit pattern).
::testing::AssertionResult ImagesBitEqual(const cv::Mat& a, const cv::Mat& b);

// True when two poses differ by at most angle_rad and translation_m.
::testing::AssertionResult PosesNear(const Pose& a, const Pose& b, double angle_rad, double translation_m);

// The romunect executable of this build, and a helper that runs it and captures output.
std::filesystem::path RomunectBinary();
struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};
CommandResult RunRomunect(const std::string& arguments);
// Runs a shell command line (sh -c), output and errors together.
CommandResult RunShell(const std::string& command_line);

// Writes text to a file (for crafting malformed inputs).
void WriteText(const std::filesystem::path& path, const std::string& text);
std::string ReadText(const std::filesystem::path& path);

// Expects an error message (InputErrorOf's) that is not empty and holds every fragment.
inline void ExpectContains(const std::string& message, std::initializer_list<std::string> fragments) {
  ASSERT_FALSE(message.empty()) << "expected an InputError";
  for (const std::string& f : fragments) EXPECT_NE(message.find(f), std::string::npos) << f << " not in: " << message;
}

// The message of the InputError that f() throws ("" when it throws none).
template <typename F>
std::string InputErrorOf(F f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace romunect::testing

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame.h"

namespace romunect::testing {

// A small camera (80 x 60) for fast tests.
CameraModel SmallCamera();

// Deterministic frames for I/O tests: depth, IR, raw and ground truth with distinct values,
// poses on a short descending path. Same seed, same bytes.
std::vector<Frame> SampleFrames(const CameraModel& camera, int count, uint32_t seed);

// Writes SampleFrames() as a complete frame directory at dir.
void WriteSampleFrameDirectory(const std::filesystem::path& dir, const CameraModel& camera, int count, uint32_t seed);

}  // namespace romunect::testing
