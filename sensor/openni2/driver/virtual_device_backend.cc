// libRomunectVirtualBackend.so: the virtual device's devices and streams, which present a
// FrameSource as a PS1080-like device: a frame directory, or the frames of a feed library
// (feed_abi.h, e.g. the live simulator) (device_content.h; romunect/sensor/openni2/virtual_device.h
// documents URIs and behaviour). The driver plug-in (virtual_driver.cc) loads it only when a
// device opens (backend_abi.h), so OpenNI2 programs that never open one map none of its
// libraries (OpenCV and what it pulls in).
//
// Threads: OpenNI2 calls in from the application's threads; in realtime pace one producer thread
// per device sends frames. One mutex per device guards the streams and the frame cursor and is
// held while a frame is handed to OpenNI2, so a stream is never destroyed mid-delivery.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "backend_abi.h"  // OpenNI2's driver API first: its XN_NEW/XN_DELETE

#include <PS1080.h>

#include "device_content.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/sensor/rig.h"
#include "virtual_device_uri.h"

namespace romunect::openni2 {
namespace {

// The PS1080 geometry the chip reports, in its own units. Defaults follow the twin's stock chip
// (RigPreset("kinect-v1")): ZPD is the PS1080's fixed 120 mm, ZPPS the pixel size there for the
// chip's 1280-px sensor (ZPD / 2 f at 640 px), LDDIS the baseline. A frames.json may override
// any of them with a top-level "ps1080" object of the same keys (docs/hardware.md).
struct ChipParameters {
  uint64_t zero_plane_distance_mm = 120;
  double zero_plane_pixel_size_mm = 0.1042;
  double emitter_dcmos_distance_cm = 7.5;
  double dcmos_rcmos_distance_cm = 2.4;
  uint64_t const_shift = 200;
  uint64_t param_coeff = 4;
  uint64_t shift_scale = 10;
  uint64_t max_shift = 2047;
  uint64_t pixel_size_factor = 1;
};

ChipParameters StockChipParameters() {
  ChipParameters p;
  const romunect::ChipGeometry chip = RigPreset("kinect-v1").depth_engine.chip;
  p.zero_plane_pixel_size_mm = static_cast<double>(p.zero_plane_distance_mm) / (2.0 * chip.camera.fx);
  p.emitter_dcmos_distance_cm = chip.baseline_m * 100.0;
  return p;
}

// The chip's "ps1080" block of frames.json (`source`), each key optional (the stock chip's value
// otherwise) and refused, naming it, when it is not what a PS1080 reports: clients divide by the
// factors and size shift tables by max_shift.
ChipParameters ReadChipParameters(const std::string& extra_json, const std::string& source) {
  ChipParameters p = StockChipParameters();
  const nlohmann::json extra = nlohmann::json::parse(extra_json, nullptr, false);
  if (!extra.is_object() || !extra.contains("ps1080")) return p;
  if (!extra["ps1080"].is_object()) throw InputError(source, "ps1080", "expected an object");
  const nlohmann::json& j = extra["ps1080"];
  // the value as found: a number in full, anything else by its type (a string may be long)
  auto found = [&j](const char* key) {
    return j[key].is_number() ? j[key].dump() : std::string("a ") + j[key].type_name();
  };
  auto whole = [&](const char* key, uint64_t lo, uint64_t hi, uint64_t* value) {
    if (!j.contains(key)) return;
    if (!j[key].is_number_unsigned() || j[key].get<uint64_t>() < lo || j[key].get<uint64_t>() > hi) {
      throw InputError(source, std::string("ps1080.") + key,
                       "expected a whole number in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], found " +
                           found(key));
    }
    *value = j[key].get<uint64_t>();
  };
  auto length = [&](const char* key, double lo, double hi, double* value) {
    if (!j.contains(key)) return;
    if (!j[key].is_number() || !(j[key].get<double>() > lo && j[key].get<double>() <= hi)) {
      throw InputError(source, std::string("ps1080.") + key,
                       "expected a number in (" + nlohmann::json(lo).dump() + ", " + nlohmann::json(hi).dump() +
                           "], found " + found(key));
    }
    *value = j[key].get<double>();
  };
  whole("zero_plane_distance_mm", 1, 10000, &p.zero_plane_distance_mm);
  length("zero_plane_pixel_size_mm", 0.0, 10.0, &p.zero_plane_pixel_size_mm);
  length("emitter_dcmos_distance_cm", 0.0, 100.0, &p.emitter_dcmos_distance_cm);
  length("dcmos_rcmos_distance_cm", -100.0, 100.0, &p.dcmos_rcmos_distance_cm);
  whole("const_shift", 0, 65535, &p.const_shift);
  whole("param_coeff", 1, 65535, &p.param_coeff);
  whole("shift_scale", 1, 65535, &p.shift_scale);
  whole("max_shift", 1, 65535, &p.max_shift);
  whole("pixel_size_factor", 1, 64, &p.pixel_size_factor);
  return p;
}

// Bytes per pixel of the formats the device sends.
int BytesPerPixel(OniPixelFormat format) {
  switch (format) {
    case ONI_PIXEL_FORMAT_RGB888: return 3;
    case ONI_PIXEL_FORMAT_GRAY8: return 1;
    default: return 2;  // depth, shifts, GRAY16, YUV422 and YUYV (4 bytes per 2 pixels)
  }
}

bool IsYuv(OniPixelFormat format) { return format == ONI_PIXEL_FORMAT_YUV422 || format == ONI_PIXEL_FORMAT_YUYV; }

template <typename T>
OniStatus Answer(const T& value, void* data, int* size) {
  if (*size != static_cast<int>(sizeof(T))) return ONI_STATUS_BAD_PARAMETER;
  std::memcpy(data, &value, sizeof(T));
  return ONI_STATUS_OK;
}

// A file descriptor closed when it goes out of scope (-1: none).
class UniqueFd {
 public:
  explicit UniqueFd(int fd = -1) : fd_(fd) {}
  UniqueFd(UniqueFd&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}
  UniqueFd& operator=(UniqueFd&&) = delete;
  ~UniqueFd() {
    if (fd_ >= 0) close(fd_);
  }

