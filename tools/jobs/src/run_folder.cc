#include "romunect/tools/jobs/run_folder.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <system_error>
#include <vector>

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/input_limits.h"
#include "romunect/tools/jobs/output_folder.h"

namespace romunect::jobs {
namespace fs = std::filesystem;

namespace {

std::string Errno() { return std::strerror(errno); }

// The text of a marker file, for messages naming the run that holds a folder.
std::string MarkerText(int fd) {
  char text[256] = {};
  const ssize_t n = ::pread(fd, text, sizeof(text) - 1, 0);
  std::string s(text, n > 0 ? static_cast<size_t>(n) : 0);
  while (!s.empty() && s.back() == '\n') s.pop_back();
  return s;
}

}  // namespace

RunFolder::RunFolder(const std::string& value, const std::string& option, const std::string& job)
    : job_(job), option_(option), dir_(OutputFolder(value, option)), work_dir_(dir_.string() + ".incomplete") {
  CheckFinalNameIsFree();
  CheckFolderCanBeCreated(dir_, option);
}

RunFolder::~RunFolder() {
  if (begun_ && !done_ && !taken_over_) {
    std::error_code ec;  // a destructor may not throw; a folder that stays is found by the next run
    fs::remove_all(work_dir_, ec);
  }
  Unlock();
}

void RunFolder::CheckFinalNameIsFree() const {
  if (fs::exists(dir_ / "report.json")) {
    throw InputError(dir_.string(), "", "holds a finished " + job_ + " (report.json); choose another " + option_);
  }
  // The run replaces at most an empty folder: nothing a user put there is ever removed.
  if (fs::exists(dir_) && !(fs::is_directory(dir_) && fs::is_empty(dir_))) {
    throw InputError(dir_.string(), "", "exists and is not an empty folder; choose another " + option_);
  }
}

void RunFolder::Unlock() {
  if (lock_fd_ >= 0) ::close(lock_fd_);
  lock_fd_ = -1;
}

bool RunFolder::TryCreate() {
  // The folder is made under a private name with its marker locked inside, then renamed into
  // place without replacing anything: no other run ever sees it without the marker.
  static std::atomic<int> counter{0};
  std::string name = ".";  // built by appends: GCC 12 warns falsely (-Wrestrict) on "." + string
  name += work_dir_.filename().string();
  name += ".new-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  const fs::path staging = work_dir_.parent_path() / name;
  if (::mkdir(staging.c_str(), 0777) != 0) {
    throw InputError(work_dir_.string(), "", "cannot be created: " + Errno());
  }
  const fs::path marker = staging / kRunMarker;
  const int fd = ::open(marker.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  const std::string text = "made by romunect " + job_ + " (pid " + std::to_string(::getpid()) + ")\n";
  if (fd < 0 || ::write(fd, text.data(), text.size()) != static_cast<ssize_t>(text.size()) ||
      ::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const std::string error = Errno();
    if (fd >= 0) ::close(fd);
    std::error_code ec;
    fs::remove_all(staging, ec);
    throw InputError(work_dir_.string(), "", "cannot be created: " + error);
  }
  int moved = ::renameat2(AT_FDCWD, staging.c_str(), AT_FDCWD, work_dir_.c_str(), RENAME_NOREPLACE);
  if (moved != 0 && errno == EINVAL && !fs::exists(work_dir_)) {  // a filesystem without RENAME_NOREPLACE
    moved = ::rename(staging.c_str(), work_dir_.c_str());         // fails on a run's folder: it is not empty
  }
  if (moved == 0) {
    lock_fd_ = fd;
    return true;
  }
  const int error = errno;
  ::close(fd);
  std::error_code ec;
  fs::remove_all(staging, ec);
  if (error == EEXIST || error == ENOTEMPTY) return false;
  throw InputError(work_dir_.string(), "", "cannot be created: " + std::string(std::strerror(error)));
}

bool RunFolder::RemoveIfStale(bool take_over) {
  const fs::path marker = work_dir_ / kRunMarker;
  const int fd = ::open(marker.c_str(), O_RDWR | O_CLOEXEC | O_NOFOLLOW);
  if (fd < 0) {
    if (!fs::exists(work_dir_)) return false;  // gone meanwhile: try again
    throw InputError(work_dir_.string(), "",
                     "exists and was not made by romunect (no " + std::string(kRunMarker) +
                         " inside); it is left alone: move it away or choose another " + option_);
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const std::string holder = MarkerText(fd);
    ::close(fd);
    throw InputError(work_dir_.string(), "",
                     "another run is writing into it (" + holder + "); wait for it or choose another " + option_);
  }
  // Locked: the run that made it is gone. Unless the folder was replaced between open and lock,
  // it is a killed run's, and ours to remove.
  struct stat locked {
  }, now{};
  const bool same = ::fstat(fd, &locked) == 0 && ::stat(marker.c_str(), &now) == 0 && locked.st_ino == now.st_ino &&
                    locked.st_dev == now.st_dev;
  if (same && take_over) {
    lock_fd_ = fd;
    const std::string text = "made by romunect " + job_ + " (pid " + std::to_string(::getpid()) + ", resumed)\n";
    const bool named = ::ftruncate(fd, 0) == 0 && ::pwrite(fd, text.data(), text.size(), 0) >= 0;
    (void)named;  // the text only names the holder in messages
    // A write cut by the kill leaves its temporary (".NAME.tmp-PID-N.EXT"): never part of a run.
    std::error_code ec;
    std::vector<fs::path> stale;
    for (auto it = fs::recursive_directory_iterator(work_dir_, ec); !ec && it != fs::recursive_directory_iterator();
         it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (name.size() > 1 && name[0] == '.' && name.find(".tmp-") != std::string::npos && it->is_regular_file(ec)) {
        stale.push_back(it->path());
      }
    }
    for (const fs::path& p : stale) fs::remove(p, ec);
    return true;
  }
  std::error_code ec;
  if (same) fs::remove_all(work_dir_, ec);
  ::close(fd);
  if (ec) throw InputError(work_dir_.string(), "", "a killed run's folder cannot be removed: " + ec.message());
  return false;
}

void RunFolder::Begin() { Start(/*take_over=*/false); }

bool RunFolder::Resume() { return Start(/*take_over=*/true); }

bool RunFolder::Start(bool take_over) {
  std::error_code ec;
  fs::create_directories(dir_.parent_path().empty() ? fs::path(".") : dir_.parent_path(), ec);
  if (ec) throw InputError(dir_.string(), "", "its parent folder cannot be created: " + ec.message());
  for (int attempt = 0; attempt < 4 && !begun_; ++attempt) {
    if (TryCreate()) {
      begun_ = true;
    } else if (RemoveIfStale(take_over)) {
      begun_ = taken_over_ = true;
    }
  }
  if (!begun_) throw InputError(work_dir_.string(), "", "other runs keep replacing it; choose another " + option_);
  CheckFinalNameIsFree();  // a run that finished while this one waited to start: throws, and ~RunFolder cleans up
  return taken_over_;
}

void RunFolder::Commit() {
  if (fs::exists(dir_)) {
    if (!fs::is_directory(dir_) || !fs::is_empty(dir_)) {
      done_ = true;  // the finished run stays where it is, without the marker: no later run removes it
      std::error_code ec;
      fs::remove(work_dir_ / kRunMarker, ec);
      Unlock();
      throw InputError(dir_.string(), "",
                       "was filled while the " + job_ + " ran; the finished run is in " + work_dir_.string());
    }
    fs::remove(dir_);  // the empty folder the run replaces
  }
  // Renamed with its marker, which goes right after: a folder under the work name always has one.
  fs::rename(work_dir_, dir_);
  done_ = true;
  Unlock();
  fs::remove(dir_ / kRunMarker);
}

std::optional<ChangedOption> FindChangedOption(const fs::path& file, const std::string& now_json,
                                               const std::vector<std::string>& ignored) {
  if (std::error_code ec; !fs::is_regular_file(file, ec)) {
    throw InputError(file.string(), "", "missing: the interrupted run left no options to check; run without --resume");
  }
  nlohmann::json recorded;
  try {
    recorded = nlohmann::json::parse(ReadInputFile(file, 1 << 20, "options file"));
  } catch (const nlohmann::json::exception& e) {
    throw InputError(file.string(), "", std::string("not valid JSON: ") + e.what());
  }
  if (!recorded.is_object()) throw InputError(file.string(), "", "not a JSON object");
  const nlohmann::json now = nlohmann::json::parse(now_json);
  for (const auto& [key, value] : now.items()) {
    if (std::find(ignored.begin(), ignored.end(), key) != ignored.end()) continue;
    const auto was = recorded.find(key);
    if (was == recorded.end() || *was != value) {
      return ChangedOption{key, was == recorded.end() ? "missing" : was->dump(), value.dump()};
    }
  }
  return std::nullopt;
}

FolderLock::FolderLock(const fs::path& folder, const std::string& option, const std::string& job)
    : path_(fs::path(WithoutTrailingSeparators(folder).string() + ".lock")) {
  std::error_code ec;
  fs::create_directories(path_.parent_path().empty() ? fs::path(".") : path_.parent_path(), ec);
  for (int attempt = 0; attempt < 4; ++attempt) {
    const int fd = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
    if (fd < 0) throw InputError(option, "", path_.string() + ": cannot be created: " + Errno());
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const std::string holder = MarkerText(fd);
      ::close(fd);
      throw InputError(option, "",
                       WithoutTrailingSeparators(folder).string() + ": another run is writing into it (" + holder +
                           "; " + path_.string() + "); wait for it or choose another " + option);
    }
    // The file may have been released and removed between open and lock: lock the one at the path.
    struct stat locked {
    }, now{};
    if (::fstat(fd, &locked) == 0 && ::stat(path_.c_str(), &now) == 0 && locked.st_ino == now.st_ino &&
        locked.st_dev == now.st_dev) {
      const std::string text = "made by romunect " + job + " (pid " + std::to_string(::getpid()) + ")\n";
      const bool named = ::ftruncate(fd, 0) == 0 && ::pwrite(fd, text.data(), text.size(), 0) >= 0;
      (void)named;  // the text only names the holder in messages: a lock without it still holds
      fd_ = fd;
      return;
    }
    ::close(fd);
  }
  throw InputError(option, "", path_.string() + ": other runs keep replacing it");
}

FolderLock::~FolderLock() {
  if (fd_ < 0) return;
  ::unlink(path_.c_str());  // while still locked: a waiter that opened it sees another inode and retries
  ::close(fd_);
}

}  // namespace romunect::jobs
