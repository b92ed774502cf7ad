#include "romunect/sensor/openni2/openni2_source.h"

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

#include <OpenNI.h>
#include <PS1080.h>

#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/openni2/oni_file.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "oni_trial_read.h"
#include "virtual_device_uri.h"

namespace romunect::openni2 {
namespace {

// OpenNI2's recorder starts on its own thread: frames sent before that are not recorded. Nothing
// reports when it has started, so the streams start only after this pause (docs/hardware.md).
constexpr std::chrono::milliseconds kRecorderStartPause{300};

// How long a recording's player thread is given to settle before its device closes, counted
// from the open and from the last wait for a frame (OpenNI2Source::Impl::~Impl says why).
constexpr std::chrono::milliseconds kPlayerSettlePause{50};

// A recording plays each frame on demand from a local file within milliseconds: without a frame
// count, a wait this long for the next one means its frames have run out.
constexpr double kUnfinishedRecordingEndWaitS = 1.0;

void EnsureOpenNI() {
  static std::mutex mutex;
  static bool initialized = false;
  std::lock_guard<std::mutex> lock(mutex);
  if (initialized) return;
  // The driver reads this while libOpenNI2 has moved to another working directory: a relative
  // directory is resolved here, where it still means what the user meant.
  if (const char* env = std::getenv(kVirtualDeviceEnv); env != nullptr) {
    const std::string absolute = AbsoluteVirtualDeviceUri(env);
    if (absolute != env) setenv(kVirtualDeviceEnv, absolute.c_str(), 1);
  }
  if (openni::OpenNI::initialize() != openni::STATUS_OK) {
    throw InputError("OpenNI2", "initialize", std::string("cannot start: ") + openni::OpenNI::getExtendedError());
  }
  initialized = true;  // never shut down: drivers and their threads live as long as the process
}

// The streams of closed recordings (OpenNI2Source::Impl::~Impl): never destroyed, and reachable
// from here so that leak checkers do not count them.
void KeepForever(std::unique_ptr<openni::VideoStream> stream) {
  static std::mutex mutex;
  static auto* const kept = new std::vector<std::unique_ptr<openni::VideoStream>>();
  std::lock_guard<std::mutex> lock(mutex);
  kept->push_back(std::move(stream));
}

std::string ExtendedError() {
  std::string e = openni::OpenNI::getExtendedError();
  while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
  for (char& c : e) {
    if (c == '\n') c = ';';
  }
  return e.empty() ? "no detail from OpenNI2" : e;
}

const char* FormatName(openni::PixelFormat f) {
  switch (f) {
    case openni::PIXEL_FORMAT_DEPTH_1_MM: return "1mm";
    case openni::PIXEL_FORMAT_DEPTH_100_UM: return "100um";
    case openni::PIXEL_FORMAT_SHIFT_9_2: return "shift9.2";
    case openni::PIXEL_FORMAT_SHIFT_9_3: return "shift9.3";
    case openni::PIXEL_FORMAT_RGB888: return "rgb888";
    case openni::PIXEL_FORMAT_YUV422: return "yuv422";
    case openni::PIXEL_FORMAT_GRAY8: return "gray8";
    case openni::PIXEL_FORMAT_GRAY16: return "gray16";
    case openni::PIXEL_FORMAT_JPEG: return "jpeg";
    case openni::PIXEL_FORMAT_YUYV: return "yuyv";
    default: return "unknown";
  }
}

const char* SensorName(openni::SensorType t) {
  switch (t) {
    case openni::SENSOR_DEPTH: return "depth";
    case openni::SENSOR_IR: return "ir";
    case openni::SENSOR_COLOR: return "color";
    default: return "unknown";
  }
}

std::string ModeString(openni::SensorType t, const openni::VideoMode& m) {
  std::ostringstream s;
  s << SensorName(t) << ' ' << m.getResolutionX() << 'x' << m.getResolutionY() << " @" << m.getFps() << " Hz "
    << FormatName(m.getPixelFormat());
  return s.str();
}

std::string ModesOf(openni::Device& device, openni::SensorType t) {
  const openni::SensorInfo* info = device.getSensorInfo(t);
  if (info == nullptr) return "none";
  std::string out;
  const auto& modes = info->getSupportedVideoModes();
  for (int i = 0; i < modes.getSize(); ++i) out += (i ? ", " : "") + ModeString(t, modes[i]);
  return out.empty() ? "none" : out;
}

std::string DeviceListText() {
  openni::Array<openni::DeviceInfo> list;
  openni::OpenNI::enumerateDevices(&list);
  std::string out;
  for (int i = 0; i < list.getSize(); ++i) out += std::string(i ? ", " : "") + list[i].getUri();
  return out.empty() ? "none" : out;
}

bool IsDepthFormat(openni::PixelFormat f) {
  return f == openni::PIXEL_FORMAT_DEPTH_1_MM || f == openni::PIXEL_FORMAT_DEPTH_100_UM;
}

// Why the virtual device's driver refused the last open ("" if unknown): OpenNI2 does not
// pass driver messages on, so ask the loaded driver itself.
std::string VirtualDeviceOpenError() {
  const std::string path = (DriverDirectory() / kVirtualDriverFile).string();
  void* driver = dlopen(path.c_str(), RTLD_NOW | RTLD_NOLOAD);
  if (driver == nullptr) return "";
  using LastError = void (*)(char*, int);
  auto last_error = reinterpret_cast<LastError>(dlsym(driver, kVirtualDeviceLastErrorSymbol));
  char message[1024] = "";
  if (last_error != nullptr) last_error(message, sizeof(message));
  dlclose(driver);  // balances the NOLOAD open; OpenNI2 keeps its own reference
  return message;
}

template <typename T>
std::optional<T> ReadProperty(const openni::VideoStream& stream, int id) {
  // Ask directly: the file driver answers recorded PS1080 properties without listing them.
  T value{};
  int size = sizeof(T);
  if (stream.getProperty(id, &value, &size) != openni::STATUS_OK || size != static_cast<int>(sizeof(T))) {
    return std::nullopt;
  }
  return value;
}

}  // namespace

std::string OpenNI2SourceOptions::Problem() const {
  auto bad = [](const std::string& field, const std::string& value, const std::string& rule) {
    return field + " = " + value + ": " + rule;
  };
  if (width < 0 || height < 0 || fps < 0)
    return bad("width/height/fps", std::to_string(width) + "/" + std::to_string(height) + "/" + std::to_string(fps),
               "must be >= 0 (0 = default)");
  if ((width == 0) != (height == 0))
    return bad("width/height", std::to_string(width) + "/" + std::to_string(height), "give both or neither");
  if (!depth && !ir) return bad("depth/ir", "false/false", "at least one stream must be opened");
  if (raw && !depth) return bad("raw", "true", "reads the depth stream: needs depth = true");
  if (!(timeout_s > 0.0 && timeout_s <= 3600.0))
    return bad("timeout_s", std::to_string(timeout_s), "must be in (0, 3600]");
  if (max_frames < 0) return bad("max_frames", std::to_string(max_frames), "must be >= 0 (0 = no limit)");
  if (camera) {
    const std::string p = camera->Problem();
    if (!p.empty()) return bad("camera", "(model)", p);
  }
  return "";
}

std::string PS1080Properties::Describe() const {
  std::ostringstream s;
  s.precision(6);
  auto m = [&s](const char* name, const std::optional<double>& v, double scale, const char* unit) {
    s << name << ' ';
    if (v) s << *v * scale << ' ' << unit;
    else s << "n/a";
  };
  m("zero plane", zero_plane_distance_m, 1e3, "mm");
  s << ", ";
  m("zero-plane pixel", zero_plane_pixel_size_m, 1e3, "mm");
  s << ", ";
  m("emitter-camera", emitter_camera_distance_m, 1e3, "mm");
  return s.str();
}

struct OpenNI2Source::Impl {
  OpenNI2SourceOptions options;
  std::string name;  // the URI as shown in messages
  openni::Device device;
  // On the heap: a recording's streams outlive the source (~Impl says why).
  std::unique_ptr<openni::VideoStream> depth_stream = std::make_unique<openni::VideoStream>();
  std::unique_ptr<openni::VideoStream> ir_stream = std::make_unique<openni::VideoStream>();
  openni::VideoStream& depth = *depth_stream;
  openni::VideoStream& ir = *ir_stream;
  openni::Recorder recorder;
  bool file = false, step = false;
  CameraModel camera;
  PS1080Properties chip;
  DepthUnit unit = DepthUnit::k100um;
  openni::VideoMode mode;
  int total_frames = 0;  // frames the stream will send; 0 = unknown (live device)
  // A recording whose recorder was killed: no frame count, so it plays until its frames run out.
  bool unfinished_recording = false;
  bool ended = false;  // an unfinished recording's frames have run out
  int primary_read = 0;
  int first_index = -1, last_index = 0;
  uint64_t first_timestamp_us = 0;
  openni::VideoFrameRef pending_ir;
  OpenNI2SourceStats stats;
  SteadyClock::time_point player_settled;  // recordings: no close before this

