// The dataset job in-process: a tiny dataset passes its check, shards in either order equal one
// run byte for byte, a rerun resumes, bad options are refused before any file, and every rule
// of the check has a case that breaks it.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <tuple>
#include <utility>

#include <Eigen/Core>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/dataset.h"
#include "romunect/tools/jobs/fuse.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using jobs::CheckDataset;
using jobs::DatasetOptions;
using jobs::RunDataset;
using testing::InputErrorOf;
using testing::ReadText;
using testing::ScratchDir;
using testing::WriteText;

// Two scenes of two or three objects, two random views each: a few seconds.
DatasetOptions Tiny(const fs::path& out) {
  DatasetOptions o;
  o.out = out.string();
  o.scenes = 2;
  o.kinds = {"pill_box", "gear", "lego"};
  o.objects = "2-3";
  o.variants = 2;
  o.views = "random";
  o.views_per_scene = 2;
  o.threads = 2;
  o.quiet = true;
  return o;
}

// Every file under dir by relative path, with its bytes.
std::map<std::string, std::string> Tree(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) files[fs::relative(entry.path(), dir).string()] = ReadText(entry.path());
  }
  return files;
}

::testing::AssertionResult SameTree(const fs::path& a, const fs::path& b) {
  const auto ta = Tree(a), tb = Tree(b);
  for (const auto& [name, bytes] : ta) {
    if (!tb.count(name)) return ::testing::AssertionFailure() << name << " only in " << a;
    if (tb.at(name) != bytes) return ::testing::AssertionFailure() << name << " differs";
  }
  for (const auto& [name, bytes] : tb) {
    if (!ta.count(name)) return ::testing::AssertionFailure() << name << " only in " << b;
  }
  return ::testing::AssertionSuccess() << ta.size() << " files equal";
}

class DatasetJob : public ::testing::Test {
 protected:
  // One tiny dataset for the tests that only read it or break copies of it.
  static void SetUpTestSuite() {
    scratch_ = new ScratchDir("dataset_suite_" + std::to_string(getpid()));  // one per test process
    summary_ = new jobs::DatasetSummary(RunDataset(Tiny(scratch_->path() / "ds")));
  }
  static void TearDownTestSuite() {
    delete summary_;
    delete scratch_;
  }
  static fs::path Dataset() { return scratch_->path() / "ds"; }
  // A copy of the dataset to break.
  static fs::path Copy(const ScratchDir& dir) {
    fs::copy(Dataset(), dir / "ds", fs::copy_options::recursive);
    return dir / "ds";
  }
  static ScratchDir* scratch_;
  static jobs::DatasetSummary* summary_;
};
ScratchDir* DatasetJob::scratch_ = nullptr;
jobs::DatasetSummary* DatasetJob::summary_ = nullptr;

TEST_F(DatasetJob, TwoScenesPassTheCheckInBopLayout) {
  EXPECT_EQ(summary_->scenes_written, 2);
  EXPECT_EQ(summary_->images, 4);
  EXPECT_GT(summary_->annotations, 0);
  EXPECT_EQ(summary_->models, 6);  // 3 kinds x 2 variants
  for (const char* file :
       {"camera.json", "dataset.json", "models/models_info.json", "train/000000/scene_camera.json",
        "train/000001/scene_gt.json", "train/000001/scene_gt_info.json", "train/000000/gray/000000.png",
        "train/000000/depth/000001.png", "train/000000/depth_gt/000000.png", "train/000000/raw/000000.png",
        "train/000000/mask/000000_000000.png", "train/000000/mask_visib/000000_000000.png"}) {
    EXPECT_TRUE(fs::exists(Dataset() / file)) << file;
  }
  const auto check = CheckDataset(Dataset().string());
  EXPECT_TRUE(check.problems.empty()) << check.Text();
  EXPECT_EQ(check.scenes, 2);
  EXPECT_EQ(check.images, 4);
  EXPECT_EQ(check.annotations, summary_->annotations);
}

