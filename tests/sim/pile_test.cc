#include "romunect/sim/pile.h"

#include <filesystem>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect::sim {
namespace {

// A small pile keeps the test fast; every kind appears at least once with 6 objects and seed 3.
PileOptions SmallPile(uint32_t seed) {
  PileOptions options;
  options.num_objects = 6;
  options.seed = seed;
  return options;
}

World SettledWorld(const PileOptions& pile, SettleSummary* summary) {
  WorldOptions options;
  options.objects = MakePileObjects(pile);
  World world(options);
  *summary = DropAndSettle(&world, pile);
  return world;
}

TEST(PileTest, SettlesWithEveryObjectInTheBin) {
  SettleSummary summary;
  World world = SettledWorld(SmallPile(3), &summary);
  std::cout << summary.BriefReport() << "\n";
  EXPECT_TRUE(summary.converged);
  EXPECT_LT(summary.kinetic_energy_j, SmallPile(3).kinetic_energy_threshold_j);
  EXPECT_EQ(summary.objects_in_bin, 6);
}

TEST(PileTest, SameSeedGivesTheSameSettledPosesBitForBit) {
  SettleSummary a_summary, b_summary, c_summary;
  World a = SettledWorld(SmallPile(5), &a_summary);
  World b = SettledWorld(SmallPile(5), &b_summary);
  World c = SettledWorld(SmallPile(6), &c_summary);
  EXPECT_EQ(a.ObjectQpos(), b.ObjectQpos());
  EXPECT_NE(a.ObjectQpos(), c.ObjectQpos());
}

TEST(PileTest, SavedSceneReloadsExactly) {
  testing::ScratchDir dir("sim_pile_save");
  SettleSummary summary;
  World world = SettledWorld(SmallPile(3), &summary);
  SaveSettledScene(world, dir / "scene.json");
  World reloaded = LoadSettledScene(dir / "scene.json");
  ASSERT_EQ(reloaded.num_objects(), world.num_objects());
  EXPECT_EQ(reloaded.ObjectQpos(), world.ObjectQpos());
  for (int i = 0; i < world.num_objects(); ++i) {
    EXPECT_TRUE(reloaded.T_W_O(i).matrix() == world.T_W_O(i).matrix()) << "object " << i;  // bit for bit
  }
  EXPECT_EQ(reloaded.composed_xml(), world.composed_xml());
  // It names its scene by an absolute path, so it reloads from any working directory.
  const auto saved = nlohmann::json::parse(testing::ReadText(dir / "scene.json"));
  EXPECT_TRUE(std::filesystem::path(saved["scene_file"].get<std::string>()).is_absolute());
}

TEST(PileTest, SettleThatNeverConvergesIsReported) {
  PileOptions pile = SmallPile(3);
  pile.num_objects = 2;
  pile.kinetic_energy_threshold_j = 1e-300;  // unreachable: contact solvers never reach exact rest
  pile.max_settle_time_s = 0.05;
  SettleSummary summary;
  World world = SettledWorld(pile, &summary);
  EXPECT_FALSE(summary.converged);
  EXPECT_NE(summary.BriefReport().find("NOT settled"), std::string::npos);
}

TEST(PileTest, BadSavedSceneNamesTheField) {
  testing::ScratchDir dir("sim_pile_bad");
  testing::WriteText(dir / "scene.json",
                     R"({"format": "romunect-scene", "version": 1, "scene_file": "", "objects": [{"kind": "spoon"}], "qpos": []})");
  try {
    LoadSettledScene(dir / "scene.json");
    FAIL() << "no exception";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("objects[0]"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("spoon"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace romunect::sim

namespace romunect::sim {
namespace {

TEST(PileTest, OptionsProblemNamesFieldValueAndRule) {
  EXPECT_EQ(PileOptions{}.Problem(), "");
  PileOptions bad;
  bad.num_objects = -1;
  EXPECT_NE(bad.Problem().find("num_objects = -1"), std::string::npos) << bad.Problem();
  bad = PileOptions{};
  bad.kinds = {ObjectKind::kUserMesh};
  EXPECT_NE(bad.Problem().find("kinds"), std::string::npos) << bad.Problem();
  bad = PileOptions{};
  bad.timestep_s = 0.0;
  EXPECT_NE(bad.Problem().find("timestep_s"), std::string::npos) << bad.Problem();
  EXPECT_EQ(ObjectKindFromString("gear", "test"), ObjectKind::kGear);
  EXPECT_THROW(ObjectKindFromString("spoon", "test"), InputError);
}

}  // namespace
}  // namespace romunect::sim