  void FinishRecording() {
    if (recorder.isValid()) {
      recorder.stop();
      recorder.destroy();  // waits for the recorder thread to write what it queued
    }
  }

  // Also runs when the constructor throws, so every opened device is taken down in this order.
  ~Impl() {
    FinishRecording();
    pending_ir.release();
    if (file && device.isValid()) {
      // A recording's device closes before its streams, after a pause, and the streams are never
      // destroyed. Why, in OpenNI2 2.2.0.33 as Debian ships it:
      // - The file driver's player thread (libOniFile, PlayerDevice::MainLoop) walks the device's
      //   list of streams without a lock: nonstop at the end of the file, every 10 ms while no
      //   stream runs. Destroying a stream frees its entry under that thread, which then crashed
      //   in about 1 run in 50 on a loaded machine. Device::close joins the thread first.
      // - Device::close also deletes libOpenNI2's per-sensor objects, and destroying a stream
      //   after that still unregisters it from its sensor's object (upstream later guarded
      //   this): a use after free. So the closed device's streams are kept, stopped, for the life
      //   of the process (KeepForever): about 20 kB and one idle libOpenNI2 thread per stream.
      // - Device::close deletes those objects before it joins the thread, which still uses them
      //   for a moment after it has handed a frame over (it wakes our wait first); and a thread
      //   that has not started yet when its device closes runs on until the driver gives up on it
      //   after 3 s. Neither offers anything to wait on, hence kPlayerSettlePause after the open
      //   and after the last wait for a frame. The streams stop first: the thread then takes no
      //   new frame for them.
      StopPlayback();
      std::this_thread::sleep_until(player_settled);
      device.close();
      if (depth.isValid()) KeepForever(std::move(depth_stream));
      if (ir.isValid()) KeepForever(std::move(ir_stream));
      return;
    }
    // Live and virtual devices keep OpenNI2's usual order, streams first (our virtual device's
    // driver guards its streams with its device mutex).
    for (openni::VideoStream* stream : {&depth, &ir}) {
      if (stream->isValid()) {
        stream->stop();
        stream->destroy();
      }
    }
    if (device.isValid()) device.close();
  }

