// Parsing of virtual-device URIs, shared by the driver plug-in and the library.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "romunect/sensor/openni2/virtual_device.h"

namespace romunect::openni2 {

inline constexpr const char* kVirtualDeviceScheme = "romunect:";
inline constexpr const char* kSimFeedScheme = "romunect-sim:";
// The environment variable that names a device for any OpenNI2 program (virtual_device.h).
inline constexpr const char* kVirtualDeviceEnv = "ROMUNECT_VIRTUAL_DEVICE";
// The driver's file name and its C function that says why the last open failed:
// void romunect_virtual_device_last_error(char* buffer, int size).
inline constexpr const char* kVirtualDriverFile = "libRomunectVirtual.so.0";
inline constexpr const char* kVirtualDeviceLastErrorSymbol = "romunect_virtual_device_last_error";
// For tests: void romunect_virtual_device_set_wait_hook(void (*hook)()), see virtual_driver.cc.
inline constexpr const char* kVirtualDeviceWaitHookSymbol = "romunect_virtual_device_set_wait_hook";

struct ParsedVirtualDeviceUri {
  std::filesystem::path dir;  // a frame directory; empty for a feed
  VirtualDeviceOptions options;
  bool feed = false;         // frames from a feed library (romunect-sim:)
  std::string feed_library;  // feed=PATH; empty = the simulator's, beside the driver folder
  std::string feed_query;    // the keys the driver does not read, for the feed
};

// True when `uri` uses one of the virtual device's schemes (whether or not it is valid).
bool IsVirtualDeviceUri(const std::string& uri);

// `value` (a romunect: URI or a plain frame directory, as ROMUNECT_VIRTUAL_DEVICE takes) with
// a relative directory made absolute against the current working directory; anything else as
// given. libOpenNI2 changes the working directory while it loads drivers, so only the caller,
// before OpenNI2 starts, knows what a relative directory meant.
std::string AbsoluteVirtualDeviceUri(const std::string& value);
// True when `value` (as above) names a relative directory.
bool HasRelativeDirectory(const std::string& value);

// Parses a virtual-device URI; on failure returns nullopt and says why in *problem.
std::optional<ParsedVirtualDeviceUri> ParseVirtualDeviceUri(const std::string& uri, std::string* problem);

}  // namespace romunect::openni2