 private:
  int fd_;
};

// Opens a frame directory exclusively, as a USB sensor opens once: an flock on the directory,
// which the kernel drops when the process ends, however it ends. Throws when another process
// holds it.
UniqueFd LockDirectory(const std::filesystem::path& dir) {
  const int raw = open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (raw < 0) return UniqueFd();  // no directory: the frame directory's own check says so
  UniqueFd locked(raw);
  if (flock(raw, LOCK_EX | LOCK_NB) != 0) {
    throw std::runtime_error(dir.string() + " is open in another process: a device opens once, as a USB sensor");
  }
  return locked;
}

class VirtualDevice;

class VirtualStream : public oni::driver::StreamBase {
 public:
  VirtualStream(VirtualDevice* device, OniSensorType type) : device_(device), type_(type) {}

  OniStatus start() override;
  void stop() override;
  OniStatus setProperty(int id, const void* data, int size) override;
  OniStatus getProperty(int id, void* data, int* size) override;
  OniBool isPropertySupported(int id) override;
  void notifyAllProperties() override;
  int getRequiredFrameSize() override {
    return mode_.resolutionX * mode_.resolutionY * BytesPerPixel(mode_.pixelFormat);
  }
  OniStatus convertDepthToColorCoordinates(StreamBase* color_stream, int depth_x, int depth_y, OniDepthPixel depth_z,
                                           int* color_x, int* color_y) override;

  OniSensorType type() const { return type_; }
  // Read and written with the device mutex held: the producer checks and waits under it.
  bool started() const { return started_; }
  void set_started(bool started) { started_ = started; }
  const OniVideoMode& mode() const { return mode_; }
  void set_mode(const OniVideoMode& mode) { mode_ = mode; }

  // How a frame becomes a half-size (QVGA) one: depth keeps every 2nd pixel of every 2nd row (a
  // mean would invent depths across edges), IR and colour average 2 x 2 pixels (binning).
  enum class HalfSize { kEvery2nd, kMean };
  // Hands one frame (CV_16U, or the colour image's CV_8UC3 RGB; the frames' size, halved for a
  // half-size mode) to OpenNI2 in the mode's pixel format. Called with the device mutex held.
  void Send(const cv::Mat& image, int frame_index, uint64_t timestamp_us, HalfSize half);

 private:
  VirtualDevice* device_;
  OniSensorType type_;
  OniVideoMode mode_{};
  // As the PS1080's: a horizontal flip, then a sub-rectangle of the flipped image. Device mutex.
  bool mirror_ = false;
  OniCropping crop_{FALSE, 0, 0, 0, 0};
  bool started_ = false;
};

// A test hook (romunect_virtual_device_set_wait_hook): called by the producer with the device
// mutex held, each time it is about to wait for a stream to start.
std::atomic<void (*)()> g_before_wait_hook{nullptr};

class VirtualDevice : public oni::driver::DeviceBase {
 public:
  VirtualDevice(const std::string& uri, const ParsedVirtualDeviceUri& parsed, oni::driver::DriverServices* services,
                VirtualBackendEndedFn ended)
      : uri_(uri),
        ended_callback_(ended),
        options_(parsed.options),
        services_(services),
        lock_(parsed.feed ? UniqueFd() : LockDirectory(parsed.dir)),  // throws
        content_(OpenDeviceContent(parsed)) {                         // throws
    chip_ = ReadChipParameters(content_.extra_json, parsed.feed ? uri : (parsed.dir / "frames.json").string());
    has_ir_ = content_.has_ir;
    fps_ = static_cast<int>(std::lround(options_.fps > 0.0 ? options_.fps : content_.fps));
    if (fps_ <= 0) fps_ = 30;
    const int w = camera().width, h = camera().height;
    // As the PS1080: depth in 1 mm and 100 um and IR at the frames' size (VGA) and at half of it
    // (QVGA), the first of each list being the stream's default (1 mm QVGA, as the PS1080's);
    // the chip's raw shifts (SHIFT_9_2: 11 bits, 2047 = none) at the frames' size when they hold
    // raw.
    std::vector<std::pair<int, int>> sizes;
    if (w % 2 == 0 && h % 2 == 0) sizes.emplace_back(w / 2, h / 2);
    sizes.emplace_back(w, h);
    for (const auto& [mw, mh] : sizes) {
      if (content_.has_depth) {
        depth_modes_.push_back({ONI_PIXEL_FORMAT_DEPTH_1_MM, mw, mh, fps_});
        depth_modes_.push_back({ONI_PIXEL_FORMAT_DEPTH_100_UM, mw, mh, fps_});
      }
      ir_modes_.push_back({ONI_PIXEL_FORMAT_GRAY16, mw, mh, fps_});
    }
    if (content_.has_raw) depth_modes_.push_back({ONI_PIXEL_FORMAT_SHIFT_9_2, w, h, fps_});
    // Colour as the PS1080's: RGB888 at the colour camera's size (VGA, the default) and half of
    // it (QVGA), then YUV422 (UYVY) and YUYV at both.
    if (content_.color_camera) {
      const int cw = content_.color_camera->camera.width, ch = content_.color_camera->camera.height;
      std::vector<std::pair<int, int>> color_sizes{{cw, ch}};
      if (cw % 4 == 0 && ch % 2 == 0) color_sizes.emplace_back(cw / 2, ch / 2);
      for (OniPixelFormat format : {ONI_PIXEL_FORMAT_RGB888, ONI_PIXEL_FORMAT_YUV422, ONI_PIXEL_FORMAT_YUYV}) {
        for (const auto& [mw, mh] : color_sizes) {
          if (!IsYuv(format) || mw % 2 == 0) color_modes_.push_back({format, mw, mh, fps_});
        }
      }
    }
    has_depth_ = !depth_modes_.empty();
    if (has_depth_) sensors_.push_back({ONI_SENSOR_DEPTH, static_cast<int>(depth_modes_.size()), depth_modes_.data()});
    if (has_ir_) sensors_.push_back({ONI_SENSOR_IR, static_cast<int>(ir_modes_.size()), ir_modes_.data()});
    if (!color_modes_.empty()) {
      sensors_.push_back({ONI_SENSOR_COLOR, static_cast<int>(color_modes_.size()), color_modes_.data()});
    }
    if (options_.pace == VirtualDeviceOptions::Pace::kRealtime) producer_ = std::thread([this] { Produce(); });
  }

