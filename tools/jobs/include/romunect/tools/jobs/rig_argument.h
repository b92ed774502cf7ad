// A rig named on the command line: a rig JSON file or a preset name.
#pragma once

#include <string>

#include "romunect/sensor/rig.h"

namespace romunect::jobs {

// A rig JSON file (a name ending in .json, or an existing file) or a preset name (RigPreset: an
// unknown name says which presets exist).
Rig LoadRigArgument(const std::string& value);

}  // namespace romunect::jobs
