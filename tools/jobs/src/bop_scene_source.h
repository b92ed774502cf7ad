// A scene folder of a BOP dataset (`romunect dataset`'s, or any BOP-scenewise one with depth and
// camera poses) as a frame source: its images in id order, depth from depth/ (depth_scale of
// scene_camera.json), the camera from the dataset's camera.json, T_W_C from cam_R_w2c and
// cam_t_w2c (mm). So `romunect fuse` fuses a dataset's scene like a scan.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/world_box.h"

namespace romunect::jobs {

// Whether camera.json's width or height is a whole number of pixels in [1, 65536]: read as an
// int, a float such as 1e30 would not fit. (`fuse` refuses others, `dataset check` reports them.)
bool IsImageSide(const nlohmann::json& value);

// Whether `dir` looks like a BOP scene folder (scene_camera.json and depth/).
bool IsBopScene(const std::filesystem::path& dir);

// The box to fuse that the scene's scene_info.json records (romunect's extra), if any.
std::optional<WorldBox> BopSceneRegion(const std::filesystem::path& dir);

// Reads scene_camera.json and ../../camera.json; throws InputError naming the file and field.
std::unique_ptr<FrameSource> OpenBopScene(const std::filesystem::path& dir);

}  // namespace romunect::jobs
