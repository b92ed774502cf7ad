// The virtual OpenNI2 device: an OpenNI2 driver plug-in (libRomunectVirtual.so.0, built by this
// project into <build>/lib/OpenNI2/Drivers) that presents a frame directory as a PS1080-like
// device, so the real OpenNI2 code path runs end to end without a Kinect (docs/hardware.md).
//
// A device is named by a URI:  romunect:<frame directory>[?key=value&...]
// (OpenNI2Source makes a relative directory absolute; OpenNI2 itself needs an absolute one)
//   pace=realtime   frames at their frames.json times (default), like a real device
//   pace=step       one frame set per step request (OpenNI2Source sends it before each frame),
//                   so no frame can be dropped: deterministic tests and offline runs
//   stop_after=N    the device stops sending after N frames, like an unplugged sensor
//   loop=1          start again at the first frame after the last (realtime only; viewers)
//   fps=F           the frame rate it announces (default: from the frame times, else 30)
//   impersonate=ps1080  announce the device as PrimeSense's PS1080 (vendor "PrimeSense", name
//                   "PS1080", USB ids 1d27:0600), for programs that look for one
// The same device also presents live frames from a feed library (feed_abi.h), by default the
// simulator's (sim/openni2_feed, libRomunectSimFeed.so beside the driver folder):
//   romunect-sim:?[driver keys above except loop][&feed=/abs/libX.so][&the feed's own keys]
// The driver keys are read by the driver; every other key is handed to the feed.
// As a PS1080: depth in ONI_PIXEL_FORMAT_DEPTH_1_MM and DEPTH_100_UM and IR in GRAY16, each at
// half the directory's resolution (the default, 1 mm: the PS1080's QVGA) and at it; colour, when
// the frames carry it, in RGB888 (VGA first), YUV422 and YUYV at the colour camera's size and half
// of it, with depth-to-colour registration; mirroring and cropping as stream properties; frames a
// slow source misses dropped, not delayed; the end of a finite source raised as OpenNI2's EOF state
// and device-disconnected events; a frame directory opens in one process at a time
// (docs/hardware.md). Any OpenNI2 program opens the device named by the environment
// variable ROMUNECT_VIRTUAL_DEVICE (a URI or a plain directory) as its first device. romunect's
// programs resolve a relative directory there against their working directory; in other programs
// the driver refuses it (libOpenNI2 reads drivers in a working directory of its own) and says so
// on stderr.
#pragma once

#include <filesystem>
#include <string>

namespace romunect::openni2 {

struct VirtualDeviceOptions {
  enum class Pace { kRealtime, kStep };
  Pace pace = Pace::kRealtime;
  int stop_after = -1;  // frames sent before the device goes silent; -1 = never
  bool loop = false;    // repeat the directory forever (realtime pace only)
  double fps = 0.0;     // announced frame rate (Hz); 0 = from the frame times
  bool impersonate_ps1080 = false;  // announce PrimeSense's vendor, name and USB ids

  // Why the options are unusable, or "" when they are valid.
  std::string Problem() const;
};

// The URI that opens `frame_dir` (made absolute) as a virtual device with `options`.
// Throws InputError if the options are invalid or the path holds '?' (the URI's separator).
std::string VirtualDeviceUri(const std::filesystem::path& frame_dir, const VirtualDeviceOptions& options = {});

// The URI of a live feed device (see above): `feed_query` holds the feed's own keys.
// Throws InputError if the options are invalid (loop is not offered for feeds).
std::string SimFeedUri(const std::string& feed_query, const VirtualDeviceOptions& options = {});

// OpenNI2's private device command that asks a step-paced virtual device for the next frame set.
inline constexpr int kVirtualDeviceStepCommand = 0x524D0001;  // 'RM' 0001

}  // namespace romunect::openni2
