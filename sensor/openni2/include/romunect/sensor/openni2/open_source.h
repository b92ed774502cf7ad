// One function that turns a source string from the command line into a FrameSource, so that
// `fuse`, `calibrate` and `record` accept a frame directory, a recording or a live device alike:
//
//   DIR                    a frame directory (holds frames.json)      -> FrameDirectorySource
//   FILE.oni               an OpenNI2 recording                       -> OpenNI2Source (file driver)
//   oni://                 the first OpenNI2 device                    -> OpenNI2Source
//   oni://URI              the OpenNI2 device with that URI            -> OpenNI2Source
//   romunect:DIR?...       the virtual device (virtual_device.h)       -> OpenNI2Source
//
// With a pose log, the source is wrapped in a PoseLogSource that sets T_B_H per frame.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/sensor/openni2/pose_log.h"

namespace romunect::openni2 {

struct OpenSourceOptions {
  std::filesystem::path pose_log;  // CSV pose log (pose_log.h); empty = none
  PoseLogSourceOptions pose;       // clock offset and hand-eye, with a pose log
  OpenNI2SourceOptions openni2;    // device options (uri is taken from the string)
  // What a frame directory's loader does with NaN/inf/negative depth pixels.
  InvalidDepthPolicy invalid_depth = InvalidDepthPolicy::kReject;
};

enum class SourceKind { kFrameDirectory, kOniFile, kDevice };

// What kind of source a string names (by its form, without opening anything).
SourceKind ClassifySource(const std::string& source);

// Opens the source; throws InputError naming the string when it fits none of the forms or the
// source cannot be opened.
std::unique_ptr<FrameSource> OpenSource(const std::string& source, const OpenSourceOptions& options = {});

// The source under a PoseLogSource (or `source` itself), as its concrete kind; nullptr when it
// is another kind. For what only one kind reports (a device's chip, a directory's manifest).
OpenNI2Source* FindOpenNI2Source(FrameSource* source);
FrameDirectorySource* FindFrameDirectorySource(FrameSource* source);

}  // namespace romunect::openni2
