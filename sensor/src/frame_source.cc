#include "romunect/sensor/frame_source.h"

namespace romunect {

const char* ToString(FrameStatus status) {
  switch (status) {
    case FrameStatus::kOk: return "ok";
    case FrameStatus::kBadFrame: return "bad frame";
    case FrameStatus::kEndOfStream: return "end of stream";
  }
  return "unknown";
}

}  // namespace romunect