  openni::VideoStream& primary() { return options.depth ? depth : ir; }

  // At a recording's end: the player thread (PlayerDevice::MainLoop) reads on at the end of the
  // file without a pause while any stream runs, a core kept busy until the source goes; with
  // every stream stopped it sleeps 10 ms a turn. A recording's teardown (~Impl) starts with it.
  void StopPlayback() {
    if (!file) return;
    for (openni::VideoStream* stream : {&depth, &ir}) {
      if (stream->isValid()) stream->stop();
    }
  }

  // Waits for a frame of `stream`. False (nothing read) at the end of a recording without a
  // frame count; throws InputError when a device stalls or OpenNI2 fails.
  bool Read(openni::VideoStream& stream, const char* what, openni::VideoFrameRef* ref) {
    openni::VideoStream* streams[] = {&stream};
    int ready = -1;
    const double wait_s = unfinished_recording ? std::min(options.timeout_s, kUnfinishedRecordingEndWaitS)
                                               : options.timeout_s;
    const int timeout_ms = static_cast<int>(std::ceil(wait_s * 1000.0));
    const openni::Status waited = openni::OpenNI::waitForAnyStream(streams, 1, &ready, timeout_ms);
    player_settled = SteadyClock::now() + kPlayerSettlePause;
    if (waited != openni::STATUS_OK && unfinished_recording) {
      if (stats.frames == 0) throw InputError(name, "", "not a readable .oni recording: its streams hold no frames");
      return false;
    }
    if (waited != openni::STATUS_OK) {
      std::ostringstream s;
      s << "no frame for " << options.timeout_s << " s (device unplugged or stalled); " << stats.frames
        << " frames were delivered before"
        << (stats.frames > 0 ? ", the last at index " + std::to_string(last_index - first_index) : std::string());
      throw InputError(name, std::string(what) + " stream", s.str());
    }
    if (stream.readFrame(ref) != openni::STATUS_OK) {
      throw InputError(name, std::string(what) + " stream", "reading a frame failed: " + ExtendedError());
    }
    return true;
  }

  void SetUp(openni::VideoStream& stream, openni::SensorType type, const char* what) {
    if (!device.hasSensor(type)) {
      throw InputError(name, std::string(what) + " stream",
                       file ? "the recording has no " + std::string(what) + " stream"
                            : "the device has no " + std::string(what) + " sensor");
    }
    if (stream.create(device, type) != openni::STATUS_OK) {
      throw InputError(name, std::string(what) + " stream", "cannot create it: " + ExtendedError());
    }
  }

  // The mode to ask for: the options' size and rate (or 640 x 480 @ 30 when offered, else the
  // largest offered in the wanted formats, else the current one) and, for depth, the unit.
  openni::VideoMode ChooseMode(openni::VideoStream& stream, openni::SensorType type, int w, int h, int fps) {
    const auto& modes = stream.getSensorInfo().getSupportedVideoModes();
    const openni::VideoMode current = stream.getVideoMode();
    auto offered = [&](int mw, int mh, int mfps, openni::PixelFormat f) {
      for (int i = 0; i < modes.getSize(); ++i) {
        if (modes[i].getResolutionX() == mw && modes[i].getResolutionY() == mh &&
            (mfps == 0 || modes[i].getFps() == mfps) && modes[i].getPixelFormat() == f) {
          return std::optional<openni::VideoMode>(modes[i]);
        }
      }
      return std::optional<openni::VideoMode>();
    };
    std::vector<openni::PixelFormat> formats;
    if (type == openni::SENSOR_IR) {
      formats = {openni::PIXEL_FORMAT_GRAY16};
    } else if (options.raw) {
      formats = {openni::PIXEL_FORMAT_SHIFT_9_2};
    } else if (options.depth_unit) {
      formats = {*options.depth_unit == DepthUnit::k100um ? openni::PIXEL_FORMAT_DEPTH_100_UM
                                                          : openni::PIXEL_FORMAT_DEPTH_1_MM};
    } else {
      formats = {openni::PIXEL_FORMAT_DEPTH_100_UM, openni::PIXEL_FORMAT_DEPTH_1_MM};
    }
    std::vector<std::array<int, 3>> sizes;
    if (w > 0) {
      sizes.push_back({w, h, fps});
    } else {
      sizes.push_back({640, 480, fps > 0 ? fps : 30});
      int largest = -1;
      for (int i = 0; i < modes.getSize(); ++i) {
        const bool wanted = std::find(formats.begin(), formats.end(), modes[i].getPixelFormat()) != formats.end();
        const int pixels = modes[i].getResolutionX() * modes[i].getResolutionY();
        if (wanted && (fps == 0 || modes[i].getFps() == fps) &&
            (largest < 0 || pixels > modes[largest].getResolutionX() * modes[largest].getResolutionY())) {
          largest = i;
        }
      }
      if (largest >= 0)
        sizes.push_back({modes[largest].getResolutionX(), modes[largest].getResolutionY(), modes[largest].getFps()});
      sizes.push_back({current.getResolutionX(), current.getResolutionY(), fps > 0 ? fps : current.getFps()});
    }
    for (const auto& size : sizes) {
      for (openni::PixelFormat f : formats) {
        if (auto m = offered(size[0], size[1], size[2], f)) return *m;
      }
    }
    std::ostringstream want;
    want << SensorName(type) << ' ';
    if (w > 0) want << w << 'x' << h;
    else want << "640x480 or the current size";
    if (fps > 0 || w == 0) want << " @" << (fps > 0 ? fps : 30) << " Hz";
    want << " in ";
    for (size_t i = 0; i < formats.size(); ++i) want << (i ? " or " : "") << FormatName(formats[i]);
    throw InputError(name, "video mode", want.str() + " is not offered; the device offers: " + ModesOf(device, type));
  }