TEST_F(DatasetJob, PosesAreBopsMillimetresAndRowMajorRotations) {
  const auto gt = nlohmann::json::parse(ReadText(Dataset() / "train/000000/scene_gt.json"));
  const auto cam = nlohmann::json::parse(ReadText(Dataset() / "train/000000/scene_camera.json"));
  const auto& first = gt["0"][0];
  Eigen::Matrix3d R;
  for (int i = 0; i < 9; ++i) R(i / 3, i % 3) = first["cam_R_m2c"][i].get<double>();
  EXPECT_LT((R * R.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-9);
  // the romunect rig measures at about 200 mm: objects sit there, in millimetres
  const double z_mm = first["cam_t_m2c"][2].get<double>();
  EXPECT_GT(z_mm, 150.0);
  EXPECT_LT(z_mm, 260.0);
  EXPECT_DOUBLE_EQ(cam["0"]["depth_scale"].get<double>(), 0.1);
}

// The stock Kinect's dataset: the approach and the random views keep the bin within its 0.5-4 m
// range (a table-top scene seen from about 0.8 m), and its depth images measure what the ground
// truth holds, within the Kinect's noise and quantization.
TEST(DatasetStockKinect, ImagesSeeTheBinFromWithinItsRangeAndMeasureIt) {
  ScratchDir dir("dataset_kinect");
  DatasetOptions o = Tiny(dir / "ds");
  o.rig = "kinect-v1";
  o.scenes = 1;
  o.views = "both";
  const jobs::DatasetSummary summary = RunDataset(o);
  ASSERT_GT(summary.images, 2);
  const auto check = CheckDataset(o.out);
  EXPECT_TRUE(check.problems.empty()) << check.Text();
  const fs::path scene = dir / "ds/train/000000";
  const auto cam = nlohmann::json::parse(ReadText(scene / "scene_camera.json"));
  ASSERT_EQ(static_cast<int>(cam.size()), summary.images);
  for (const auto& [key, view] : cam.items()) {
    // Where the camera is: its centre's distance to the bin's floor (the world's origin height).
    Eigen::Matrix3d R;
    Eigen::Vector3d t;
    for (int i = 0; i < 9; ++i) R(i / 3, i % 3) = view["cam_R_w2c"][i].get<double>();
    for (int i = 0; i < 3; ++i) t(i) = view["cam_t_w2c"][i].get<double>();
    const double height_mm = (-R.transpose() * t).z();
    EXPECT_GT(height_mm, 500.0) << key;   // beyond the stock device's near limit (0.48 m)
    EXPECT_LT(height_mm, 1500.0) << key;  // a table-top scene, not the far end of its range
    char name[16];
    std::snprintf(name, sizeof name, "%06d.png", std::stoi(key));
    const cv::Mat depth = cv::imread((scene / "depth" / name).string(), cv::IMREAD_UNCHANGED);
    const cv::Mat truth = cv::imread((scene / "depth_gt" / name).string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(depth.type(), CV_16U) << key;
    int seen = 0, measured = 0, close = 0;
    for (int v = 0; v < depth.rows; ++v) {
      for (int u = 0; u < depth.cols; ++u) {
        const int gt = truth.at<uint16_t>(v, u), d = depth.at<uint16_t>(v, u);
        if (gt == 0) continue;
        ++seen;
        if (d == 0) continue;
        ++measured;
        close += std::abs(d - gt) <= 100;  // 10 mm at 0.1 mm per unit: a few of its codes at 1 m
      }
    }
    ASSERT_GT(seen, 0) << key;
    // The stock device measures nearly all it sees at this range (95-98 %): its projector's
    // shadows beside the objects and their edges are the rest.
    EXPECT_GT(measured, 0.9 * seen) << key;
    EXPECT_GT(close, 0.97 * measured) << key;  // 99.8 %: the rest are edges between surfaces
  }
}

TEST(DatasetViews, TheApproachIsTheArmsOwnTrajectoryEveryKthFrame) {
  ScratchDir dir("dataset_approach");
  DatasetOptions o = Tiny(dir / "ds");
  o.scenes = 1;
  o.views = "approach";
  o.every = 20;  // of the approach's 30 Hz frames (descent and coverage leg: 60 to 150)
  const auto summary = RunDataset(o);
  EXPECT_GE(summary.images, 3);
  EXPECT_LE(summary.images, 8);
  const auto cam = nlohmann::json::parse(ReadText(dir / "ds/train/000000/scene_camera.json"));
  // the camera starts 40 cm above the bin and comes down to the rig's stand-off levels (about
  // 20 cm), sweeping between them
  std::vector<double> height_mm;
  for (int im = 0; im < summary.images; ++im) {
    const auto& entry = cam[std::to_string(im)];
    EXPECT_EQ(entry["view"], "approach");
    Eigen::Matrix3d R;
    for (int i = 0; i < 9; ++i) R(i / 3, i % 3) = entry["cam_R_w2c"][i].get<double>();
    Eigen::Vector3d t;
    for (int i = 0; i < 3; ++i) t(i) = entry["cam_t_w2c"][i].get<double>();
    height_mm.push_back((-R.transpose() * t).z());  // the camera centre in W
  }
  EXPECT_EQ(std::max_element(height_mm.begin(), height_mm.end()), height_mm.begin());
  EXPECT_LT(*std::min_element(height_mm.begin(), height_mm.end()), height_mm[0] - 100.0);
  const auto check = CheckDataset((dir / "ds").string());
  EXPECT_TRUE(check.problems.empty()) << check.Text();
}

TEST_F(DatasetJob, ShardsInEitherOrderEqualOneRunByteForByte) {
  ScratchDir dir("dataset_shards");
  DatasetOptions second = Tiny(dir / "ab"), first = Tiny(dir / "ab");
  second.shard = "1/2";
  first.shard = "0/2";
  first.threads = second.threads = 1;  // bytes do not depend on the thread count either
  EXPECT_EQ(RunDataset(second).scenes_written, 1);
  EXPECT_EQ(RunDataset(first).scenes_written, 1);
  EXPECT_TRUE(SameTree(Dataset(), dir / "ab"));
}

TEST_F(DatasetJob, RerunSkipsCompleteScenesAndRedoesAnIncompleteOne) {
  ScratchDir dir("dataset_resume");
  const fs::path ds = Copy(dir);
  // a run killed in scene 1: its folder under the temporary name, half written
  fs::rename(ds / "train/000001", ds / "train/000001.incomplete");
  fs::remove(ds / "train/000001.incomplete/scene_gt.json");
  const auto before = CheckDataset(ds.string());
  EXPECT_EQ(before.scenes, 1);
  EXPECT_EQ(before.incomplete_scenes, 1);
  const auto summary = RunDataset(Tiny(ds));
  EXPECT_EQ(summary.scenes_skipped, 1);
  EXPECT_EQ(summary.scenes_written, 1);
  EXPECT_FALSE(fs::exists(ds / "train/000001.incomplete"));
  EXPECT_TRUE(SameTree(Dataset(), ds));
}

TEST_F(DatasetJob, ARerunRemovesTheTemporariesOfDeadProcessesOfThisHostOnly) {
  ScratchDir dir("dataset_stale");
  const fs::path ds = Copy(dir);
  const pid_t gone = fork();  // a pid that surely has no process any more
  if (gone == 0) _exit(0);
  waitpid(gone, nullptr, 0);
  char host[256] = {};
  gethostname(host, sizeof host - 1);
  const std::string dead = ".obj_000001.ply.tmp-" + std::string(host) + "-" + std::to_string(gone) + "-0";
  const std::string elsewhere = ".obj_000001.ply.tmp-some-other-node-" + std::to_string(gone) + "-0";
  WriteText(ds / "models" / dead, "half a model");
  WriteText(ds / "models" / elsewhere, "another node's model, being written");
  EXPECT_EQ(RunDataset(Tiny(ds)).scenes_skipped, 2);
  EXPECT_FALSE(fs::exists(ds / "models" / dead));
  EXPECT_TRUE(fs::exists(ds / "models" / elsewhere));
}

TEST_F(DatasetJob, OtherSettingsInTheFolderAreRefusedNamingTheOption) {
  ScratchDir dir("dataset_settings");
  const fs::path ds = Copy(dir);
  DatasetOptions o = Tiny(ds);
  o.seed = 2;
  EXPECT_NE(InputErrorOf([&] { RunDataset(o); }).find("--seed"), std::string::npos);
  o = Tiny(ds);
  o.objects = "2-4";
  EXPECT_NE(InputErrorOf([&] { RunDataset(o); }).find("--objects"), std::string::npos);
  EXPECT_TRUE(SameTree(Dataset(), ds));  // nothing written
}

TEST(DatasetOptions, BadInputIsRefusedNamingTheOptionBeforeAnyFile) {
  ScratchDir dir("dataset_bad");
  const fs::path out = dir / "ds";
  auto refused = [&](const std::function<void(DatasetOptions*)>& change, const std::string& option) {
    DatasetOptions o = Tiny(out);
    change(&o);
    const std::string message = InputErrorOf([&] { RunDataset(o); });
    EXPECT_NE(message.find(option), std::string::npos) << option << ": " << message;
    EXPECT_FALSE(fs::exists(out)) << option;
  };
  refused([](DatasetOptions* o) { o->kinds = {"pill_box", "spoon"}; }, "--kinds");
  refused([](DatasetOptions* o) { o->objects = "2-70"; }, "--objects");   // more than the bin holds
  refused([](DatasetOptions* o) { o->objects = "40-50"; }, "--objects");  // ... of these kinds
  refused([](DatasetOptions* o) { o->objects = "3-2"; }, "--objects");
  refused([](DatasetOptions* o) { o->shard = "3/2"; }, "--shard");
  refused([](DatasetOptions* o) { o->shard = "12"; }, "--shard");  // no N
  refused([](DatasetOptions* o) { o->views = "sideways"; }, "--views");
  refused([](DatasetOptions* o) { o->every = 0; }, "--every");
  refused([](DatasetOptions* o) { o->rig = "kinect-v3"; }, "--rig");
  refused([](DatasetOptions* o) { o->scenes = 0; }, "--scenes");
  // a folder with other things in it is never touched
  fs::create_directories(out);
  WriteText(out / "notes.txt", "mine");
  EXPECT_NE(InputErrorOf([&] { RunDataset(Tiny(out)); }).find("holds notes.txt but no dataset.json"),
            std::string::npos);
  EXPECT_EQ(Tree(out).size(), 1u);
  // a dataset.json that is JSON of the wrong shape is refused, not a type_error
  for (const char* wrong : {"[1, 2]", R"({"format": 2, "settings": {}})", R"({"format": "x"})"}) {
    WriteText(out / "dataset.json", wrong);
    EXPECT_NE(InputErrorOf([&] { RunDataset(Tiny(out)); }).find("format"), std::string::npos) << wrong;
  }
}

TEST_F(DatasetJob, FuseReadsASceneFolderAsAFrameSource) {
  ScratchDir dir("dataset_fuse");
  jobs::FuseOptions o;
  o.source = (Dataset() / "train/000000").string();
  o.out = (dir / "fused").string();
  const jobs::FuseJobSummary fused = jobs::RunFuse(o);
  EXPECT_EQ(fused.report.frames, 2u);  // the scene's two views
  EXPECT_EQ(fused.box_from, "scene_info.json's region_W");
  EXPECT_GT(fused.report.completeness, 0.0);
  EXPECT_TRUE(fs::exists(dir / "fused/report.json"));
}

// docs/datasets.md's Python recipe, as written there but for the dataset's folder and image, reads
// an image of a scene: a line per object in it (Debian 12's python3-opencv and python3-numpy).
TEST_F(DatasetJob, TheDocsPythonRecipeReadsAnImage) {
  const std::string doc = ReadText(fs::path(ROMUNECT_SOURCE_DIR) / "docs" / "datasets.md");
  const size_t begin = doc.find("```python\n", doc.find("## Reading an image in Python"));
  ASSERT_NE(begin, std::string::npos);
  const size_t code = begin + 10, end = doc.find("```", code);
  std::string recipe = doc.substr(code, end - code);
  // the scene's image with the most objects in view
  const auto gt = nlohmann::json::parse(ReadText(Dataset() / "train/000000/scene_gt.json"));
  std::string im;
  size_t objects = 0;
  for (const auto& [id, in_view] : gt.items()) {
    if (in_view.size() > objects) std::tie(im, objects) = std::make_pair(id, in_view.size());
  }
  ASSERT_GT(objects, 0u);
  const std::string where = R"(root, scene, im = "data/bins", "train/000000", 5)";
  ASSERT_NE(recipe.find(where), std::string::npos) << recipe;
  recipe.replace(recipe.find(where), where.size(), "root, scene, im = '" + Dataset().string() + "', 'train/000000', " + im);
  ScratchDir dir("dataset_python_recipe");
  WriteText(dir / "recipe.py", recipe);
  const testing::CommandResult run = testing::RunShell("/usr/bin/python3 '" + (dir / "recipe.py").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output << "\n(needs python3-opencv and python3-numpy: run scripts/setup.sh)";
  EXPECT_EQ(static_cast<size_t>(std::count(run.output.begin(), run.output.end(), '\n')), objects) << run.output;
}

// --- each rule of the check, broken on a copy ---

nlohmann::json ReadJson(const fs::path& file) { return nlohmann::json::parse(ReadText(file)); }
void WriteJson(const fs::path& file, const nlohmann::json& doc) { WriteText(file, doc.dump()); }

// The check's problems joined, for EXPECT on a substring.
std::string Problems(const fs::path& ds) {
  std::string text;
  for (const auto& p : CheckDataset(ds.string()).problems) text += p + "\n";
  return text;
}

TEST_F(DatasetJob, FuseRefusesACameraOfNoWholeSize) {
  ScratchDir dir("dataset_fuse_camera");
  const fs::path ds = Copy(dir);
  jobs::FuseOptions o;
  o.source = (ds / "train/000000").string();
  o.out = (dir / "fused").string();
  for (const nlohmann::json& width : {nlohmann::json(1e20), nlohmann::json(640.5), nlohmann::json(-640)}) {
    auto camera = ReadJson(ds / "camera.json");
    camera["width"] = width;  // 1e20 as an int was undefined behaviour
    WriteJson(ds / "camera.json", camera);
    EXPECT_NE(InputErrorOf([&] { jobs::RunFuse(o); }).find("width"), std::string::npos) << width;
  }
  EXPECT_FALSE(fs::exists(dir / "fused"));
}

TEST_F(DatasetJob, CheckFindsACameraOfNoWholeSize) {
  ScratchDir dir("dataset_check_camera");
  const fs::path ds = Copy(dir);
  auto camera = ReadJson(ds / "camera.json");
  camera["width"] = 1e30;  // read as an int, undefined behaviour
  camera["height"] = 0;
  WriteJson(ds / "camera.json", camera);
  const std::string problems = Problems(ds);
  EXPECT_NE(problems.find("camera.json: width missing or not a whole number of pixels"), std::string::npos) << problems;
  EXPECT_NE(problems.find("camera.json: height missing or not a whole number of pixels"), std::string::npos)
      << problems;
}

TEST_F(DatasetJob, CheckFindsAMissingKeyAndAWrongType) {
  ScratchDir dir("dataset_check_keys");
  const fs::path ds = Copy(dir);
  auto cam = ReadJson(ds / "train/000000/scene_camera.json");
  cam["0"].erase("cam_K");
  WriteJson(ds / "train/000000/scene_camera.json", cam);
  auto gt = ReadJson(ds / "train/000001/scene_gt.json");
  gt["1"][0]["obj_id"] = "one";
  WriteJson(ds / "train/000001/scene_gt.json", gt);
  const std::string problems = Problems(ds);
  EXPECT_NE(problems.find("0: cam_K missing"), std::string::npos) << problems;
  EXPECT_NE(problems.find("1[0]: obj_id is not an obj_id"), std::string::npos) << problems;
}

TEST_F(DatasetJob, CheckFindsAnImageOfTheWrongSize) {
  ScratchDir dir("dataset_check_size");
  const fs::path ds = Copy(dir);
  cv::imwrite((ds / "train/000000/depth_gt/000001.png").string(), cv::Mat(48, 64, CV_16U, cv::Scalar(0)));
  EXPECT_NE(Problems(ds).find("depth_gt/000001.png: 64 x 48"), std::string::npos) << Problems(ds);
}

TEST_F(DatasetJob, CheckFindsVisiblePixelsOutsideTheMaskAndCountsThatDisagree) {
  ScratchDir dir("dataset_check_masks");
  const fs::path ds = Copy(dir);
  const fs::path visib_file = ds / "train/000000/mask_visib/000000_000000.png";
  cv::Mat visib = cv::imread(visib_file.string(), cv::IMREAD_UNCHANGED);
  const cv::Mat mask = cv::imread((ds / "train/000000/mask/000000_000000.png").string(), cv::IMREAD_UNCHANGED);
  cv::Point outside(-1, -1);
  for (int v = 0; v < mask.rows && outside.x < 0; ++v) {
    for (int u = 0; u < mask.cols && outside.x < 0; ++u) {
      if (!mask.at<uint8_t>(v, u)) outside = {u, v};
    }
  }
  ASSERT_GE(outside.x, 0);
  visib.at<uint8_t>(outside) = 255;
  cv::imwrite(visib_file.string(), visib);
  const std::string problems = Problems(ds);
  EXPECT_NE(problems.find("000000_000000.png: 1 pixels outside mask"), std::string::npos) << problems;
  EXPECT_NE(problems.find("0[0]: px_count_visib is"), std::string::npos) << problems;
}

TEST_F(DatasetJob, CheckFindsAVisibleFractionThatIsNotTheRatio) {
  ScratchDir dir("dataset_check_fract");
  const fs::path ds = Copy(dir);
  auto info = ReadJson(ds / "train/000001/scene_gt_info.json");
  info["0"][0]["visib_fract"] = info["0"][0]["visib_fract"].get<double>() * 0.5 + 0.01;
  info["1"][0]["px_count_valid"] = info["1"][0]["px_count_valid"].get<int>() + 1;
  WriteJson(ds / "train/000001/scene_gt_info.json", info);
  const std::string problems = Problems(ds);
  EXPECT_NE(problems.find("0[0]: visib_fract"), std::string::npos) << problems;
  EXPECT_NE(problems.find("1[0]: px_count_valid is"), std::string::npos) << problems;
}

TEST_F(DatasetJob, CheckFindsAPoseOneMillimetreOff) {
  ScratchDir dir("dataset_check_pose");
  const fs::path ds = Copy(dir);
  auto gt = ReadJson(ds / "train/000000/scene_gt.json");
  // 1 mm along the view: ten times the check's tolerance on every visible pixel
  ASSERT_FALSE(gt["0"].empty());
  gt["0"][0]["cam_t_m2c"][2] = gt["0"][0]["cam_t_m2c"][2].get<double>() + 1.0;
  WriteJson(ds / "train/000000/scene_gt.json", gt);
  const std::string problems = Problems(ds);
  EXPECT_NE(problems.find("mask_visib/000000_000000.png: obj_id"), std::string::npos) << problems;
  EXPECT_NE(problems.find("off depth_gt by more than 0.1 mm"), std::string::npos) << problems;
}

TEST_F(DatasetJob, CheckFindsAModelThatIsNotTheRenderedOne) {
  ScratchDir dir("dataset_check_model");
  const fs::path ds = Copy(dir);
  const auto gt = ReadJson(ds / "train/000000/scene_gt.json");
  const int obj_id = gt["0"][0]["obj_id"].get<int>();
  // the PLY scaled by 1.02 about its origin: its surface moves by far more than 0.1 mm
  char name[32];
  std::snprintf(name, sizeof name, "models/obj_%06d.ply", obj_id);
  std::istringstream in(ReadText(ds / name));
  std::string out, line;
  bool header = true;
  int vertices = 0;
  while (std::getline(in, line)) {
    if (!header && vertices > 0) {
      std::istringstream w(line);
      double x, y, z;
      std::string rest;
      w >> x >> y >> z;
      std::getline(w, rest);
      char scaled[128];
      std::snprintf(scaled, sizeof scaled, "%.6f %.6f %.6f", x * 1.02, y * 1.02, z * 1.02);
      line = scaled + rest;
      --vertices;
    }
    if (line.rfind("element vertex ", 0) == 0) vertices = std::stoi(line.substr(15));
    if (line == "end_header") header = false;
    out += line + "\n";
  }
  WriteText(ds / name, out);
  char expected[32];
  std::snprintf(expected, sizeof expected, "obj_id %d:", obj_id);
  EXPECT_NE(Problems(ds).find(expected), std::string::npos) << Problems(ds);
}

TEST(DatasetCheck, AFolderWithoutADatasetIsBadInput) {
  ScratchDir dir("dataset_check_none");
  EXPECT_NE(InputErrorOf([&] { CheckDataset(dir.path().string()); }).find("holds no dataset"), std::string::npos);
}

}  // namespace
}  // namespace romunect
