#include "feed_library_source.h"

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <stdexcept>

namespace romunect::openni2 {
namespace {

// The simulator's feed library: libRomunectSimFeed.so in <build>/lib, beside the virtual device's
// backend this code is part of (CMake builds both there).
std::string DefaultFeedLibrary() {
  Dl_info info{};
  if (dladdr(reinterpret_cast<void*>(&DefaultFeedLibrary), &info) == 0 || info.dli_fname == nullptr) return "";
  return (std::filesystem::path(info.dli_fname).parent_path() / "libRomunectSimFeed.so").string();
}

}  // namespace

FeedLibrarySource::FeedLibrarySource(const std::string& library, const std::string& query)
    : path_(library.empty() ? DefaultFeedLibrary() : library) {
  LoadLibrary(path_);
  try {
    CreateFeed(query);
  } catch (...) {
    dlclose(handle_);
    throw;
  }
  camera_.width = info_.width;
  camera_.height = info_.height;
  camera_.fx = info_.fx;
  camera_.fy = info_.fy;
  camera_.cx = info_.cx;
  camera_.cy = info_.cy;
}

void FeedLibrarySource::LoadLibrary(const std::string& path) {
  // Never unloaded (NODELETE): its renderer's and physics' threads and statics may outlive the feed.
  handle_ = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
  if (handle_ == nullptr) throw std::runtime_error("cannot load the feed library " + path + ": " + dlerror());
  create_ = reinterpret_cast<RomunectFeedCreateFn>(dlsym(handle_, ROMUNECT_FEED_CREATE_SYMBOL));
  next_ = reinterpret_cast<RomunectFeedNextFn>(dlsym(handle_, ROMUNECT_FEED_NEXT_SYMBOL));
  destroy_ = reinterpret_cast<RomunectFeedDestroyFn>(dlsym(handle_, ROMUNECT_FEED_DESTROY_SYMBOL));
  if (create_ == nullptr || next_ == nullptr || destroy_ == nullptr) {
    dlclose(handle_);
    throw std::runtime_error(path + " is not a romunect feed library (it lacks romunect_feed_create/next/destroy)");
  }
}

void FeedLibrarySource::CreateFeed(const std::string& query) {
  char error[1024] = "";
  RomunectFeedInfo info{};
  feed_ = create_(query.c_str(), &info, error, sizeof(error));
  if (feed_ == nullptr) throw std::runtime_error(path_ + ": " + error);
  if ((info.abi_version != 1 && info.abi_version != ROMUNECT_FEED_ABI_VERSION) || info.width <= 0 || info.height <= 0 ||
      !(info.fx > 0.0 && info.fy > 0.0)) {
    destroy_(feed_);
    throw std::runtime_error(path_ + ": unsupported feed (ABI version " + std::to_string(info.abi_version) + ", size " +
                             std::to_string(info.width) + "x" + std::to_string(info.height) + ")");
  }
  info_ = info;
  if (info.abi_version < 2 || info.has_color == 0) return;
  ColorCamera rgb;
  rgb.camera.width = info.color_width;
  rgb.camera.height = info.color_height;
  rgb.camera.fx = info.color_fx;
  rgb.camera.fy = info.color_fy;
  rgb.camera.cx = info.color_cx;
  rgb.camera.cy = info.color_cy;
  std::array<double, 16> T;
  std::copy(std::begin(info.T_C_RGB), std::end(info.T_C_RGB), T.begin());
  const std::string matrix_problem = RigidityProblem(
      Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(T.data()));
  if (!matrix_problem.empty()) {
    destroy_(feed_);
    throw std::runtime_error(path_ + ": the feed's T_C_RGB is not rigid: " + matrix_problem);
  }
  rgb.T_C_RGB = PoseFromRowMajor(T);
  if (const std::string problem = rgb.Problem(); !problem.empty()) {
    destroy_(feed_);
    throw std::runtime_error(path_ + ": the feed's colour camera: " + problem);
  }
  color_camera_ = rgb;
}

FeedLibrarySource::~FeedLibrarySource() {
  destroy_(feed_);
  dlclose(handle_);
}

std::string FeedLibrarySource::Describe() const {
  std::string d = "feed library " + path_ + ", " + std::to_string(info_.width) + "x" + std::to_string(info_.height);
  d += info_.frame_count > 0 ? ", " + std::to_string(info_.frame_count) + " frames" : std::string(", endless");
  return d;
}

FrameStatus FeedLibrarySource::Next(Frame* frame, std::string* error) {
  if (ended_) return FrameStatus::kEndOfStream;
  char message[1024] = "";
  RomunectFeedFrame f{};
  const int status = next_(feed_, &f, message, sizeof(message));
  if (status == 0) {
    ended_ = true;
    return FrameStatus::kEndOfStream;
  }
  const int index = produced_++;
  if (status < 0) {
    *error = message;
    return FrameStatus::kBadFrame;
  }
  *frame = Frame();
  frame->index = index;
  frame->time_s = f.time_s;
  // Copies: the feed's buffers live only until its next call.
  const int h = info_.height, w = info_.width;
  if (f.depth_m != nullptr) frame->depth_m = cv::Mat(h, w, CV_32F, const_cast<float*>(f.depth_m)).clone();
  if (f.ir != nullptr) frame->ir = cv::Mat(h, w, CV_16U, const_cast<uint16_t*>(f.ir)).clone();
  if (color_camera_ && f.color_rgb != nullptr) {
    frame->color = cv::Mat(color_camera_->camera.height, color_camera_->camera.width, CV_8UC3,
                           const_cast<uint8_t*>(f.color_rgb))
                       .clone();
  }
  return FrameStatus::kOk;
}

}  // namespace romunect::openni2
