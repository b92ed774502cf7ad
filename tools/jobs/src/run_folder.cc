#include "romunect/tools/jobs/run_folder.h"

#include <system_error>

#include "romunect/sensor/errors.h"
#include "romunect/tools/jobs/output_folder.h"

namespace romunect::jobs {
namespace fs = std::filesystem;

RunFolder::RunFolder(const std::string& value, const std::string& option, const std::string& job)
    : job_(job), dir_(OutputFolder(value, option)), work_dir_(dir_.string() + ".incomplete") {
  if (fs::exists(dir_ / "report.json")) {
    throw InputError(dir_.string(), "", "holds a finished " + job_ + " (report.json); choose another " + option);
  }
  // The run replaces at most an empty folder: nothing a user put there is ever removed.
  if (fs::exists(dir_) && !(fs::is_directory(dir_) && fs::is_empty(dir_))) {
    throw InputError(dir_.string(), "", "exists and is not an empty folder; choose another " + option);
  }
  CheckFolderCanBeCreated(dir_, option);
}

RunFolder::~RunFolder() {
  if (!begun_ || done_) return;
  std::error_code ec;  // a destructor may not throw; a folder that stays is found by the next run
  fs::remove_all(work_dir_, ec);
}

void RunFolder::Begin() {
  if (fs::exists(work_dir_)) fs::remove_all(work_dir_);
  fs::create_directories(work_dir_);
  begun_ = true;
}

void RunFolder::Commit() {
  if (fs::exists(dir_)) {
    if (!fs::is_directory(dir_) || !fs::is_empty(dir_)) {
      done_ = true;  // the finished run stays where it is
      throw InputError(dir_.string(), "",
                       "was filled while the " + job_ + " ran; the finished run is in " + work_dir_.string());
    }
    fs::remove(dir_);  // the empty folder the run replaces
  }
  fs::create_directories(dir_.parent_path().empty() ? fs::path(".") : dir_.parent_path());
  fs::rename(work_dir_, dir_);
  done_ = true;
}

}  // namespace romunect::jobs
