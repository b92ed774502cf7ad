// Parsing of virtual-device URIs, shared by the driver plug-in and the library.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "romunect/openni2/virtual_device.h"

namespace romunect::openni2 {

inline constexpr const char* kVirtualDeviceScheme = "romunect:";

struct ParsedVirtualDeviceUri {
  std::filesystem::path dir;
  VirtualDeviceOptions options;
};

// True when `uri` uses the virtual device's scheme (whether or not it is valid).
bool IsVirtualDeviceUri(const std::string& uri);

// Parses a virtual-device URI; on failure returns nullopt and says why in *problem.
std::optional<ParsedVirtualDeviceUri> ParseVirtualDeviceUri(const std::string& uri, std::string* problem);

}  // namespace romunect::openni2