  // The constructor's steps, in order (after the streams are created with SetUp).
  void OpenDevice();         // opens the URI; playback on demand for recordings
  void SelectPrimaryMode();  // the primary stream's mode: chosen, or a recording's own
  void CheckDepthFormat();   // raw shifts or a depth unit, as asked; sets unit
  void MatchIrMode();        // IR in depth's size, in gray16
  void MakeCamera();
  void ReadChip();       // the PS1080 geometry the depth stream answers
  void ReadLength();     // total_frames of recordings and finite devices
  void StartRecorder();  // when record_oni is set
  void StartStreams();
};

namespace {

bool IsOniPath(const std::string& uri) { return uri.size() > 4 && uri.compare(uri.size() - 4, 4, ".oni") == 0; }

// How long a trial read of a recording may take: its decoding runs at well over 50 MB/s.
double TrialReadLimitS(const std::string& path) {
  std::error_code ec;
  const auto bytes = std::filesystem::file_size(path, ec);
  return 60.0 + (ec ? 0.0 : static_cast<double>(bytes) / 5e6);
}

// True in the trial-read program: the reads it runs are the trial, and skip their own.
bool g_in_trial_read = false;

// The trial read's arguments (oni_file.h): "read", then the options a read of a recording
// depends on, in this order; or "modes" and the recording, for ListVideoModes.
std::vector<std::string> TrialReadArguments(const OpenNI2SourceOptions& o) {
  std::ostringstream timeout;
  timeout.precision(17);
  timeout << o.timeout_s;
  const char* unit = !o.depth_unit ? "auto" : *o.depth_unit == DepthUnit::k100um ? "100um" : "1mm";
  return {"read", o.uri, o.raw ? "1" : "0", o.depth ? "1" : "0", o.ir ? "1" : "0", std::to_string(o.width),
          std::to_string(o.height), std::to_string(o.fps), unit, std::to_string(o.max_frames), timeout.str()};
}

std::optional<OpenNI2SourceOptions> ParseTrialReadArguments(const std::vector<std::string>& a) {
  if (a.size() != 11 || a[0] != "read") return std::nullopt;
  OpenNI2SourceOptions o;
  o.uri = a[1];
  auto flag = [](const std::string& v, bool* out) {
    *out = v == "1";
    return v == "0" || v == "1";
  };
  auto integer = [](const std::string& v, int* out) {
    const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), *out);
    return ec == std::errc() && end == v.data() + v.size();
  };
  if (!flag(a[2], &o.raw) || !flag(a[3], &o.depth) || !flag(a[4], &o.ir) || !integer(a[5], &o.width) ||
      !integer(a[6], &o.height) || !integer(a[7], &o.fps) || !integer(a[9], &o.max_frames)) {
    return std::nullopt;
  }
  if (a[8] == "100um") {
    o.depth_unit = DepthUnit::k100um;
  } else if (a[8] == "1mm") {
    o.depth_unit = DepthUnit::k1mm;
  } else if (a[8] != "auto") {
    return std::nullopt;
  }
  char* end = nullptr;
  o.timeout_s = std::strtod(a[10].c_str(), &end);
  if (a[10].empty() || *end != '\0') return std::nullopt;
  return o;
}

