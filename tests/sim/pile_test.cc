#include "romunect/sim/pile.h"

#include <algorithm>
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
  nlohmann::json numbered = saved;
  numbered["format"] = 2;  // a fuzzer's find: a format of the wrong type was an uncaught type_error
  expect_refused(numbered, "format");
  expect_refused(nlohmann::json::array({saved}), "format");
  // numbers their fields cannot hold (converting them was undefined behaviour)
  nlohmann::json bright = saved;
  bright["objects"][0]["material"]["albedo"] = 1e300;
  expect_refused(bright, "objects[0].material.albedo");
  for (const nlohmann::json& seed : {nlohmann::json(1e30), nlohmann::json(-1), nlohmann::json(4294967296LL)}) {
    nlohmann::json gear = saved;
    gear["objects"][0]["kind"] = "gear";
    gear["objects"][0]["seed"] = seed;
    expect_refused(gear, "objects[0].seed");
  }
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

// A one-layer pile of each of the paper's kinds at the counts `romunect experiment table1`
// drops: every object found room on the floor and lies there on its broadest face, its highest
// point no higher than its thinnest size (5 % for the seeded size variation, 0.5 mm for MuJoCo's
// soft contact), and the pile settles.
TEST(PileTest, OneLayerPilesLieOnTheFloorSideBySide) {
  const struct {
    ObjectKind kind;
    int count;
    double thickness_m;  // objects.h: the kind's thinnest size
  } bins[] = {{ObjectKind::kKey, 2, 0.003},
              {ObjectKind::kPillBox, 4, 0.016},
              {ObjectKind::kPuzzlePiece, 4, 0.004},
              {ObjectKind::kLegoBrick, 8, 0.0114 + 0.0018}};  // the studs stand 1.8 mm proud
  for (const auto& bin : bins) {
    for (uint32_t seed : {1u, 2u}) {
      PileOptions pile;
      pile.num_objects = bin.count;
      pile.kinds = {bin.kind};
      pile.seed = seed;
      pile.one_layer = true;
      SettleSummary summary;
      World world = SettledWorld(pile, &summary);
      const std::string what = std::string(ToString(bin.kind)) + " seed " + std::to_string(seed);
      EXPECT_TRUE(summary.converged) << what;
      EXPECT_EQ(summary.not_in_one_layer, 0) << what;
      EXPECT_EQ(summary.objects_in_bin, bin.count) << what;
      const Pose T_Bin_W = world.T_W_Bin().inverse();
      for (int i = 0; i < world.num_objects(); ++i) {
        double top_m = -1.0;
        for (const Mesh& part : world.options().objects[i].parts_O) {
          for (const Eigen::Vector3d& v : part.vertices) top_m = std::max(top_m, (T_Bin_W * world.T_W_O(i) * v).z());
        }
        EXPECT_LE(top_m, 1.05 * bin.thickness_m + 0.0005) << what << ", object " << i;
      }
    }
  }
}

// More objects than one layer holds: the ones without room land on the others, and the
// summary says how many.
TEST(PileTest, AOneLayerPileWithoutRoomSaysHowManyLieOnOthers) {
  PileOptions pile;
  pile.num_objects = 6;
  pile.kinds = {ObjectKind::kKey};
  pile.one_layer = true;
  SettleSummary summary;
  World world = SettledWorld(pile, &summary);
  EXPECT_GE(summary.not_in_one_layer, 3);  // 60 x 22 mm keys: at most 2 side by side in 120 x 55 mm
  EXPECT_NE(summary.BriefReport().find("on others (no room on the floor)"), std::string::npos) << summary.BriefReport();
  PileOptions bad;
  bad.one_layer_gap_m = -0.001;
  EXPECT_NE(bad.Problem().find("one_layer_gap_m"), std::string::npos);
}

}  // namespace
}  // namespace romunect::sim
