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
  // It names the built-in scene within the scenes folder, so a moved checkout still reloads it.
  const auto saved = nlohmann::json::parse(testing::ReadText(dir / "scene.json"));
  EXPECT_EQ(saved["scene_file"], "default/scene.xml");
  EXPECT_EQ(saved["scene_file_relative_to"], "romunect scenes");
}

// A 20 mm cube in millimetres, as an OBJ.
void WriteCubeObjMm(const std::filesystem::path& path) {
  std::string text;
  for (int i = 0; i < 8; ++i) {
    text += "v " + std::to_string(i & 1 ? 10 : -10) + " " + std::to_string(i & 2 ? 10 : -10) + " " +
            std::to_string(i & 4 ? 10 : -10) + "\n";
  }
  text += "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
  testing::WriteText(path, text);
}

TEST(PileTest, SavedSceneNamesUserFilesAbsolutelyAndRefusesMissingOnes) {
  testing::ScratchDir dir("sim_pile_paths");
  WriteCubeObjMm(dir / "cube.obj");
  WorldOptions options;
  options.objects.push_back(MakeUserMeshObject(dir / "cube.obj", 1e-3, IrMaterial{}));
  World world(options);
  SaveSettledScene(world, dir / "scene.json");
  const auto saved = nlohmann::json::parse(testing::ReadText(dir / "scene.json"));
  const std::filesystem::path mesh = saved["objects"][0]["file"].get<std::string>();
  EXPECT_TRUE(mesh.is_absolute()) << mesh;  // a user's file: reloads from any working directory
  EXPECT_FALSE(saved["objects"][0].contains("file_relative_to"));

  // A version 1 file (absolute scene path) still loads, to the same world.
  nlohmann::json v1 = saved;
  v1["version"] = 1;
  v1["scene_file"] = (ScenesDir() / "default" / "scene.xml").string();
  v1.erase("scene_file_relative_to");
  testing::WriteText(dir / "v1.json", v1.dump());
  EXPECT_EQ(LoadSettledScene(dir / "v1.json").composed_xml(), world.composed_xml());

  auto expect_refused = [&](const nlohmann::json& j, const std::string& field) {
    testing::WriteText(dir / "bad.json", j.dump());
    try {
      LoadSettledScene(dir / "bad.json");
      ADD_FAILURE() << "accepted a scene with a bad " << field;
    } catch (const InputError& e) {
      EXPECT_EQ(e.field(), field) << e.what();
    }
  };
  nlohmann::json moved = saved;
  moved["scene_file"] = "default/no_such_scene.xml";
  expect_refused(moved, "scene_file");
  nlohmann::json relative = v1;
  relative["scene_file"] = "default/scene.xml";  // relative, but to nothing said
  expect_refused(relative, "scene_file");
  nlohmann::json other_root = saved;
  other_root["scene_file_relative_to"] = "somewhere";
  expect_refused(other_root, "scene_file_relative_to");
  std::filesystem::remove(dir / "cube.obj");
  expect_refused(saved, "objects[0].file");
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
  testing::WriteText(
      dir / "scene.json",
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
