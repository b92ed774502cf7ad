// A run folder as one transaction: the run is built in `<run>.incomplete/` and renamed to
// `<run>/` when complete, so a folder under the final name is always complete. The final name
// may be new or an empty folder; one that holds a finished run (its report.json), anything else,
// or a file is refused before any work and never touched.
#pragma once

#include <filesystem>
#include <string>

namespace romunect::jobs {

class RunFolder {
 public:
  // Checks `value` (named by `option`, "--out") and whether the folder can be created; throws
  // InputError naming the option or the folder. `job` names the run in messages ("scan": a
  // report.json there is "a finished scan"). Creates nothing.
  RunFolder(const std::string& value, const std::string& option, const std::string& job);
  // A run that never committed leaves nothing: its work folder is removed.
  ~RunFolder();
  RunFolder(const RunFolder&) = delete;
  RunFolder& operator=(const RunFolder&) = delete;

  const std::filesystem::path& dir() const { return dir_; }            // the final name
  const std::filesystem::path& work_dir() const { return work_dir_; }  // <dir>.incomplete

  // Creates the work folder, replacing one a crashed run left.
  void Begin();
  // Moves the work folder under the final name. Throws InputError, keeping the work folder,
  // when the final name was filled meanwhile.
  void Commit();

 private:
  std::string job_;
  std::filesystem::path dir_, work_dir_;
  bool begun_ = false, done_ = false;
};

}  // namespace romunect::jobs