// What can be said about the options and the URI before OpenNI2 is asked: OpenNI2 itself only
// reports "not found"; a recording is checked before libOpenNI2 reads it (oni_file.h).
void CheckBeforeOpening(const OpenNI2SourceOptions& options) {
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("OpenNI2 source options", "", problem);
  if (IsOniPath(options.uri)) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(options.uri, ec)) throw InputError(options.uri, "", "no such .oni file");
    if (!g_in_trial_read) {
      CheckOniStructure(options.uri);
      TrialReadOni(options.uri, TrialReadArguments(options), TrialReadLimitS(options.uri));
    }
  }
  if (IsVirtualDeviceUri(options.uri)) {
    std::string why;
    const auto parsed = ParseVirtualDeviceUri(options.uri, &why);
    if (!parsed) throw InputError(options.uri, "", "not a valid virtual-device URI: " + why);
    std::error_code ec;
    if (!parsed->feed && !std::filesystem::is_regular_file(parsed->dir / "frames.json", ec)) {
      throw InputError(options.uri, "",
                       "no OpenNI2 device opens with this URI: " + parsed->dir.string() +
                           " is not a frame directory (no frames.json)");
    }
  }
}

}  // namespace

void OpenNI2Source::Impl::OpenDevice() {
  const std::string& uri = options.uri;
  if (device.open(uri.empty() ? openni::ANY_DEVICE : uri.c_str()) != openni::STATUS_OK) {
    if (IsOniPath(uri)) throw InputError(name, "", "not a readable .oni recording: " + ExtendedError());
    if (uri.empty()) {
      const std::string why = VirtualDeviceOpenError();  // ROMUNECT_VIRTUAL_DEVICE's problem, if any
      throw InputError("OpenNI2", "",
                       "no device found (" + (why.empty() ? ExtendedError() : why) +
                           "); is the sensor plugged in and its driver in " + DriverDirectory().string() + "?");
    }
    if (IsVirtualDeviceUri(uri)) {
      const std::string why = VirtualDeviceOpenError();
      if (!why.empty()) throw InputError(name, "", "the virtual device cannot open: " + why);
    }
    throw InputError(name, "",
                     "no OpenNI2 device opens with this URI (" + ExtendedError() +
                         "); devices found: " + DeviceListText());
  }
  file = device.isFile();
  if (file) {
    player_settled = SteadyClock::now() + kPlayerSettlePause;
    // Speed -1: the file driver sends each frame on demand, so none is skipped; no repeat.
    device.getPlaybackControl()->setSpeed(-1.0f);
    device.getPlaybackControl()->setRepeatEnabled(false);
  }
  step = device.isCommandSupported(kVirtualDeviceStepCommand);
  if (device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_OFF)) {
    device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_OFF);  // depth stays in the IR camera
  }
}

void OpenNI2Source::Impl::SelectPrimaryMode() {
  openni::VideoStream& stream = primary();
  const openni::SensorType type = options.depth ? openni::SENSOR_DEPTH : openni::SENSOR_IR;
  if (!file) {
    mode = ChooseMode(stream, type, options.width, options.height, options.fps);
    if (stream.setVideoMode(mode) != openni::STATUS_OK) {
      throw InputError(name, "video mode", "the device refused " + ModeString(type, mode) + ": " + ExtendedError());
    }
    return;
  }
  // Recordings play in their recorded mode; check it against what was asked for.
  mode = stream.getVideoMode();
  const bool size_ok = options.width == 0 ||
                       (mode.getResolutionX() == options.width && mode.getResolutionY() == options.height);
  const bool fps_ok = options.fps == 0 || mode.getFps() == options.fps;
  if (!size_ok || !fps_ok) {
    throw InputError(name, "video mode",
                     "the recording holds " + ModeString(type, mode) + ", not the requested " +
                         std::to_string(options.width) + "x" + std::to_string(options.height) + " @" +
                         std::to_string(options.fps) + " Hz");
  }
}

void OpenNI2Source::Impl::CheckDepthFormat() {
  if (!options.depth) return;
  const openni::PixelFormat f = depth.getVideoMode().getPixelFormat();
  if (options.raw) {
    if (f != openni::PIXEL_FORMAT_SHIFT_9_2) {
      throw InputError(name, "depth stream",
                       std::string("pixel format ") + FormatName(f) +
                           ", not the raw shifts (shift9.2) asked for (a calibration's depth "
                           "model reads raw shifts; `fuse --device-depth` fuses the metric "
                           "depth instead)");
    }
    return;
  }
  if (f == openni::PIXEL_FORMAT_SHIFT_9_2) {
    throw InputError(name, "depth stream",
                     "holds the chip's raw shifts (shift9.2), not metric depth: `record --raw` "
                     "copies them, `fuse` needs a calibration with a depth model for them");
  }
  if (!IsDepthFormat(f)) {
    throw InputError(name, "depth stream",
                     std::string("pixel format ") + FormatName(f) + " is not a depth unit (1mm or 100um)");
  }
  unit = f == openni::PIXEL_FORMAT_DEPTH_100_UM ? DepthUnit::k100um : DepthUnit::k1mm;
  if (file && options.depth_unit && *options.depth_unit != unit) {
    throw InputError(name, "depth unit",
                     std::string("the recording holds ") + ToString(unit) + ", not " + ToString(*options.depth_unit));
  }
}

