#include "virtual_device_uri.h"

#include <cmath>
#include <cstdlib>
#include <sstream>

#include "romunect/sensor/errors.h"

namespace romunect::openni2 {

std::string VirtualDeviceOptions::Problem() const {
  if (stop_after < -1) return "stop_after = " + std::to_string(stop_after) + ": must be -1 (never) or >= 0";
  if (!std::isfinite(fps) || fps < 0.0 || fps > 1000.0) {
    return "fps = " + std::to_string(fps) + ": must be 0 (from frame times) or in (0, 1000]";
  }
  if (loop && pace == Pace::kStep) return "loop = 1: only with pace=realtime";
  return "";
}

namespace {

// The driver's keys of `options` appended to `uri` (which ends in its path).
std::string WithOptions(const std::string& uri_path, const VirtualDeviceOptions& options,
                        const std::string& extra_query = "") {
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("virtual device", "options", problem);
  std::ostringstream uri;
  uri << uri_path;
  char sep = '?';
  auto add = [&](const std::string& key, const std::string& value) {
    uri << sep << key << '=' << value;
    sep = '&';
  };
  if (options.pace == VirtualDeviceOptions::Pace::kStep) add("pace", "step");
  if (options.stop_after >= 0) add("stop_after", std::to_string(options.stop_after));
  if (options.loop) add("loop", "1");
  if (options.impersonate_ps1080) add("impersonate", "ps1080");
  if (options.fps > 0.0) {
    std::ostringstream fps;
    fps.precision(17);
    fps << options.fps;
    add("fps", fps.str());
  }
  if (!extra_query.empty()) uri << sep << extra_query;
  return uri.str();
}

}  // namespace

std::string VirtualDeviceUri(const std::filesystem::path& frame_dir, const VirtualDeviceOptions& options) {
  const std::string dir = std::filesystem::absolute(frame_dir).lexically_normal().string();
  if (dir.find('?') != std::string::npos) {
    throw InputError(dir, "", "a virtual device's directory may not contain '?'");
  }
  return WithOptions(kVirtualDeviceScheme + dir, options);
}

std::string SimFeedUri(const std::string& feed_query, const VirtualDeviceOptions& options) {
  if (options.loop) throw InputError("virtual device", "options", "loop = 1: only for frame directories");
  return WithOptions(kSimFeedScheme, options, feed_query);
}

bool IsVirtualDeviceUri(const std::string& uri) {
  return uri.rfind(kVirtualDeviceScheme, 0) == 0 || uri.rfind(kSimFeedScheme, 0) == 0;
}

namespace {

// A romunect: URI or a plain directory split into scheme ("" for a plain one), directory and
// "?query" (possibly empty).
struct DirectoryUriParts {
  std::string scheme;
  std::filesystem::path dir;
  std::string query;
};

DirectoryUriParts SplitDirectoryUri(const std::string& value) {
  DirectoryUriParts parts;
  std::string rest = value;
  if (value.rfind(kVirtualDeviceScheme, 0) == 0) {
    parts.scheme = kVirtualDeviceScheme;
    rest = value.substr(parts.scheme.size());
    if (rest.rfind("//", 0) == 0) rest = rest.substr(2);
  }
  const size_t q = rest.find('?');
  parts.dir = rest.substr(0, q);
  if (q != std::string::npos) parts.query = rest.substr(q);
  return parts;
}

}  // namespace

bool HasRelativeDirectory(const std::string& value) {
  if (value.empty() || value.rfind(kSimFeedScheme, 0) == 0) return false;
  const std::filesystem::path dir = SplitDirectoryUri(value).dir;
  return !dir.empty() && dir.is_relative();
}

std::string AbsoluteVirtualDeviceUri(const std::string& value) {
  if (!HasRelativeDirectory(value)) return value;
  const DirectoryUriParts parts = SplitDirectoryUri(value);
  return parts.scheme + std::filesystem::absolute(parts.dir).lexically_normal().string() + parts.query;
}

std::optional<ParsedVirtualDeviceUri> ParseVirtualDeviceUri(const std::string& uri, std::string* problem) {
  if (!IsVirtualDeviceUri(uri)) {
    *problem = std::string("does not start with ") + kVirtualDeviceScheme;
    return std::nullopt;
  }
  ParsedVirtualDeviceUri parsed;
  parsed.feed = uri.rfind(kSimFeedScheme, 0) == 0;
  std::string rest = uri.substr(std::string(parsed.feed ? kSimFeedScheme : kVirtualDeviceScheme).size());
  // Accept both romunect:/abs/dir and romunect:///abs/dir.
  if (rest.rfind("//", 0) == 0) rest = rest.substr(2);
  const size_t q = rest.find('?');
  if (parsed.feed) {
    if (q != 0 && !rest.empty()) {
      *problem = "a feed URI has no path: romunect-sim:?key=value&...";
      return std::nullopt;
    }
  } else {
    parsed.dir = rest.substr(0, q);
    if (parsed.dir.empty() || !parsed.dir.is_absolute()) {
      *problem = "the directory must be an absolute path";
      return std::nullopt;
    }
  }
  if (q != std::string::npos) {
    std::stringstream query(rest.substr(q + 1));
    std::string item;
    while (std::getline(query, item, '&')) {
      const size_t eq = item.find('=');
      const std::string key = item.substr(0, eq);
      const std::string value = eq == std::string::npos ? "" : item.substr(eq + 1);
      char* end = nullptr;
      if (key == "pace" && (value == "step" || value == "realtime")) {
        parsed.options.pace = value == "step" ? VirtualDeviceOptions::Pace::kStep
                                              : VirtualDeviceOptions::Pace::kRealtime;
      } else if (key == "stop_after" && !value.empty()) {
        const long n = std::strtol(value.c_str(), &end, 10);
        if (*end != '\0') {
          *problem = "stop_after=" + value + ": not an integer";
          return std::nullopt;
        }
        parsed.options.stop_after = static_cast<int>(n);
      } else if (key == "impersonate" && value == "ps1080") {
        parsed.options.impersonate_ps1080 = true;
      } else if (key == "loop" && (value == "0" || value == "1")) {
        parsed.options.loop = value == "1";
      } else if (key == "fps" && !value.empty()) {
        parsed.options.fps = std::strtod(value.c_str(), &end);
        if (*end != '\0') {
          *problem = "fps=" + value + ": not a number";
          return std::nullopt;
        }
      } else if (parsed.feed && key == "feed" && !value.empty()) {
        parsed.feed_library = value;
      } else if (parsed.feed) {
        parsed.feed_query += (parsed.feed_query.empty() ? "" : "&") + item;  // the feed's own key
      } else {
        *problem = "unknown or malformed parameter '" + item +
                   "' (expected pace=realtime|step, stop_after=N, loop=0|1, fps=F, impersonate=ps1080)";
        return std::nullopt;
      }
    }
  }
  if (parsed.feed && parsed.options.loop) {
    *problem = "loop=1: only for frame directories";
    return std::nullopt;
  }
  const std::string options_problem = parsed.options.Problem();
  if (!options_problem.empty()) {
    *problem = options_problem;
    return std::nullopt;
  }
  return parsed;
}

}  // namespace romunect::openni2