  ~VirtualDevice() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closing_ = true;
    }
    wake_.notify_all();
    if (producer_.joinable()) producer_.join();
  }

  OniStatus getSensorInfoList(OniSensorInfo** infos, int* count) override {
    *infos = sensors_.data();
    *count = static_cast<int>(sensors_.size());
    return ONI_STATUS_OK;
  }

  oni::driver::StreamBase* createStream(OniSensorType type) override {
    const std::vector<OniVideoMode>* modes = Modes(type);
    if (modes == nullptr || modes->empty()) return nullptr;
    auto* stream = new VirtualStream(this, type);
    stream->set_mode(modes->front());
    std::lock_guard<std::mutex> lock(mutex_);
    streams_.insert(stream);
    return stream;
  }

  void destroyStream(oni::driver::StreamBase* stream) override {
    std::lock_guard<std::mutex> lock(mutex_);
    streams_.erase(static_cast<VirtualStream*>(stream));
    delete stream;
  }

  OniStatus getProperty(int id, void* data, int* size) override {
    switch (id) {
      case ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION: {
        std::lock_guard<std::mutex> lock(mutex_);
        return Answer(registration_, data, size);
      }
      case ONI_DEVICE_PROPERTY_DRIVER_VERSION: return Answer(OniVersion{0, 1, 0, 0}, data, size);
      case ONI_DEVICE_PROPERTY_SERIAL_NUMBER: {
        const char serial[] = "romunect-virtual";
        if (*size < static_cast<int>(sizeof(serial))) return ONI_STATUS_BAD_PARAMETER;
        std::memcpy(data, serial, sizeof(serial));
        *size = sizeof(serial);
        return ONI_STATUS_OK;
      }
      default: return ONI_STATUS_NOT_SUPPORTED;
    }
  }
  OniStatus setProperty(int id, const void* data, int size) override {
    if (id == ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION) {
      if (size != sizeof(OniImageRegistrationMode)) return ONI_STATUS_BAD_PARAMETER;
      const auto mode = *static_cast<const OniImageRegistrationMode*>(data);
      if (!isImageRegistrationModeSupported(mode)) return ONI_STATUS_NOT_SUPPORTED;
      std::lock_guard<std::mutex> lock(mutex_);
      registration_ = mode;
      return ONI_STATUS_OK;
    }
    return ONI_STATUS_NOT_SUPPORTED;
  }
  // Depth to colour needs a colour camera to register to (a directory whose frames carry colour).
  OniBool isImageRegistrationModeSupported(OniImageRegistrationMode mode) override {
    return mode == ONI_IMAGE_REGISTRATION_OFF ||
           (mode == ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR && content_.color_camera.has_value());
  }
  OniBool isPropertySupported(int id) override {
    return id == ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION || id == ONI_DEVICE_PROPERTY_DRIVER_VERSION ||
           id == ONI_DEVICE_PROPERTY_SERIAL_NUMBER;
  }

