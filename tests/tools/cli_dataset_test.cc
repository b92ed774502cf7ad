// `romunect dataset` through the binary, as a user and a cluster run it: killed with SIGKILL
// and rerun, or two shards at once in one folder, it writes the bytes of one uninterrupted run;
// bad options exit with 2 and write nothing; `dataset check` exits 0 on a good dataset.
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <map>
#include <thread>

#include <gtest/gtest.h>

#include "romunect/testing/test_support.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using testing::ReadText;
using testing::RunRomunect;
using testing::ScratchDir;

const char* kTiny =
    " --scenes 3 --kinds pill_box,gear --objects 2-3 --variants 2 --views random --views-per-scene 4 --quiet";

std::map<std::string, std::string> Tree(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) files[fs::relative(entry.path(), dir).string()] = ReadText(entry.path());
  }
  return files;
}

// Starts romunect with `arguments` (split at spaces) without waiting; returns its pid. With
// max_file_bytes > 0, no file it writes may grow beyond that (a full disk, as the process sees it).
pid_t Start(const std::string& arguments, rlim_t max_file_bytes = 0) {
  std::vector<std::string> words = {testing::RomunectBinary().string()};
  std::istringstream in(arguments);
  for (std::string w; in >> w;) words.push_back(w);
  const pid_t pid = fork();
  if (pid == 0) {
    if (max_file_bytes > 0) {
      signal(SIGXFSZ, SIG_IGN);  // a write past the limit fails (EFBIG) instead of killing
      const rlimit limit{max_file_bytes, max_file_bytes};
      setrlimit(RLIMIT_FSIZE, &limit);
    }
    std::vector<char*> argv;
    for (auto& w : words) argv.push_back(w.data());
    argv.push_back(nullptr);
    freopen("/dev/null", "w", stderr);
    freopen("/dev/null", "w", stdout);
    execv(argv[0], argv.data());
    _exit(127);
  }
  return pid;
}

int Wait(pid_t pid) {
  int status = 0;
  waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

// Whether a scene is being written: an .incomplete folder with an image in it.
bool SceneInProgress(const fs::path& dir) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir / "train", ec)) {
    if (entry.path().extension() == ".incomplete" && !fs::is_empty(entry.path() / "gray", ec) && !ec) return true;
  }
  return false;
}

TEST(CliDataset, KilledAtAnyMomentAndRerunEqualsAnUninterruptedRun) {
  ScratchDir dir("cli_dataset_kill");
  const auto whole = RunRomunect("dataset " + (dir / "whole").string() + kTiny);
  ASSERT_EQ(whole.exit_code, 0) << whole.output;
  const auto check = RunRomunect("dataset check " + (dir / "whole").string());
  EXPECT_EQ(check.exit_code, 0) << check.output;

  // SIGKILL while the second scene is being written (the first is complete by then)
  const fs::path killed = dir / "killed";
  const pid_t pid = Start("dataset " + killed.string() + kTiny);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!(fs::exists(killed / "train/000000") && SceneInProgress(killed)) &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  kill(pid, SIGKILL);
  EXPECT_EQ(Wait(pid), -SIGKILL);
  ASSERT_TRUE(fs::exists(killed / "train/000000.incomplete") || fs::exists(killed / "train/000001.incomplete") ||
              fs::exists(killed / "train/000002.incomplete"))
      << "the run ended before it was killed";
  const auto rerun = RunRomunect("dataset " + killed.string() + kTiny);
  ASSERT_EQ(rerun.exit_code, 0) << rerun.output;
  EXPECT_TRUE(Tree(dir / "whole") == Tree(killed));
}

TEST(CliDataset, AFullDiskFailsWithTheFileAndLeavesNoSceneComplete) {
  ScratchDir dir("cli_dataset_full");
  ASSERT_EQ(RunRomunect("dataset " + (dir / "whole").string() + kTiny).exit_code, 0);
  // 200 kB per file: the models fit, an IR image (about 290 kB) does not
  const fs::path full = dir / "full";
  EXPECT_EQ(Wait(Start("dataset " + full.string() + kTiny, 200 * 1024)), 1);
  EXPECT_TRUE(fs::exists(full / "train/000000.incomplete"));
  EXPECT_FALSE(fs::exists(full / "train/000000"));
  // with room again, the rerun completes the same dataset
  ASSERT_EQ(RunRomunect("dataset " + full.string() + kTiny).exit_code, 0);
  EXPECT_TRUE(Tree(dir / "whole") == Tree(full));
}

TEST(CliDataset, TwoShardsAtOnceInOneFolderEqualOneRun) {
  ScratchDir dir("cli_dataset_shards");
  ASSERT_EQ(RunRomunect("dataset " + (dir / "whole").string() + kTiny).exit_code, 0);
  const pid_t a = Start("dataset " + (dir / "sharded").string() + kTiny + " --shard 0/2");
  const pid_t b = Start("dataset " + (dir / "sharded").string() + kTiny + " --shard 1/2");
  EXPECT_EQ(Wait(a), 0);
  EXPECT_EQ(Wait(b), 0);
  EXPECT_TRUE(Tree(dir / "whole") == Tree(dir / "sharded"));
}

TEST(CliDataset, BadOptionsExitWithTwoNamingTheOptionAndWriteNothing) {
  ScratchDir dir("cli_dataset_bad");
  const std::string out = (dir / "ds").string();
  for (const auto& [arguments, option] : std::vector<std::pair<std::string, std::string>>{
           {" --kinds pill_box,spoon", "--kinds"}, {" --objects 1-80", "--objects"}, {" --shard 3/2", "--shard"}}) {
    const auto r = RunRomunect("dataset " + out + arguments);
    EXPECT_EQ(r.exit_code, 2) << arguments << ": " << r.output;
    EXPECT_NE(r.output.find(option), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(out)) << arguments;
  }
  const auto none = RunRomunect("dataset check " + out);
  EXPECT_EQ(none.exit_code, 2) << none.output;
}

}  // namespace
}  // namespace romunect
