// libRomunectVirtual.so.0: an OpenNI2 driver plug-in for romunect's virtual device
// (romunect/sensor/openni2/virtual_device.h documents URIs and behaviour). It announces devices
// and loads the devices' code, libRomunectVirtualBackend.so (backend_abi.h), only when one
// opens: so it links nothing but the C++ runtime, and an OpenNI2 program that loads the driver
// folder without opening a romunect device maps no more than this small library.
#include <dlfcn.h>

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include "backend_abi.h"  // OpenNI2's driver API
#include "virtual_device_uri.h"

namespace romunect::openni2 {
namespace {

// PrimeSense's USB vendor id and the PS1080 reference design's product id.
constexpr uint16_t kPrimeSenseUsbVendorId = 0x1d27;
constexpr uint16_t kPs1080UsbProductId = 0x0600;

// The backend, loaded once and never unloaded (its devices' threads may outlive a close).
// Empty with why in *error when it cannot load.
void* LoadBackend(std::string* error) {
  static std::mutex mutex;
  static void* handle = nullptr;
  static std::string load_error;
  std::lock_guard<std::mutex> lock(mutex);
  if (handle == nullptr && load_error.empty()) {
    Dl_info info{};
    std::filesystem::path path = kVirtualBackendFile;
    if (dladdr(reinterpret_cast<void*>(&LoadBackend), &info) != 0 && info.dli_fname != nullptr) {
      path = std::filesystem::path(info.dli_fname).parent_path().parent_path().parent_path() / kVirtualBackendFile;
    }
    handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    if (handle == nullptr) load_error = std::string("cannot load the virtual device's backend: ") + dlerror();
  }
  *error = load_error;
  return handle;
}

// Why the last deviceOpen failed. OpenNI2 2.2 does not pass a driver's log on to the
// application's getExtendedError(), so OpenNI2Source asks here (kVirtualDeviceLastErrorSymbol).
std::mutex g_last_open_error_mutex;
std::string g_last_open_error;

void SetLastOpenError(const std::string& message) {
  std::lock_guard<std::mutex> lock(g_last_open_error_mutex);
  g_last_open_error = message;
}

class VirtualDriver;
// The one driver OpenNI2 creates, for the backend's end-of-source callback.
std::atomic<VirtualDriver*> g_driver{nullptr};
void SourceEnded(const char* uri);

class VirtualDriver : public oni::driver::DriverBase {
 public:
  explicit VirtualDriver(OniDriverServices* services) : DriverBase(services) { g_driver = this; }
  ~VirtualDriver() override {
    StopEvents();
    g_driver = nullptr;
  }

  // A finite source has ended: as OpenNI2's file player, the device's state becomes EOF; and as a
  // PS1080 whose cable is pulled, it is disconnected. The events are raised on the driver's own
  // thread, so a listener may close the device (which waits for the device's producer) at once.
  void Ended(const std::string& uri) {
    std::lock_guard<std::mutex> lock(events_mutex_);
    if (stopping_) return;
    ended_.push_back(uri);
    if (!events_.joinable()) events_ = std::thread([this] { RaiseEvents(); });
    events_wake_.notify_one();
  }

  OniStatus initialize(oni::driver::DeviceConnectedCallback connected,
                       oni::driver::DeviceDisconnectedCallback disconnected,
                       oni::driver::DeviceStateChangedCallback state_changed, void* cookie) override {
    const OniStatus status = DriverBase::initialize(connected, disconnected, state_changed, cookie);
    // ROMUNECT_VIRTUAL_DEVICE lets any OpenNI2 program (NiViewer2, ...) find a device at start-up.
    if (const char* env = std::getenv(kVirtualDeviceEnv); env != nullptr && *env != '\0') AnnounceFromEnvironment(env);
    return status;
  }