  OniBool isCommandSupported(int id) override {
    return id == kVirtualDeviceStepCommand && options_.pace == VirtualDeviceOptions::Pace::kStep;
  }
  // Step pace: sends the next frame set synchronously, so it is queued before the caller reads.
  OniStatus invoke(int id, void* /*data*/, int /*size*/) override {
    if (!isCommandSupported(id)) return ONI_STATUS_NOT_SUPPORTED;
    bool ended = false;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (CanSendLocked() && FetchLocked()) SendPendingLocked();
      ended = TakeEndLocked();
    }
    if (ended) ended_callback_(uri_.c_str());
    return ONI_STATUS_OK;
  }

  // Under the mutex, so a start cannot land between the producer's check and its wait and be
  // lost; a stop also waits out a delivery in progress, so none reaches OpenNI2 after it returns.
  void SetStarted(VirtualStream* stream, bool started) {
    std::lock_guard<std::mutex> lock(mutex_);
    stream->set_started(started);
    if (started) wake_.notify_all();
  }

  std::mutex& mutex() { return mutex_; }
  const CameraModel& camera() const { return content_.source->camera(); }
  const std::optional<ColorCamera>& color_camera() const { return content_.color_camera; }
  const ChipParameters& chip() const { return chip_; }
  int total_frames() const {
    // A finite device says how many frames it will send, as OpenNI2's file player does.
    return content_.frame_count;
  }
  bool IsOffered(OniSensorType type, const OniVideoMode& mode) const {
    const std::vector<OniVideoMode>* modes = Modes(type);
    if (modes == nullptr) return false;
    for (const OniVideoMode& m : *modes) {
      if (m.pixelFormat == mode.pixelFormat && m.resolutionX == mode.resolutionX && m.resolutionY == mode.resolutionY &&
          m.fps == mode.fps) {
        return true;
      }
    }
    return false;
  }

 private:
  const std::vector<OniVideoMode>* Modes(OniSensorType type) const {
    switch (type) {
      case ONI_SENSOR_DEPTH: return has_depth_ ? &depth_modes_ : nullptr;
      case ONI_SENSOR_IR: return has_ir_ ? &ir_modes_ : nullptr;
      case ONI_SENSOR_COLOR: return &color_modes_;
      default: return nullptr;
    }
  }

  // True once, when a finite source has ended and the driver has not been told yet. Mutex held.
  bool TakeEndLocked() {
    if (!ended_ || end_reported_ || ended_callback_ == nullptr) return false;
    end_reported_ = true;
    return true;
  }

  bool AnyStartedLocked() const {
    return std::any_of(streams_.begin(), streams_.end(), [](const VirtualStream* s) { return s->started(); });
  }
  bool CanSendLocked() const {
    if (options_.stop_after >= 0 && sent_ >= options_.stop_after) return false;
    return !ended_;
  }

  // The source's next frame. A source that can no longer deliver (it throws) ends the device's
  // stream, as a sensor whose cable was pulled: OpenNI2 has no way to pass an error on.
  FrameStatus NextFromSource(Frame* frame, std::string* error) {
    try {
      return content_.source->Next(frame, error);
    } catch (const std::exception& e) {
      services_->errorLoggerAppend("romunect virtual device: %s", e.what());
      return FrameStatus::kEndOfStream;
    }
  }

  // Takes the next frame from the source into pending_ (unless one waits there). Mutex held.
  // False at the source's end.
  bool FetchLocked() {
    if (pending_) return true;
    Frame frame;
    std::string error;
    for (;;) {
      const FrameStatus status = NextFromSource(&frame, &error);
      if (status == FrameStatus::kEndOfStream) {
        ended_ = true;
        return false;
      }
      if (status == FrameStatus::kOk) break;
      services_->errorLoggerAppend("romunect virtual device: %s", error.c_str());
      ++sent_;  // the lost frame's number is skipped, as a device that drops one
    }
    frame.time_s -= content_.time_origin_s;
    pending_ = std::move(frame);
    return true;
  }

  // Hands the pending frame to every started stream, numbered `frame_index` and stamped
  // `time_s` on the device's clock. Mutex held.
  void SendPendingLocked(int skipped = 0) {
    const Frame frame = std::move(*pending_);
    pending_.reset();
    sent_ += skipped;                 // the frames dropped before this one keep their numbers
    const int frame_index = ++sent_;  // 1-based, as the PS1080 and .oni files count
    const uint64_t timestamp_us = static_cast<uint64_t>(std::llround((frame.time_s + time_shift_s_) * 1e6));
    // Depth seen from the colour camera, once for every depth stream, when registration is on.
    cv::Mat registered_m;
    for (VirtualStream* s : streams_) {
      if (!s->started()) continue;
      if (s->type() == ONI_SENSOR_IR) {
        s->Send(frame.ir, frame_index, timestamp_us, VirtualStream::HalfSize::kMean);
      } else if (s->type() == ONI_SENSOR_COLOR) {
        s->Send(frame.color, frame_index, timestamp_us, VirtualStream::HalfSize::kMean);
      } else if (s->mode().pixelFormat == ONI_PIXEL_FORMAT_SHIFT_9_2) {
        s->Send(frame.raw, frame_index, timestamp_us, VirtualStream::HalfSize::kEvery2nd);
      } else {
        const bool registered = registration_ == ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR;
        if (registered && registered_m.empty()) {
          registered_m = RegisterDepthToColor(frame.depth_m, camera(), *content_.color_camera, frame.depth_m.size());
        }
        const cv::Mat& depth_m = registered ? registered_m : frame.depth_m;
        const DepthUnit unit = s->mode().pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM ? DepthUnit::k1mm
                                                                                    : DepthUnit::k100um;
        cv::Mat counts(depth_m.size(), CV_16U);
        for (int v = 0; v < counts.rows; ++v) {
          const float* in = depth_m.ptr<float>(v);
          uint16_t* out = counts.ptr<uint16_t>(v);
          for (int u = 0; u < counts.cols; ++u) out[u] = QuantizeDepth(in[u], unit);
        }
        s->Send(counts, frame_index, timestamp_us, VirtualStream::HalfSize::kEvery2nd);
      }
    }
  }

  // Realtime pace: sends frames at their times while any stream runs. The device's clock starts
  // with the first stream and keeps running while streams are stopped, as a PS1080's does: frames
  // after a restart carry the time since the first start (time_shift_s_), not the source's time.
  // A frame that comes from the source a frame interval or more after its time is sent at once, in
  // the frame slot of the device's clock it falls in: the slots it missed are dropped frames (their
  // numbers and times are skipped), as a sensor drops the frames its host does not take in time,
  // and the clock moves on with them. A source slower than real time thus runs its own time
  // slower, while the device's frames keep to the wall clock.
  void Produce() {
    std::unique_lock<std::mutex> lock(mutex_);
    bool running = false;
    std::optional<SteadyClock::time_point> first_start;
    double first_t_s = 0.0;
    SteadyClock::time_point start;
    double start_t_s = 0.0;
    const double period_s = 1.0 / fps_;
    while (!closing_) {
      if (!AnyStartedLocked() || !CanSendLocked() || !FetchLocked()) {
        running = false;
        if (TakeEndLocked()) ended_callback_(uri_.c_str());  // queued: the driver raises the events
        if (auto* hook = g_before_wait_hook.load()) hook();
        wake_.wait(lock);
        continue;
      }
      const double t_s = pending_->time_s;
      if (!running) {
        // Let every stream the application starts together see the first frame.
        running = true;
        start = SteadyClock::now() + std::chrono::milliseconds(50);
        start_t_s = t_s;
        if (!first_start) {
          first_start = start;
          first_t_s = t_s;
        }
        time_shift_s_ = std::chrono::duration<double>(start - *first_start).count() + first_t_s - start_t_s;
      }
      auto due = start +
                 std::chrono::duration_cast<SteadyClock::duration>(std::chrono::duration<double>(t_s - start_t_s));
      const double late_s = std::chrono::duration<double>(SteadyClock::now() - due).count();
      const int skipped = late_s >= period_s ? static_cast<int>(std::floor(late_s / period_s)) : 0;
      if (skipped > 0) {
        const auto shift = std::chrono::duration_cast<SteadyClock::duration>(
            std::chrono::duration<double>(skipped * period_s));
        start += shift;
        due += shift;
        time_shift_s_ += skipped * period_s;
      }
      if (wake_.wait_until(lock, due, [this] { return closing_; })) break;
      if (SteadyClock::now() < due) continue;
      if (AnyStartedLocked() && CanSendLocked()) SendPendingLocked(skipped);
    }
  }

  std::string uri_;
  VirtualBackendEndedFn ended_callback_;
  VirtualDeviceOptions options_;
  oni::driver::DriverServices* services_;
  UniqueFd lock_;  // the frame directory's exclusive lock while the device is open
  DeviceContent content_;
  ChipParameters chip_;
  bool has_depth_ = false, has_ir_ = false;
  int fps_ = 30;
  std::vector<OniVideoMode> depth_modes_, ir_modes_, color_modes_;
  std::vector<OniSensorInfo> sensors_;

  std::mutex mutex_;
  std::condition_variable wake_;
  std::set<VirtualStream*> streams_;
  std::optional<Frame> pending_;  // fetched from the source, not yet sent
  int sent_ = 0;                  // frame numbers used so far
  double time_shift_s_ = 0.0;     // device time - source time (realtime pace, after a restart)
  bool ended_ = false;            // the source has no more frames
  bool end_reported_ = false;     // the driver was told of the end
  OniImageRegistrationMode registration_ = ONI_IMAGE_REGISTRATION_OFF;
  bool closing_ = false;
  std::thread producer_;
};

