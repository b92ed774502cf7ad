// The run-folder transaction: refusals before any work, the rename when complete, nothing left
// behind by a run that fails.
#include <filesystem>

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
  WriteText(dir / "empty.incomplete" / "stale.txt", "from a run that crashed");
  RunFolder run((dir / "empty").string(), "--out", "scan");
  EXPECT_EQ(run.dir(), dir / "empty");
  EXPECT_EQ(run.work_dir(), fs::path((dir / "empty").string() + ".incomplete"));
  run.Begin();
  EXPECT_FALSE(fs::exists(run.work_dir() / "stale.txt"));
  WriteText(run.work_dir() / "report.json", "{}");
  run.Commit();
  EXPECT_EQ(ReadText(dir / "empty" / "report.json"), "{}");
  EXPECT_FALSE(fs::exists(run.work_dir()));
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

}  // namespace
}  // namespace romunect::jobs
