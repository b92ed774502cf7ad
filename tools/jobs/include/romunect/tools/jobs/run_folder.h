// A run folder as one transaction: the run is built in `<run>.incomplete/` and renamed to
// `<run>/` when complete, so a folder under the final name is always complete. The final name
// may be new or an empty folder; one that holds a finished run (its report.json), anything else,
// or a file is refused before any work and never touched.
//
// Two runs into one folder cannot share it: Begin() creates `<run>.incomplete/` atomically with
// a marker file (kRunMarker) that says romunect made it, and holds an exclusive lock on the
// marker for the run's life. A second run is refused in Begin(), before any work. A work folder
// with a marker and no lock is what a killed run left: it is removed and replaced. A work folder
// without the marker is never removed. Every job that writes a run folder uses this class.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace romunect::jobs {

// The marker file in a work folder: romunect made the folder and may remove it. It is removed
// right after the rename, so no finished run holds it.
constexpr const char* kRunMarker = ".romunect-run";

class RunFolder {
 public:
  // Checks `value` (named by `option`, "--out") and whether the folder can be created; throws
  // InputError naming the option or the folder. `job` names the run in messages ("scan": a
  // report.json there is "a finished scan"). Creates nothing.
  RunFolder(const std::string& value, const std::string& option, const std::string& job);
  // A run that never committed leaves nothing: its work folder is removed (but a taken-over one).
  ~RunFolder();
  RunFolder(const RunFolder&) = delete;
  RunFolder& operator=(const RunFolder&) = delete;

  const std::filesystem::path& dir() const { return dir_; }            // the final name
  const std::filesystem::path& work_dir() const { return work_dir_; }  // <dir>.incomplete

  // Creates and locks the work folder, replacing one a killed run left. Throws InputError when
  // another run holds it, when it lacks the marker, or when the final name was filled meanwhile.
  void Begin();
  // Begin(), but a killed run's work folder is taken over with its files (locked, its marker
  // kept) instead of removed, less the temporaries its cut writes left: true then; false when
  // there was none and a fresh one was made. A taken-over folder stays when the run fails: it
  // can be resumed again.
  bool Resume();
  // Moves the work folder under the final name. Throws InputError, keeping the work folder,
  // when the final name was filled meanwhile.
  void Commit();

 private:
  bool Start(bool take_over);  // Begin and Resume
  void CheckFinalNameIsFree() const;
  bool TryCreate();      // false when the work folder exists
  // A killed run's work folder (marker, no lock): removed, or with `take_over` locked and kept
  // (true). Throws when it is not a killed run's.
  bool RemoveIfStale(bool take_over = false);
  void Unlock();

  std::string job_, option_;
  std::filesystem::path dir_, work_dir_;
  int lock_fd_ = -1;  // the marker, locked (flock) while this run owns the work folder
  bool begun_ = false, done_ = false, taken_over_ = false;
};

// A resumable run records the options that decide its bytes (a JSON object) in its work folder;
// a resume compares them with its own. The first key of `now_json`, `ignored` aside, whose
// recorded value differs or is missing ("missing"), with both values as JSON text; nothing when
// all match. Throws InputError naming `file` when it is missing or not a JSON object.
struct ChangedOption {
  std::string key, recorded, now;
};
std::optional<ChangedOption> FindChangedOption(const std::filesystem::path& file, const std::string& now_json,
                                               const std::vector<std::string>& ignored = {});

// An exclusive lock for a run that writes into an output folder in place (calibrate's --out, which
// may hold the calibration it updates): the lock file
// `<folder>.lock` beside the folder is created and locked (flock) for the lock's life, and removed
// when it is released. Throws InputError, before any work, when another run holds it. A lock file
// a killed run left is taken over.
class FolderLock {
 public:
  FolderLock(const std::filesystem::path& folder, const std::string& option, const std::string& job);
  ~FolderLock();
  FolderLock(const FolderLock&) = delete;
  FolderLock& operator=(const FolderLock&) = delete;

  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  int fd_ = -1;
};

}  // namespace romunect::jobs
