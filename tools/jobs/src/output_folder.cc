#include "romunect/tools/jobs/output_folder.h"

#include <unistd.h>

#include <system_error>

#include "romunect/sensor/errors.h"

namespace romunect::jobs {
namespace fs = std::filesystem;

fs::path WithoutTrailingSeparators(const fs::path& path) {
  fs::path p = path.lexically_normal();
  while (!p.empty() && p.filename().empty() && p != p.root_path()) p = p.parent_path();
  return p;
}

fs::path OutputFolder(const std::string& value, const std::string& option) {
  const fs::path dir = WithoutTrailingSeparators(value);
  const std::string name = dir.filename().string();
  if (dir.empty() || name.empty() || name == "." || name == "..") {
    throw InputError(option, "", "'" + value + "' names no folder of its own; give a new folder's name");
  }
  return dir;
}

void CheckFolderCanBeCreated(const fs::path& dir, const std::string& option) {
  std::error_code ec;
  fs::path existing = dir;
  while (!existing.empty() && !fs::exists(existing, ec)) existing = existing.parent_path();
  if (existing.empty()) existing = ".";
  if (!fs::is_directory(existing, ec)) {
    throw InputError(option, "", dir.string() + ": cannot be created: " + existing.string() + " is not a folder");
  }
  if (::access(existing.c_str(), W_OK | X_OK) != 0) {
    throw InputError(option, "", dir.string() + ": cannot be created: " + existing.string() + " is not writable");
  }
}

}  // namespace romunect::jobs