OniStatus VirtualStream::start() {
  device_->SetStarted(this, true);
  return ONI_STATUS_OK;
}

void VirtualStream::stop() { device_->SetStarted(this, false); }

// The half-size image of a CV_16U or CV_8UC3 image with even sides.
cv::Mat Halved(const cv::Mat& full, VirtualStream::HalfSize half) {
  if (full.type() == CV_8UC3) {  // colour: 2 x 2 means, channel by channel
    cv::Mat out(full.rows / 2, full.cols / 2, CV_8UC3);
    for (int v = 0; v < out.rows; ++v) {
      const auto* a = full.ptr<cv::Vec3b>(2 * v);
      const auto* b = full.ptr<cv::Vec3b>(2 * v + 1);
      auto* o = out.ptr<cv::Vec3b>(v);
      for (int u = 0; u < out.cols; ++u) {
        for (int c = 0; c < 3; ++c) {
          o[u][c] = static_cast<uint8_t>((a[2 * u][c] + a[2 * u + 1][c] + b[2 * u][c] + b[2 * u + 1][c] + 2) / 4);
        }
      }
    }
    return out;
  }
  cv::Mat out(full.rows / 2, full.cols / 2, CV_16U);
  for (int v = 0; v < out.rows; ++v) {
    const uint16_t* a = full.ptr<uint16_t>(2 * v);
    const uint16_t* b = full.ptr<uint16_t>(2 * v + 1);
    uint16_t* o = out.ptr<uint16_t>(v);
    for (int u = 0; u < out.cols; ++u) {
      o[u] = half == VirtualStream::HalfSize::kEvery2nd
                 ? a[2 * u]
                 : static_cast<uint16_t>((a[2 * u] + a[2 * u + 1] + b[2 * u] + b[2 * u + 1] + 2) / 4);
    }
  }
  return out;
}

