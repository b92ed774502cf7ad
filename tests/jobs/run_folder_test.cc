// The run-folder transaction: refusals before any work, the rename when complete, nothing left
// behind by a run that fails.
#include <atomic>
#include <filesystem>
#include <iterator>
#include <map>
#include <string>
#include <thread>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/run_folder.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::InputErrorOf;
using testing::ReadText;
using testing::ScratchDir;
using testing::WriteText;

TEST(RunFolder, RefusesAFolderThatHoldsAnythingAndTouchesNothing) {
  ScratchDir dir("run_folder");
  WriteText(dir / "mine" / "notes.txt", "precious");
  EXPECT_THAT(InputErrorOf([&] { RunFolder run((dir / "mine").string() + "/", "--out", "scan"); }),
              HasSubstr((dir / "mine").string() + ": exists and is not an empty folder; choose another --out"));
  WriteText(dir / "file", "precious");
  EXPECT_THAT(InputErrorOf([&] { RunFolder run((dir / "file").string(), "--out", "scan"); }),
              HasSubstr("exists and is not an empty folder"));
  WriteText(dir / "done" / "report.json", "{}");
  EXPECT_THAT(InputErrorOf([&] { RunFolder run((dir / "done").string(), "--out", "scan"); }),
              HasSubstr("holds a finished scan (report.json); choose another --out"));
  EXPECT_THAT(InputErrorOf([&] { RunFolder run(".", "--out", "scan"); }),
              HasSubstr("--out: '.' names no folder of its own"));
  EXPECT_THAT(InputErrorOf([&] { RunFolder run((dir / "file" / "run").string(), "--out", "scan"); }),
              HasSubstr("file is not a folder"));
  EXPECT_EQ(ReadText(dir / "mine" / "notes.txt"), "precious");
  EXPECT_EQ(ReadText(dir / "file"), "precious");
  EXPECT_FALSE(fs::exists(dir / "mine.incomplete"));
}

TEST(RunFolder, BuildsInTheWorkFolderAndRenamesWhenComplete) {
  ScratchDir dir("run_folder");
  fs::create_directories(dir / "empty");  // an empty folder is replaced
  WriteText(dir / "empty.incomplete" / "stale.txt", "from a run that was killed");
  WriteText(dir / "empty.incomplete" / kRunMarker, "made by romunect scan (pid 1)\n");  // and unlocked
  RunFolder run((dir / "empty").string(), "--out", "scan");
  EXPECT_EQ(run.dir(), dir / "empty");
  EXPECT_EQ(run.work_dir(), fs::path((dir / "empty").string() + ".incomplete"));
  run.Begin();
  EXPECT_FALSE(fs::exists(run.work_dir() / "stale.txt"));
  WriteText(run.work_dir() / "report.json", "{}");
  run.Commit();
  EXPECT_EQ(ReadText(dir / "empty" / "report.json"), "{}");
  EXPECT_FALSE(fs::exists(dir / "empty" / kRunMarker));
  EXPECT_FALSE(fs::exists(run.work_dir()));
}

// Resume takes a killed run's work folder over with its files; with none it starts a fresh one;
// a folder another run holds is refused as by Begin.
TEST(RunFolder, ResumeTakesOverAKilledRunsWorkFolderWithItsFiles) {
  ScratchDir dir("run_folder");
  WriteText(dir / "killed.incomplete" / "frame.png", "finished before the kill");
  WriteText(dir / "killed.incomplete" / kRunMarker, "made by romunect scan (pid 1)\n");  // and unlocked
  RunFolder run((dir / "killed").string(), "--out", "scan");
  EXPECT_TRUE(run.Resume());
  EXPECT_EQ(ReadText(run.work_dir() / "frame.png"), "finished before the kill");
  RunFolder second((dir / "killed").string(), "--out", "scan");
  const std::string refused = InputErrorOf([&] { second.Resume(); });
  EXPECT_NE(refused.find("another run is writing into it"), std::string::npos) << refused;
  run.Commit();
  EXPECT_EQ(ReadText(dir / "killed" / "frame.png"), "finished before the kill");
  EXPECT_FALSE(fs::exists(dir / "killed" / kRunMarker));
  RunFolder fresh((dir / "fresh").string(), "--out", "scan");
  EXPECT_FALSE(fresh.Resume());
  EXPECT_EQ(std::distance(fs::directory_iterator(fresh.work_dir()), fs::directory_iterator()), 1);  // the marker
}

// A work folder without the marker was not made by romunect: refused, and never removed.
TEST(RunFolder, NeverRemovesAWorkFolderItDidNotMake) {
  ScratchDir dir("run_folder");
  WriteText(dir / "run.incomplete" / "notes.txt", "the user's");
  RunFolder run((dir / "run").string(), "--out", "scan");
  EXPECT_THAT(InputErrorOf([&] { run.Begin(); }),
              HasSubstr("run.incomplete: exists and was not made by romunect (no .romunect-run inside)"));
  EXPECT_EQ(ReadText(dir / "run.incomplete" / "notes.txt"), "the user's");
  EXPECT_FALSE(fs::exists(dir / "run"));
}

// The files of a small run, the same for every run: what a lone run leaves.
void WriteRun(const fs::path& work) {
  for (int i = 0; i < 5; ++i) WriteText(work / ("frame" + std::to_string(i) + ".txt"), std::string(1000 + i, 'a' + i));
  WriteText(work / "report.json", "{\"frames\": 5}");
}

std::map<std::string, std::string> Files(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) files[fs::relative(e.path(), dir).string()] = ReadText(e.path());
  }
  return files;
}

