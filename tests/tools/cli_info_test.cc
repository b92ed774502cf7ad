#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/testing/test_support.h"

namespace romunect {
namespace {
using testing::RunRomunect;
using testing::ScratchDir;

TEST(Cli, VersionAndHelp) {
  const auto version = RunRomunect("--version");
  EXPECT_EQ(version.exit_code, 0);
  EXPECT_NE(version.output.find("romunect 0."), std::string::npos) << version.output;
  const auto help = RunRomunect("info --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("DIR"), std::string::npos);
}

TEST(Cli, NoSubcommandOrUnknownOptionFails) {
  EXPECT_NE(RunRomunect("").exit_code, 0);
  EXPECT_NE(RunRomunect("info --bogus x").exit_code, 0);
}

TEST(Cli, InfoSummarizesAFrameDirectory) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 4);
  const auto r = RunRomunect("info " + dir.path().string());
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("frames: 3"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("80 x 60"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("valid depth pixels"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("camera positions"), std::string::npos) << r.output;
}

TEST(Cli, InfoRejectsBadInputWithFileAndField) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 4);
  auto doc = nlohmann::json::parse(testing::ReadText(dir / "frames.json"));
  doc["frames"][0]["T_W_C"][5] = 7.0;
  testing::WriteText(dir / "frames.json", doc.dump());
  const auto r = RunRomunect("info " + dir.path().string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("frames.json: frames[0].T_W_C: not a rigid transform"), std::string::npos) << r.output;

  const auto missing = RunRomunect("info " + (dir / "nope").string());
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.output.find("not a directory"), std::string::npos) << missing.output;
}

}  // namespace
}  // namespace romunect