void OpenNI2Source::Impl::MatchIrMode() {
  if (!(options.depth && options.ir)) return;
  // IR in the same size and rate as depth, so every Frame's images share one camera.
  if (!file) {
    const openni::VideoMode ir_mode = ChooseMode(ir, openni::SENSOR_IR, mode.getResolutionX(), mode.getResolutionY(),
                                                 mode.getFps());
    if (ir.setVideoMode(ir_mode) != openni::STATUS_OK) {
      throw InputError(name, "video mode",
                       "the device refused " + ModeString(openni::SENSOR_IR, ir_mode) + ": " + ExtendedError());
    }
  }
  const openni::VideoMode m = ir.getVideoMode();
  if (m.getResolutionX() != mode.getResolutionX() || m.getResolutionY() != mode.getResolutionY() ||
      m.getPixelFormat() != openni::PIXEL_FORMAT_GRAY16) {
    throw InputError(name, "IR stream",
                     ModeString(openni::SENSOR_IR, m) + " does not match depth " +
                         ModeString(openni::SENSOR_DEPTH, mode) + " in size, or is not gray16");
  }
}

// Camera: given, or a centred pinhole from the fields of view.
void OpenNI2Source::Impl::MakeCamera() {
  const int w = mode.getResolutionX(), h = mode.getResolutionY();
  if (options.camera) {
    if (options.camera->width != w || options.camera->height != h) {
      throw InputError(name, "camera",
                       "the given camera is " + std::to_string(options.camera->width) + "x" +
                           std::to_string(options.camera->height) + " but the stream is " + std::to_string(w) + "x" +
                           std::to_string(h));
    }
    camera = *options.camera;
    return;
  }
  const double hfov = primary().getHorizontalFieldOfView(), vfov = primary().getVerticalFieldOfView();
  if (!(hfov > 0.0 && hfov < M_PI && vfov > 0.0 && vfov < M_PI)) {
    throw InputError(name, "field of view",
                     "the device reports " + std::to_string(hfov) + " x " + std::to_string(vfov) +
                         " rad; give a camera model instead");
  }
  camera.width = w;
  camera.height = h;
  camera.fx = w / (2.0 * std::tan(hfov / 2.0));
  camera.fy = h / (2.0 * std::tan(vfov / 2.0));
  camera.cx = (w - 1) / 2.0;
  camera.cy = (h - 1) / 2.0;
}

void OpenNI2Source::Impl::ReadChip() {
  if (!options.depth) return;
  // The PS1080 reports ZPD in mm, ZPPS in mm, LDDIS and DCRCDIS in cm.
  auto length = [&](int id, double scale, std::optional<double>* out) {
    if (auto v = ReadProperty<double>(depth, id)) *out = *v * scale;
  };
  if (auto v = ReadProperty<uint64_t>(depth, XN_STREAM_PROPERTY_ZERO_PLANE_DISTANCE)) {
    chip.zero_plane_distance_m = static_cast<double>(*v) * 1e-3;
  }
  length(XN_STREAM_PROPERTY_ZERO_PLANE_PIXEL_SIZE, 1e-3, &chip.zero_plane_pixel_size_m);
  length(XN_STREAM_PROPERTY_EMITTER_DCMOS_DISTANCE, 1e-2, &chip.emitter_camera_distance_m);
  length(XN_STREAM_PROPERTY_DCMOS_RCMOS_DISTANCE, 1e-2, &chip.depth_rgb_camera_distance_m);
  auto integer = [&](int id, std::optional<long long>* out) {
    if (auto v = ReadProperty<uint64_t>(depth, id)) *out = static_cast<long long>(*v);
  };
  integer(XN_STREAM_PROPERTY_CONST_SHIFT, &chip.const_shift);
  integer(XN_STREAM_PROPERTY_PARAM_COEFF, &chip.param_coeff);
  integer(XN_STREAM_PROPERTY_SHIFT_SCALE, &chip.shift_scale);
  integer(XN_STREAM_PROPERTY_MAX_SHIFT, &chip.max_shift);
  integer(XN_STREAM_PROPERTY_PIXEL_SIZE_FACTOR, &chip.pixel_size_factor);
}

void OpenNI2Source::Impl::ReadLength() {
  if (file) {
    total_frames = device.getPlaybackControl()->getNumberOfFrames(primary());
    // A recorder that did not close its file (killed, out of power) leaves no count (-1).
    if (total_frames <= 0) {
      total_frames = 0;
      unfinished_recording = true;
    }
  } else if (auto n = ReadProperty<int>(primary(), ONI_STREAM_PROPERTY_NUMBER_OF_FRAMES)) {
    total_frames = *n;  // a finite (virtual) device announces its length
  }
}

void OpenNI2Source::Impl::StartRecorder() {
  if (options.record_oni.empty()) return;
  const std::string path = options.record_oni.string();
  if (recorder.create(path.c_str()) != openni::STATUS_OK) {
    throw InputError(path, "", "cannot create the .oni recording: " + ExtendedError());
  }
  for (openni::VideoStream* stream : {&depth, &ir}) {
    if (stream->isValid() && recorder.attach(*stream, false) != openni::STATUS_OK) {
      throw InputError(path, "", "cannot attach a stream to the recorder: " + ExtendedError());
    }
  }
  recorder.start();
  std::this_thread::sleep_for(kRecorderStartPause);
}