  // Announces a device for a romunect: URI whose directory holds frames.json.
  OniStatus tryDevice(const char* uri) override {
    if (!IsVirtualDeviceUri(uri)) return ONI_STATUS_ERROR;  // another driver's
    std::string problem;
    const auto parsed = ParseVirtualDeviceUri(uri, &problem);
    std::error_code ec;
    if (parsed && !parsed->feed && !std::filesystem::is_regular_file(parsed->dir / "frames.json", ec)) {
      problem = "no frames.json in " + parsed->dir.string();
    } else if (parsed && std::strlen(uri) >= ONI_MAX_STR) {
      problem = "the URI is longer than OpenNI2's " + std::to_string(ONI_MAX_STR - 1) + " characters";
    }
    if (!problem.empty()) {
      ReportOpenError(std::string(uri) + ": " + problem);
      return ONI_STATUS_ERROR;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (!announced_.count(uri)) {
      OniDeviceInfo info{};
      std::snprintf(info.uri, sizeof(info.uri), "%s", uri);
      if (parsed->options.impersonate_ps1080) {
        std::snprintf(info.vendor, sizeof(info.vendor), "PrimeSense");
        std::snprintf(info.name, sizeof(info.name), "PS1080");
        info.usbVendorId = kPrimeSenseUsbVendorId;
        info.usbProductId = kPs1080UsbProductId;
      } else {
        std::snprintf(info.vendor, sizeof(info.vendor), "romunect");
        std::snprintf(info.name, sizeof(info.name), parsed->feed ? "romunect live feed" : "romunect virtual sensor");
      }
      announced_[uri] = info;
      deviceConnected(&info);
    }
    return ONI_STATUS_OK;
  }

  oni::driver::DeviceBase* deviceOpen(const char* uri, const char* /*mode*/) override {
    std::string problem;
    const auto parsed = ParseVirtualDeviceUri(uri, &problem);
    if (!parsed) {
      ReportOpenError(problem);
      return nullptr;
    }
    void* backend = LoadBackend(&problem);
    auto open = backend == nullptr ? nullptr
                                   : reinterpret_cast<VirtualBackendOpenFn>(dlsym(backend, kVirtualBackendOpenSymbol));
    if (open == nullptr) {
      ReportOpenError(problem.empty() ? std::string("the backend lacks ") + kVirtualBackendOpenSymbol : problem);
      return nullptr;
    }
    char error[2048] = "";
    oni::driver::DeviceBase* device = open(uri, &getServices(), &SourceEnded, error, sizeof(error));
    if (device == nullptr) {
      ReportOpenError(error);
      return nullptr;
    }
    SetLastOpenError("");
    return device;
  }

  void deviceClose(oni::driver::DeviceBase* device) override { delete device; }

  void shutdown() override { StopEvents(); }

 private:
  // OpenNI2 passes a driver's log on to no one: the reason is kept for OpenNI2Source
  // (romunect_virtual_device_last_error) and logged.
  void ReportOpenError(const std::string& message) {
    SetLastOpenError(message);
    getServices().errorLoggerAppend("%s", message.c_str());
  }

  void AnnounceFromEnvironment(const std::string& value) {
    const std::string uri = IsVirtualDeviceUri(value) ? value : kVirtualDeviceScheme + value;
    std::string problem;
    const auto parsed = ParseVirtualDeviceUri(uri, &problem);
    if (HasRelativeDirectory(value)) {
      // The working directory is libOpenNI2's own while drivers load: a relative one means nothing
      // here. romunect's programs resolve it before OpenNI2 starts; other programs must not guess.
      // Said on stderr too: in another program nothing else would show it.
      const std::string message = std::string(kVirtualDeviceEnv) + "=" + value +
                                  ": a relative directory; OpenNI2 loads its drivers in another working "
                                  "directory, so give an absolute path";
      ReportOpenError(message);
      std::fprintf(stderr, "romunect virtual device: %s\n", message.c_str());
      return;
    }
    if (!parsed) {
      ReportOpenError(std::string(kVirtualDeviceEnv) + "=" + value + ": " + problem);
      return;
    }
    if (tryDevice(uri.c_str()) != ONI_STATUS_OK) {
      std::lock_guard<std::mutex> lock(g_last_open_error_mutex);
      g_last_open_error = std::string(kVirtualDeviceEnv) + "=" + value + ": " + g_last_open_error;
    }
  }

  void RaiseEvents() {
    std::unique_lock<std::mutex> lock(events_mutex_);
    for (;;) {
      events_wake_.wait(lock, [this] { return stopping_ || !ended_.empty(); });
      if (stopping_) return;
      const std::string uri = ended_.front();
      ended_.pop_front();
      lock.unlock();
      OniDeviceInfo info{};
      bool known = false;
      {
        std::lock_guard<std::mutex> announced_lock(mutex_);
        if (const auto it = announced_.find(uri); it != announced_.end()) {
          info = it->second;
          announced_.erase(it);
          known = true;
        }
      }
      if (known) {
        deviceStateChanged(&info, ONI_DEVICE_STATE_EOF);
        deviceDisconnected(&info);
      }
      lock.lock();
    }
  }

  void StopEvents() {
    {
      std::lock_guard<std::mutex> lock(events_mutex_);
      stopping_ = true;
    }
    events_wake_.notify_all();
    if (events_.joinable()) events_.join();
  }

  std::mutex mutex_;
  std::map<std::string, OniDeviceInfo> announced_;  // by URI

  std::mutex events_mutex_;  // guards ended_ and stopping_
  std::condition_variable events_wake_;
  std::deque<std::string> ended_;  // URIs whose sources ended, not yet raised
  bool stopping_ = false;
  std::thread events_;
};

void SourceEnded(const char* uri) {
  if (VirtualDriver* driver = g_driver.load()) driver->Ended(uri);
}

}  // namespace
}  // namespace romunect::openni2

ONI_EXPORT_DRIVER(romunect::openni2::VirtualDriver)

// Test hook: `hook` (nullptr to remove) runs on the producer thread with the device mutex held,
// each time the producer is about to wait for a stream to start (the window a start must not
// fall into unnoticed).
extern "C" __attribute__((visibility("default"))) void romunect_virtual_device_set_wait_hook(void (*hook)()) {
  std::string error;
  void* backend = romunect::openni2::LoadBackend(&error);
  if (backend == nullptr) return;
  auto set = reinterpret_cast<romunect::openni2::VirtualBackendWaitHookFn>(
      dlsym(backend, romunect::openni2::kVirtualBackendWaitHookSymbol));
  if (set != nullptr) set(hook);
}

// Copies why the last deviceOpen failed ("" after a success) into buffer (size bytes).
extern "C" __attribute__((visibility("default"))) void romunect_virtual_device_last_error(char* buffer, int size) {
  if (buffer == nullptr || size <= 0) return;
  std::lock_guard<std::mutex> lock(romunect::openni2::g_last_open_error_mutex);
  std::snprintf(buffer, static_cast<size_t>(size), "%s", romunect::openni2::g_last_open_error.c_str());
}