// BT.601 full-range YUV 4:2:2 of an RGB row pair of pixels, in the byte order of `format`
// (YUV422: U Y0 V Y1, as OpenNI2's UYVY; YUYV: Y0 U Y1 V).
void PackYuv(const cv::Vec3b& p0, const cv::Vec3b& p1, OniPixelFormat format, uint8_t* out) {
  auto luma = [](const cv::Vec3b& p) { return 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]; };
  auto byte = [](double x) { return static_cast<uint8_t>(std::clamp(std::lround(x), 0L, 255L)); };
  const double y0 = luma(p0), y1 = luma(p1);
  const double r = 0.5 * (p0[0] + p1[0]), b = 0.5 * (p0[2] + p1[2]), y = 0.5 * (y0 + y1);
  const uint8_t u = byte(128.0 + 0.564 * (b - y)), v = byte(128.0 + 0.713 * (r - y));
  if (format == ONI_PIXEL_FORMAT_YUV422) {
    out[0] = u, out[1] = byte(y0), out[2] = v, out[3] = byte(y1);
  } else {
    out[0] = byte(y0), out[1] = u, out[2] = byte(y1), out[3] = v;
  }
}

void VirtualStream::Send(const cv::Mat& full, int frame_index, uint64_t timestamp_us, HalfSize half) {
  if (full.empty()) return;
  const bool halve = full.cols == 2 * mode_.resolutionX && full.rows == 2 * mode_.resolutionY;
  const cv::Mat image = halve ? Halved(full, half) : full;
  if (image.cols != mode_.resolutionX || image.rows != mode_.resolutionY) return;
  OniFrame* frame = getServices().acquireFrame();
  if (frame == nullptr) return;
  const bool cropped = crop_.enabled;
  const int x0 = cropped ? crop_.originX : 0, y0 = cropped ? crop_.originY : 0;
  const int w = cropped ? crop_.width : mode_.resolutionX, h = cropped ? crop_.height : mode_.resolutionY;
  const int row_bytes = w * BytesPerPixel(mode_.pixelFormat);
  const size_t in_bytes = image.elemSize();
  // The mirrored, cropped image's pixels in the source's own layout, row by row.
  std::vector<uint8_t> row(static_cast<size_t>(w) * in_bytes);
  frame->dataSize = row_bytes * h;
  for (int v = 0; v < h; ++v) {
    const uint8_t* in = image.ptr<uint8_t>(y0 + v);
    for (int u = 0; u < w; ++u) {
      const int x = mirror_ ? image.cols - 1 - (x0 + u) : x0 + u;
      std::memcpy(row.data() + u * in_bytes, in + x * in_bytes, in_bytes);
    }
    uint8_t* out = static_cast<uint8_t*>(frame->data) + static_cast<size_t>(v) * row_bytes;
    if (IsYuv(mode_.pixelFormat)) {
      const auto* rgb = reinterpret_cast<const cv::Vec3b*>(row.data());
      for (int u = 0; u + 1 < w; u += 2) PackYuv(rgb[u], rgb[u + 1], mode_.pixelFormat, out + 2 * u);
    } else {
      std::memcpy(out, row.data(), row_bytes);
    }
  }
  frame->sensorType = type_;
  frame->timestamp = timestamp_us;
  frame->frameIndex = frame_index;
  frame->width = w;
  frame->height = h;
  frame->videoMode = mode_;
  frame->croppingEnabled = cropped ? TRUE : FALSE;
  frame->cropOriginX = x0;
  frame->cropOriginY = y0;
  frame->stride = row_bytes;
  raiseNewFrame(frame);
  getServices().releaseFrame(frame);
}

// Where a depth pixel of this stream's mode lands in the colour stream's image (its mode's size),
// from the depth and colour cameras (the image registration's own geometry).
OniStatus VirtualStream::convertDepthToColorCoordinates(StreamBase* color_stream, int depth_x, int depth_y,
                                                        OniDepthPixel depth_z, int* color_x, int* color_y) {
  const auto* color = static_cast<VirtualStream*>(color_stream);
  const std::optional<ColorCamera>& camera = device_->color_camera();
  if (type_ != ONI_SENSOR_DEPTH || color == nullptr || color->type() != ONI_SENSOR_COLOR || !camera ||
      mode_.pixelFormat == ONI_PIXEL_FORMAT_SHIFT_9_2 || depth_z == 0) {
    return ONI_STATUS_BAD_PARAMETER;
  }
  const CameraModel& depth_camera = device_->camera();
  const double sx = static_cast<double>(depth_camera.width) / mode_.resolutionX;
  const double sy = static_cast<double>(depth_camera.height) / mode_.resolutionY;
  const Eigen::Vector2d u_px((depth_x + 0.5) * sx - 0.5, (depth_y + 0.5) * sy - 0.5);
  const double unit_m = mode_.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM ? 1e-3 : 1e-4;
  const auto c = DepthPixelToColor(u_px, depth_z * unit_m, depth_camera, *camera);
  if (!c) return ONI_STATUS_BAD_PARAMETER;
  const double cx = static_cast<double>(color->mode().resolutionX) / camera->camera.width;
  const double cy = static_cast<double>(color->mode().resolutionY) / camera->camera.height;
  *color_x = static_cast<int>(std::lround((c->x() + 0.5) * cx - 0.5));
  *color_y = static_cast<int>(std::lround((c->y() + 0.5) * cy - 0.5));
  return ONI_STATUS_OK;
}

