#include "romunect/sensor/openni2/open_source.h"

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "virtual_device_uri.h"

namespace romunect::openni2 {
namespace {

constexpr const char* kDeviceScheme = "oni://";

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

FrameSource* Unwrap(FrameSource* source) {
  if (auto* logged = dynamic_cast<PoseLogSource*>(source)) return &logged->inner();
  return source;
}

}  // namespace

SourceKind ClassifySource(const std::string& source) {
  if (source.rfind(kDeviceScheme, 0) == 0 || IsVirtualDeviceUri(source)) return SourceKind::kDevice;
  if (EndsWith(source, ".oni")) return SourceKind::kOniFile;
  return SourceKind::kFrameDirectory;
}

std::unique_ptr<FrameSource> OpenSource(const std::string& source, const OpenSourceOptions& options) {
  if (source.empty()) {
    throw InputError("source", "", "empty; expected a frame directory, a .oni file, oni://[URI] or romunect:DIR");
  }
  std::unique_ptr<FrameSource> inner;
  switch (ClassifySource(source)) {
    case SourceKind::kFrameDirectory: {
      std::error_code ec;
      if (!std::filesystem::is_directory(source, ec)) {
        throw InputError(source, "", "not a directory, a .oni file, oni://[URI] or romunect:DIR");
      }
      inner = std::make_unique<FrameDirectorySource>(source, options.invalid_depth);
      break;
    }
    case SourceKind::kOniFile:
    case SourceKind::kDevice: {
      OpenNI2SourceOptions o = options.openni2;
      o.uri = source.rfind(kDeviceScheme, 0) == 0 ? source.substr(std::string(kDeviceScheme).size()) : source;
      inner = std::make_unique<OpenNI2Source>(o);
      break;
    }
  }
  if (options.pose_log.empty()) return inner;
  return std::make_unique<PoseLogSource>(std::move(inner), PoseLog::Load(options.pose_log), options.pose);
}

OpenNI2Source* FindOpenNI2Source(FrameSource* source) { return dynamic_cast<OpenNI2Source*>(Unwrap(source)); }

FrameDirectorySource* FindFrameDirectorySource(FrameSource* source) {
  return dynamic_cast<FrameDirectorySource*>(Unwrap(source));
}

}  // namespace romunect::openni2