// Two runs into one folder at once, many times: one is refused before any work (in its
// constructor or Begin), the other's folder holds exactly what a lone run writes.
TEST(RunFolder, TwoRunsAtOnceIntoOneFolderOneIsRefusedBeforeAnyWork) {
  ScratchDir dir("run_folder");
  {
    RunFolder lone((dir / "lone").string(), "--out", "scan");
    lone.Begin();
    WriteRun(lone.work_dir());
    lone.Commit();
  }
  const std::map<std::string, std::string> expected = Files(dir / "lone");
  constexpr int kTrials = 200;  // enough to interleave Begin, the work and Commit both ways
  int both_ran = 0;
  for (int trial = 0; trial < kTrials; ++trial) {
    const fs::path out = dir / ("run" + std::to_string(trial));
    std::atomic<int> ready{0};
    std::atomic<int> worked{0}, refused{0};
    std::string refusals[2];
    auto one_run = [&](int k) {
      ready++;
      while (ready < 2) {
      }
      try {
        RunFolder run(out.string(), "--out", "scan");
        run.Begin();
        worked++;  // past Begin: the work starts here
        WriteRun(run.work_dir());
        run.Commit();
      } catch (const InputError& e) {
        refused++;
        refusals[k] = e.what();
      }
    };
    std::thread a(one_run, 0), b(one_run, 1);
    a.join();
    b.join();
    both_ran += worked == 2;
    ASSERT_EQ(refused, 1) << refusals[0] << " | " << refusals[1];
    const std::string why = refusals[0] + refusals[1];
    EXPECT_TRUE(why.find("another run is writing into it (made by romunect scan") != std::string::npos ||
                why.find("holds a finished scan") != std::string::npos ||
                why.find("exists and is not an empty folder") != std::string::npos)
        << why;
    EXPECT_EQ(Files(out), expected);
    EXPECT_FALSE(fs::exists(out.string() + ".incomplete"));
  }
  EXPECT_EQ(both_ran, 0);                                     // the refused run never started its work
  for (const auto& e : fs::directory_iterator(dir.path())) {  // no staging folder left behind
    EXPECT_EQ(e.path().filename().string().find(".new-"), std::string::npos) << e.path();
  }
}

TEST(RunFolder, CreatesMissingParentsOnCommit) {
  ScratchDir dir("run_folder");
  RunFolder run((dir / "a" / "b" / "run").string(), "--out", "scan");
  run.Begin();
  run.Commit();
  EXPECT_TRUE(fs::is_directory(dir / "a" / "b" / "run"));
}

TEST(RunFolder, LeavesNothingWhenTheRunFails) {
  ScratchDir dir("run_folder");
  EXPECT_THROW(
      {
        RunFolder run((dir / "run").string(), "--out", "scan");
        run.Begin();
        WriteText(run.work_dir() / "half.txt", "half a run");
        throw InputError("test", "", "the run failed");
      },
      InputError);
  EXPECT_FALSE(fs::exists(dir / "run"));
  EXPECT_FALSE(fs::exists(dir / "run.incomplete"));
}

TEST(RunFolder, KeepsTheFinishedRunWhenTheFolderWasFilledMeanwhile) {
  ScratchDir dir("run_folder");
  RunFolder run((dir / "run").string(), "--out", "scan");
  run.Begin();
  WriteText(run.work_dir() / "report.json", "{}");
  WriteText(dir / "run" / "other.txt", "someone else's");
  EXPECT_THAT(InputErrorOf([&] { run.Commit(); }),
              HasSubstr("was filled while the scan ran; the finished run is in " + run.work_dir().string()));
  EXPECT_EQ(ReadText(dir / "run" / "other.txt"), "someone else's");
  EXPECT_EQ(ReadText(run.work_dir() / "report.json"), "{}");
}

// Runs that write into a folder in place (calibrate, record, render) hold <folder>.lock: a second
// one is refused, naming the first; the lock file goes with the lock; a killed run's file is taken.
TEST(FolderLock, ASecondRunIsRefusedUntilTheFirstEnds) {
  ScratchDir dir("folder_lock");
  {
    const FolderLock first(dir / "out", "--out", "calibrate");
    EXPECT_EQ(first.path(), fs::path((dir / "out").string() + ".lock"));
    EXPECT_THAT(InputErrorOf([&] { FolderLock second(dir / "out/", "--out", "calibrate"); }),
                HasSubstr("out: another run is writing into it (made by romunect calibrate (pid "));
    EXPECT_EQ(InputErrorOf([&] { FolderLock other(dir / "other", "--out", "calibrate"); }), "");
  }
  EXPECT_FALSE(fs::exists(dir / "out.lock"));
  WriteText(dir / "out.lock", "made by romunect record (pid 1)\n");  // a killed run's, unlocked
  EXPECT_EQ(InputErrorOf([&] { FolderLock again(dir / "out", "--out", "calibrate"); }), "");
  EXPECT_FALSE(fs::exists(dir / "out.lock"));
}

// Many runs at once on one folder: at every moment at most one holds the lock.
TEST(FolderLock, AtMostOneHolderAtOnce) {
  ScratchDir dir("folder_lock");
  std::atomic<int> holders{0}, most{0}, taken{0};
  auto runs = [&] {
    for (int i = 0; i < 200; ++i) {
      try {
        const FolderLock lock(dir / "out", "--out", "record");
        most = std::max(most.load(), ++holders);
        taken++;
        holders--;
      } catch (const InputError&) {
      }
    }
  };
  std::thread a(runs), b(runs), c(runs);
  a.join();
  b.join();
  c.join();
  EXPECT_EQ(most, 1);
  EXPECT_GT(taken, 0);
  EXPECT_FALSE(fs::exists(dir / "out.lock"));
}

}  // namespace
}  // namespace romunect::jobs