void OpenNI2Source::Impl::StartStreams() {
  for (openni::VideoStream* stream : {&depth, &ir}) {
    if (stream->isValid() && stream->start() != openni::STATUS_OK) {
      throw InputError(name, "streams", "cannot start: " + ExtendedError());
    }
  }
}

OpenNI2Source::OpenNI2Source(const OpenNI2SourceOptions& given) : impl_(std::make_unique<Impl>()) {
  OpenNI2SourceOptions options = given;
  if (IsVirtualDeviceUri(options.uri)) options.uri = AbsoluteVirtualDeviceUri(options.uri);  // romunect:frames
  CheckBeforeOpening(options);
  Impl& s = *impl_;  // its destructor takes down whatever a throwing step leaves open
  s.options = options;
  s.name = options.uri.empty() ? "the first OpenNI2 device" : options.uri;
  EnsureOpenNI();
  s.OpenDevice();
  if (options.depth) s.SetUp(s.depth, openni::SENSOR_DEPTH, "depth");
  if (options.ir) s.SetUp(s.ir, openni::SENSOR_IR, "IR");
  s.SelectPrimaryMode();
  s.CheckDepthFormat();
  s.MatchIrMode();
  for (openni::VideoStream* stream : {&s.depth, &s.ir}) {
    if (stream->isValid() && !s.file && stream->isPropertySupported(ONI_STREAM_PROPERTY_MIRRORING)) {
      stream->setMirroringEnabled(false);
    }
  }
  s.MakeCamera();
  s.ReadChip();
  s.ReadLength();
  s.StartRecorder();
  s.StartStreams();
}

OpenNI2Source::~OpenNI2Source() = default;  // Impl's destructor takes the device down

void OpenNI2Source::FinishRecording() { impl_->FinishRecording(); }

const CameraModel& OpenNI2Source::camera() const { return impl_->camera; }
const PS1080Properties& OpenNI2Source::chip() const { return impl_->chip; }
DepthUnit OpenNI2Source::depth_unit() const { return impl_->unit; }
bool OpenNI2Source::is_recording_playback() const { return impl_->file; }
const OpenNI2SourceStats& OpenNI2Source::stats() const { return impl_->stats; }

std::string OpenNI2Source::Describe() const {
  const Impl& s = *impl_;
  const openni::DeviceInfo& info = s.device.getDeviceInfo();
  std::ostringstream d;
  d << (s.file ? "OpenNI2 recording " : "OpenNI2 device ") << info.getUri() << " (" << info.getVendor() << ' '
    << info.getName() << "), " << s.mode.getResolutionX() << 'x' << s.mode.getResolutionY() << " @" << s.mode.getFps()
    << " Hz";
  if (s.options.depth)
    d << (s.options.raw ? std::string(", raw shifts") : std::string(", depth in ") + ToString(s.unit));
  if (s.options.ir) d << ", IR";
  if (s.total_frames > 0) d << ", " << s.total_frames << " frames";
  if (s.chip.zero_plane_distance_m || s.chip.emitter_camera_distance_m) d << "; chip: " << s.chip.Describe();
  return d.str();
}

FrameStatus OpenNI2Source::Next(Frame* frame, std::string* error) {
  ROMUNECT_CHECK(frame != nullptr && error != nullptr);
  Impl& s = *impl_;
  // Recordings and sources that announce a length (finite virtual devices) number frames 1..N.
  if ((s.options.max_frames > 0 && s.stats.frames >= s.options.max_frames) ||
      (s.total_frames > 0 && (s.primary_read >= s.total_frames || s.last_index >= s.total_frames)) || s.ended) {
    s.StopPlayback();
    return FrameStatus::kEndOfStream;
  }
  if (s.step) s.device.invoke(kVirtualDeviceStepCommand, nullptr, 0);

  openni::VideoFrameRef primary;
  if (!s.Read(s.primary(), s.options.depth ? "depth" : "IR", &primary)) {
    s.ended = true;
    s.StopPlayback();
    return FrameStatus::kEndOfStream;
  }
  ++s.primary_read;
  const int index = primary.getFrameIndex();
  if (s.first_index < 0) {
    s.first_index = index;
    s.first_timestamp_us = primary.getTimestamp();
    if ((s.file || s.total_frames > 0) && index > 1) s.stats.dropped_frames += index - 1;
  } else if (index > s.last_index + 1) {
    s.stats.dropped_frames += index - s.last_index - 1;
  }
  s.last_index = index;

  *frame = Frame();
  frame->index = s.file || s.total_frames > 0 ? index - 1 : index - s.first_index;
  frame->time_s = static_cast<double>(static_cast<int64_t>(primary.getTimestamp() - s.first_timestamp_us)) * 1e-6;
  const int w = s.camera.width, h = s.camera.height;
  auto check_size = [&](const openni::VideoFrameRef& ref, const char* what) {
    if (ref.getWidth() != w || ref.getHeight() != h || ref.getStrideInBytes() < w * 2 ||
        ref.getDataSize() < ref.getStrideInBytes() * (h - 1) + w * 2) {
      *error = std::string(what) + " frame " + std::to_string(ref.getFrameIndex()) + " is " +
               std::to_string(ref.getWidth()) + "x" + std::to_string(ref.getHeight()) + ", expected " +
               std::to_string(w) + "x" + std::to_string(h);
      return false;
    }
    return true;
  };
  auto copy16 = [&](const openni::VideoFrameRef& ref) {
    cv::Mat out(h, w, CV_16U);
    const auto* data = static_cast<const uint8_t*>(ref.getData());
    for (int v = 0; v < h; ++v) std::memcpy(out.ptr(v), data + static_cast<size_t>(v) * ref.getStrideInBytes(), w * 2);
    return out;
  };

  if (s.options.depth) {
    if (!check_size(primary, "depth")) return FrameStatus::kBadFrame;
    const cv::Mat counts = copy16(primary);
    if (s.options.raw) {
      frame->raw = counts;  // the chip's shifts as sent
    } else {
      frame->depth_m.create(h, w, CV_32F);
      for (int v = 0; v < h; ++v) {
        const uint16_t* in = counts.ptr<uint16_t>(v);
        float* out = frame->depth_m.ptr<float>(v);
        for (int u = 0; u < w; ++u) out[u] = DequantizeDepth(in[u], s.unit);
      }
    }
    if (s.options.ir) {
      // Pair by frame number: older IR frames are skipped, a newer one waits for its depth.
      for (int tries = 0; tries < 8; ++tries) {
        if (!s.pending_ir.isValid() && !s.Read(s.ir, "IR", &s.pending_ir)) {
          s.ended = true;  // the recording ends inside this frame: its IR was never written
          s.StopPlayback();
          return FrameStatus::kEndOfStream;
        }
        if (s.pending_ir.getFrameIndex() >= index) break;
        s.pending_ir.release();
        ++s.stats.unpaired_ir;
      }
      if (s.pending_ir.isValid() && s.pending_ir.getFrameIndex() == index) {
        if (!check_size(s.pending_ir, "IR")) return FrameStatus::kBadFrame;
        frame->ir = copy16(s.pending_ir);
        s.pending_ir.release();
      } else {
        ++s.stats.unpaired_ir;
      }
    }
  } else {
    if (!check_size(primary, "IR")) return FrameStatus::kBadFrame;
    frame->ir = copy16(primary);
  }
  ++s.stats.frames;
  return FrameStatus::kOk;
}