OniStatus VirtualStream::setProperty(int id, const void* data, int size) {
  switch (id) {
    case ONI_STREAM_PROPERTY_VIDEO_MODE: {
      if (size != sizeof(OniVideoMode)) return ONI_STATUS_BAD_PARAMETER;
      const OniVideoMode& mode = *static_cast<const OniVideoMode*>(data);
      if (!device_->IsOffered(type_, mode)) return ONI_STATUS_NOT_SUPPORTED;
      std::lock_guard<std::mutex> lock(device_->mutex());
      mode_ = mode;
      crop_.enabled = FALSE;  // a crop is of the old mode's image
      return ONI_STATUS_OK;
    }
    case ONI_STREAM_PROPERTY_MIRRORING: {
      if (size != sizeof(OniBool)) return ONI_STATUS_BAD_PARAMETER;
      std::lock_guard<std::mutex> lock(device_->mutex());
      mirror_ = *static_cast<const OniBool*>(data) != FALSE;
      return ONI_STATUS_OK;
    }
    case ONI_STREAM_PROPERTY_CROPPING: {
      if (size != sizeof(OniCropping)) return ONI_STATUS_BAD_PARAMETER;
      const OniCropping& c = *static_cast<const OniCropping*>(data);
      std::lock_guard<std::mutex> lock(device_->mutex());
      if (c.enabled && !(c.originX >= 0 && c.originY >= 0 && c.width > 0 && c.height > 0 &&
                         c.originX + c.width <= mode_.resolutionX && c.originY + c.height <= mode_.resolutionY)) {
        return ONI_STATUS_BAD_PARAMETER;  // not inside the mode's image
      }
      if (c.enabled && IsYuv(mode_.pixelFormat) && (c.originX % 2 != 0 || c.width % 2 != 0)) {
        return ONI_STATUS_BAD_PARAMETER;  // 4:2:2 pairs pixels
      }
      crop_ = c;
      crop_.enabled = c.enabled ? TRUE : FALSE;
      return ONI_STATUS_OK;
    }
    default: return ONI_STATUS_NOT_SUPPORTED;
  }
}

OniStatus VirtualStream::getProperty(int id, void* data, int* size) {
  const bool color = type_ == ONI_SENSOR_COLOR;
  const CameraModel& c = color ? device_->color_camera()->camera : device_->camera();
  const ChipParameters& chip = device_->chip();
  const bool depth = type_ == ONI_SENSOR_DEPTH;
  switch (id) {
    case ONI_STREAM_PROPERTY_VIDEO_MODE: return Answer(mode_, data, size);
    case ONI_STREAM_PROPERTY_CROPPING:
      return Answer(crop_.enabled ? crop_ : OniCropping{FALSE, 0, 0, mode_.resolutionX, mode_.resolutionY}, data, size);
    case ONI_STREAM_PROPERTY_HORIZONTAL_FOV:
      return Answer(static_cast<float>(2.0 * std::atan(c.width / (2.0 * c.fx))), data, size);
    case ONI_STREAM_PROPERTY_VERTICAL_FOV:
      return Answer(static_cast<float>(2.0 * std::atan(c.height / (2.0 * c.fy))), data, size);
    case ONI_STREAM_PROPERTY_MAX_VALUE:
      if (color) return Answer(255, data, size);
      if (depth && mode_.pixelFormat == ONI_PIXEL_FORMAT_SHIFT_9_2)
        return Answer(static_cast<int>(kRawInvalid), data, size);
      return Answer(depth ? (mode_.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM ? 10000 : 65535) : 1023, data, size);
    case ONI_STREAM_PROPERTY_MIN_VALUE: return Answer(0, data, size);
    case ONI_STREAM_PROPERTY_STRIDE: return Answer(mode_.resolutionX * BytesPerPixel(mode_.pixelFormat), data, size);
    case ONI_STREAM_PROPERTY_MIRRORING: return Answer(OniBool{mirror_ ? TRUE : FALSE}, data, size);
    case ONI_STREAM_PROPERTY_NUMBER_OF_FRAMES:
      if (device_->total_frames() == 0) return ONI_STATUS_NOT_SUPPORTED;
      return Answer(device_->total_frames(), data, size);
    default: break;
  }
  if (!depth) return ONI_STATUS_NOT_SUPPORTED;
  switch (id) {
    case XN_STREAM_PROPERTY_ZERO_PLANE_DISTANCE: return Answer(chip.zero_plane_distance_mm, data, size);
    case XN_STREAM_PROPERTY_ZERO_PLANE_PIXEL_SIZE: return Answer(chip.zero_plane_pixel_size_mm, data, size);
    case XN_STREAM_PROPERTY_EMITTER_DCMOS_DISTANCE: return Answer(chip.emitter_dcmos_distance_cm, data, size);
    case XN_STREAM_PROPERTY_DCMOS_RCMOS_DISTANCE: {
      // The colour camera's own offset, when the frames come with one.
      const std::optional<ColorCamera>& rgb = device_->color_camera();
      return Answer(rgb ? 100.0 * rgb->T_C_RGB.translation().norm() : chip.dcmos_rcmos_distance_cm, data, size);
    }
    case XN_STREAM_PROPERTY_CONST_SHIFT: return Answer(chip.const_shift, data, size);
    case XN_STREAM_PROPERTY_PARAM_COEFF: return Answer(chip.param_coeff, data, size);
    case XN_STREAM_PROPERTY_SHIFT_SCALE: return Answer(chip.shift_scale, data, size);
    case XN_STREAM_PROPERTY_MAX_SHIFT: return Answer(chip.max_shift, data, size);
    case XN_STREAM_PROPERTY_PIXEL_SIZE_FACTOR: return Answer(chip.pixel_size_factor, data, size);
    default: return ONI_STATUS_NOT_SUPPORTED;
  }
}

