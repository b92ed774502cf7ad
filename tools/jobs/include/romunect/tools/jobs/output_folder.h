// Output folders named on the command line, checked before any work: a long run must not end
// in a refusal, and nothing outside the folder it creates may be touched.
#pragma once

#include <filesystem>
#include <string>

namespace romunect::jobs {

// `path` lexically normal and without trailing separators ("scan1/" is "scan1"; a root stays).
std::filesystem::path WithoutTrailingSeparators(const std::filesystem::path& path);

// The folder `value` names, lexically normal and without trailing separators ("runs/a/" is
// "runs/a", "runs/a/../b" is "runs/b"). Throws InputError(option) for "", ".", "..", "../.." or a
// root: they name no folder of their own.
std::filesystem::path OutputFolder(const std::string& value, const std::string& option);

// Throws InputError(option) unless `dir` is a directory already or can be created: its nearest
// existing ancestor must be a directory this process may write in.
void CheckFolderCanBeCreated(const std::filesystem::path& dir, const std::string& option);

}  // namespace romunect::jobs