std::vector<DeviceListing> ListDevices() {
  EnsureOpenNI();
  openni::Array<openni::DeviceInfo> list;
  openni::OpenNI::enumerateDevices(&list);
  std::vector<DeviceListing> out;
  for (int i = 0; i < list.getSize(); ++i) out.push_back({list[i].getUri(), list[i].getVendor(), list[i].getName()});
  return out;
}

std::vector<std::string> ListVideoModes(const std::string& uri) {
  if (IsOniPath(uri) && !g_in_trial_read) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(uri, ec)) throw InputError(uri, "", "no such .oni file");
    CheckOniStructure(uri);
    TrialReadOni(uri, {"modes", uri}, TrialReadLimitS(uri));
  }
  EnsureOpenNI();
  openni::Device device;
  const std::string name = uri.empty() ? "the first OpenNI2 device" : uri;
  if (device.open(uri.empty() ? openni::ANY_DEVICE : uri.c_str()) != openni::STATUS_OK) {
    throw InputError(name, "",
                     "no OpenNI2 device opens with this URI (" + ExtendedError() +
                         "); devices found: " + DeviceListText());
  }
  std::vector<std::string> out;
  for (openni::SensorType t : {openni::SENSOR_DEPTH, openni::SENSOR_IR, openni::SENSOR_COLOR}) {
    const openni::SensorInfo* info = device.getSensorInfo(t);
    if (info == nullptr) continue;
    const auto& modes = info->getSupportedVideoModes();
    for (int i = 0; i < modes.getSize(); ++i) out.push_back(ModeString(t, modes[i]));
  }
  // A recording's player thread that has not started when its device closes holds the close for
  // 3 s (OpenNI2Source::Impl::~Impl).
  if (IsOniPath(uri)) std::this_thread::sleep_for(kPlayerSettlePause);
  device.close();
  return out;
}

std::filesystem::path DriverDirectory() {
  Dl_info info{};
  if (dladdr(reinterpret_cast<void*>(&oniInitialize), &info) == 0 || info.dli_fname == nullptr) return {};
  return std::filesystem::path(info.dli_fname).parent_path() / "OpenNI2" / "Drivers";
}

int OniTrialReadMain(int argc, char** argv) {
  g_in_trial_read = true;
  const std::vector<std::string> args(argv + std::min(argc, 1), argv + argc);
  try {
    if (args.size() == 2 && args[0] == "modes") {
      ListVideoModes(args[1]);
      return kOniTrialReadOk;
    }
    std::optional<OpenNI2SourceOptions> options = ParseTrialReadArguments(args);
    if (!options) return kOniTrialReadUsage;
    // Reads what the caller will read, to its end or max_frames.
    OpenNI2Source source(*options);
    Frame frame;
    std::string error;
    while (source.Next(&frame, &error) != FrameStatus::kEndOfStream) {
    }
  } catch (const InputError&) {
    return kOniTrialReadInputError;
  } catch (...) {
    return kOniTrialReadOtherError;
  }
  return kOniTrialReadOk;
}

}  // namespace romunect::openni2
