#include "romunect/tools/jobs/rig_argument.h"

#include <filesystem>

namespace romunect::jobs {

Rig LoadRigArgument(const std::string& value) {
  if (value.size() > 5 && value.substr(value.size() - 5) == ".json") return LoadRig(value);
  if (std::filesystem::exists(value)) return LoadRig(value);
  return RigPreset(value);
}

}  // namespace romunect::jobs