OniBool VirtualStream::isPropertySupported(int id) {
  switch (id) {
    case ONI_STREAM_PROPERTY_VIDEO_MODE:
    case ONI_STREAM_PROPERTY_CROPPING:
    case ONI_STREAM_PROPERTY_HORIZONTAL_FOV:
    case ONI_STREAM_PROPERTY_VERTICAL_FOV:
    case ONI_STREAM_PROPERTY_MAX_VALUE:
    case ONI_STREAM_PROPERTY_MIN_VALUE:
    case ONI_STREAM_PROPERTY_STRIDE:
    case ONI_STREAM_PROPERTY_MIRRORING: return TRUE;
    case ONI_STREAM_PROPERTY_NUMBER_OF_FRAMES: return device_->total_frames() > 0;
    case XN_STREAM_PROPERTY_ZERO_PLANE_DISTANCE:
    case XN_STREAM_PROPERTY_ZERO_PLANE_PIXEL_SIZE:
    case XN_STREAM_PROPERTY_EMITTER_DCMOS_DISTANCE:
    case XN_STREAM_PROPERTY_DCMOS_RCMOS_DISTANCE:
    case XN_STREAM_PROPERTY_CONST_SHIFT:
    case XN_STREAM_PROPERTY_PARAM_COEFF:
    case XN_STREAM_PROPERTY_SHIFT_SCALE:
    case XN_STREAM_PROPERTY_MAX_SHIFT:
    case XN_STREAM_PROPERTY_PIXEL_SIZE_FACTOR: return type_ == ONI_SENSOR_DEPTH;
    default: return FALSE;
  }
}

// Raised when a recorder attaches, so .oni files carry the mode, fields of view and chip geometry
// (a stream without CROPPING records but plays back no frames).
void VirtualStream::notifyAllProperties() {
  static const int kIds[] = {ONI_STREAM_PROPERTY_VIDEO_MODE,
                             ONI_STREAM_PROPERTY_CROPPING,
                             ONI_STREAM_PROPERTY_HORIZONTAL_FOV,
                             ONI_STREAM_PROPERTY_VERTICAL_FOV,
                             ONI_STREAM_PROPERTY_MAX_VALUE,
                             ONI_STREAM_PROPERTY_STRIDE,
                             ONI_STREAM_PROPERTY_MIRRORING,
                             XN_STREAM_PROPERTY_ZERO_PLANE_DISTANCE,
                             XN_STREAM_PROPERTY_ZERO_PLANE_PIXEL_SIZE,
                             XN_STREAM_PROPERTY_EMITTER_DCMOS_DISTANCE,
                             XN_STREAM_PROPERTY_DCMOS_RCMOS_DISTANCE,
                             XN_STREAM_PROPERTY_CONST_SHIFT,
                             XN_STREAM_PROPERTY_PARAM_COEFF,
                             XN_STREAM_PROPERTY_SHIFT_SCALE,
                             XN_STREAM_PROPERTY_MAX_SHIFT,
                             XN_STREAM_PROPERTY_PIXEL_SIZE_FACTOR};
  for (int id : kIds) {
    if (!isPropertySupported(id)) continue;
    alignas(8) unsigned char buffer[sizeof(OniVideoMode) + sizeof(OniCropping)];
    int size = 0;
    switch (id) {
      case ONI_STREAM_PROPERTY_VIDEO_MODE: size = sizeof(OniVideoMode); break;
      case ONI_STREAM_PROPERTY_CROPPING: size = sizeof(OniCropping); break;
      case ONI_STREAM_PROPERTY_HORIZONTAL_FOV:
      case ONI_STREAM_PROPERTY_VERTICAL_FOV: size = sizeof(float); break;
      case ONI_STREAM_PROPERTY_MAX_VALUE:
      case ONI_STREAM_PROPERTY_STRIDE: size = sizeof(int); break;
      case ONI_STREAM_PROPERTY_MIRRORING: size = sizeof(OniBool); break;
      case XN_STREAM_PROPERTY_ZERO_PLANE_PIXEL_SIZE:
      case XN_STREAM_PROPERTY_EMITTER_DCMOS_DISTANCE:
      case XN_STREAM_PROPERTY_DCMOS_RCMOS_DISTANCE: size = sizeof(double); break;
      default: size = sizeof(uint64_t); break;
    }
    if (getProperty(id, buffer, &size) == ONI_STATUS_OK) raisePropertyChanged(id, buffer, size);
  }
}

}  // namespace
}  // namespace romunect::openni2

extern "C" __attribute__((visibility("default"))) oni::driver::DeviceBase* romunect_virtual_backend_open(
    const char* uri, oni::driver::DriverServices* services, romunect::openni2::VirtualBackendEndedFn ended, char* error,
    int error_size) {
  std::string problem;
  const auto parsed = romunect::openni2::ParseVirtualDeviceUri(uri, &problem);
  try {
    if (parsed) return new romunect::openni2::VirtualDevice(uri, *parsed, services, ended);
  } catch (const std::exception& e) {
    problem = e.what();
  }
  std::snprintf(error, static_cast<size_t>(error_size), "%s", problem.c_str());
  return nullptr;
}

extern "C" __attribute__((visibility("default"))) void romunect_virtual_backend_set_wait_hook(void (*hook)()) {
  romunect::openni2::g_before_wait_hook.store(hook);
}
