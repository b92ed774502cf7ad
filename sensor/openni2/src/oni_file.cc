#include "romunect/sensor/openni2/oni_file.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstring>
#include <functional>
#include <set>
#include <sstream>
#include <thread>
#include <vector>

#include "romunect/sensor/errors.h"

namespace romunect::openni2 {
namespace {

// The container as libOniFile (OpenNI2's file driver) reads it: a 24-byte file header, then
// records, each a header (magic "NIR\0", type, node id, fields size, payload size, undo
// position), its fields, then its payload; all little-endian and packed.
constexpr size_t kFileHeaderSize = 24;
constexpr uint32_t kRecordMagic = 0x0052494E;  // "NIR\0"
constexpr size_t kRecordHeaderSize = 28;       // files from version 1.0.1.0 on: 64-bit undo position
constexpr size_t kRecordHeaderSizeOld = 24;    // earlier files: 32-bit
// The driver's record buffer: the largest data record it takes (1600 x 1200 x 3 bytes of data).
constexpr uint64_t kMaxDataSize = 1600ull * 1200ull * 3ull;
constexpr uint64_t kMaxRecordSize = kRecordHeaderSize + 81 + 8 + 4 + kMaxDataSize;
constexpr uint32_t kMaxNameLength = 80;  // node and property names, without their NUL
constexpr uint32_t kMaxNodeId = 255;     // the driver allocates a table of this many nodes

enum RecordType : uint32_t {
  kNodeAdded1004 = 0x02,
  kIntProperty = 0x03,
  kRealProperty = 0x04,
  kStringProperty = 0x05,
  kGeneralProperty = 0x06,
  kNodeRemoved = 0x07,
  kNodeDataBegin = 0x08,
  kNodeStateReady = 0x09,
  kNewData = 0x0A,
  kEnd = 0x0B,
  kNodeAdded1005 = 0x0C,
  kNodeAdded = 0x0D,
  kSeekTable = 0x0E,
};

const char* TypeName(uint32_t type) {
  switch (type) {
    case kNodeAdded1004:
    case kNodeAdded1005:
    case kNodeAdded: return "node added";
    case kIntProperty: return "integer property";
    case kRealProperty: return "real property";
    case kStringProperty: return "string property";
    case kGeneralProperty: return "general property";
    case kNodeRemoved: return "node removed";
    case kNodeDataBegin: return "node data begin";
    case kNodeStateReady: return "node state ready";
    case kNewData: return "frame data";
    case kEnd: return "end";
    case kSeekTable: return "seek table";
    default: return "unknown";
  }
}

uint32_t U32(const uint8_t* p) { return p[0] | (p[1] << 8) | (p[2] << 16) | (static_cast<uint32_t>(p[3]) << 24); }
uint64_t U64(const uint8_t* p) { return U32(p) | (static_cast<uint64_t>(U32(p + 4)) << 32); }

// Reads n bytes at offset into dst; false when the source ends before.
using ReadAt = std::function<bool(uint64_t offset, size_t n, uint8_t* dst)>;

class Problem : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The fields of one record, read in order as the driver's Record::Read* do.
class Fields {
 public:
  Fields(const std::vector<uint8_t>& bytes, size_t header) : b_(bytes), at_(header) {}
  uint32_t U32Field(const char* what) { return U32(Take(4, what)); }
  uint64_t U64Field(const char* what) { return U64(Take(8, what)); }
  // A length-prefixed string whose length counts its terminating NUL.
  std::string String(const char* what, uint32_t max_length) {
    const uint32_t n = U32Field(what);
    if (n == 0 || n > max_length + 1) {
      throw Problem(std::string(what) + " length " + std::to_string(n) + ", expected 1.." + std::to_string(max_length + 1));
    }
    const uint8_t* s = Take(n, what);
    if (s[n - 1] != 0 || std::memchr(s, 0, n - 1) != nullptr) {
      throw Problem(std::string(what) + " is not one NUL-terminated string of its " + std::to_string(n) + " bytes");
    }
    return std::string(reinterpret_cast<const char*>(s), n - 1);
  }
  const uint8_t* Take(uint64_t n, const char* what) {
    if (n > b_.size() - at_) {
      throw Problem(std::string(what) + " ends past the record's " + std::to_string(b_.size()) + " bytes of fields");
    }
    const uint8_t* p = b_.data() + at_;
    at_ += n;
    return p;
  }

 private:
  const std::vector<uint8_t>& b_;
  size_t at_;
};

struct WalkState {
  uint64_t size = 0;
  bool old_header = false;
  uint32_t max_node_id = 0;
  std::set<uint32_t> nodes;  // added before
};

void CheckNode(const WalkState& w, uint32_t node) {
  if (node > w.max_node_id) {
    throw Problem("node id " + std::to_string(node) + " above the file header's largest, " + std::to_string(w.max_node_id));
  }
  if (w.nodes.count(node) == 0) throw Problem("node id " + std::to_string(node) + " was not added before");
}

void CheckFields(WalkState& w, uint32_t type, uint32_t node, const std::vector<uint8_t>& fields, size_t header) {
  Fields f(fields, header);
  switch (type) {
    case kNodeAdded1004:
    case kNodeAdded1005:
    case kNodeAdded: {
      if (node > w.max_node_id) {
        throw Problem("node id " + std::to_string(node) + " above the file header's largest, " + std::to_string(w.max_node_id));
      }
      f.String("node name", kMaxNameLength);
      f.Take(8, "node type and codec");
      if (type == kNodeAdded1004) break;
      f.Take(4 + 8 + 8, "frame count and time stamps");
      if (type == kNodeAdded1005) break;
      const uint64_t seek = w.old_header ? f.U32Field("seek table position") : f.U64Field("seek table position");
      if (seek >= w.size) {
        throw Problem("cut short: the seek table belongs at byte " + std::to_string(seek) + ", past the file's " +
                      std::to_string(w.size) + " bytes (a copy interrupted early?)");
      }
      w.nodes.insert(node);
      break;
    }
    case kIntProperty:
    case kRealProperty:
    case kStringProperty:
    case kGeneralProperty: {
      CheckNode(w, node);
      f.String("property name", kMaxNameLength);
      const uint32_t n = f.U32Field("property size");
      if ((type == kIntProperty || type == kRealProperty) && n != 8) {
        throw Problem("property size " + std::to_string(n) + ", expected 8");
      }
      const uint8_t* value = f.Take(n, "property value");
      if (type == kStringProperty && (n == 0 || value[n - 1] != 0)) throw Problem("string property not NUL-terminated");
      break;
    }
    case kNodeDataBegin: CheckNode(w, node); f.Take(4 + 8, "frame count and time stamp"); break;
    case kNewData: CheckNode(w, node); f.Take(8 + 4, "time stamp and frame number"); break;
    case kNodeRemoved:  // a removed node's seek table follows its removal
    case kNodeStateReady:
    case kSeekTable: CheckNode(w, node); break;
    default: break;
  }
  if (type == kNodeAdded1004 || type == kNodeAdded1005) w.nodes.insert(node);
}

// A seek table's payload: entries of time stamp, configuration id and file position.
void CheckSeekTable(const WalkState& w, const std::vector<uint8_t>& payload) {
  const size_t entry = w.old_header ? 16 : 20;
  if (payload.size() % entry != 0) {
    throw Problem("seek table of " + std::to_string(payload.size()) + " bytes, expected whole " + std::to_string(entry) +
                  "-byte entries");
  }
  for (size_t at = 0; at < payload.size(); at += entry) {
    const uint64_t position = w.old_header ? U32(payload.data() + at + 12) : U64(payload.data() + at + 12);
    if (position >= w.size) {
      throw Problem("seek table entry " + std::to_string(at / entry) + " points to byte " + std::to_string(position) +
                    ", past the file's " + std::to_string(w.size));
    }
  }
}

void CheckFileHeader(WalkState& w, const ReadAt& read) {
  uint8_t h[kFileHeaderSize];
  if (w.size < kFileHeaderSize || !read(0, kFileHeaderSize, h)) {
    throw Problem("shorter than the 24-byte file header");
  }
  if (std::memcmp(h, "NI10", 4) != 0) throw Problem("file header: no \"NI10\" magic (not an OpenNI recording)");
  const unsigned major = h[4], minor = h[5], maintenance = h[6] | (h[7] << 8);
  const uint32_t build = U32(h + 8);
  const uint64_t version = (static_cast<uint64_t>(maintenance) << 32) | build;
  if (major != 1 || minor != 0 || version < 4 || maintenance > 1) {
    std::ostringstream s;
    s << "file header: format version " << major << '.' << minor << '.' << maintenance << '.' << build
      << ", expected 1.0.0.4 to 1.0.1.x";
    throw Problem(s.str());
  }
  w.old_header = maintenance < 1;
  w.max_node_id = U32(h + 20);
  if (w.max_node_id > kMaxNodeId) {
    throw Problem("file header: largest node id " + std::to_string(w.max_node_id) + ", expected at most " +
                  std::to_string(kMaxNodeId));
  }
}

std::string WalkContainer(uint64_t size, const ReadAt& read) {
  WalkState w;
  w.size = size;
  uint64_t pos = 0;
  int index = 0;
  uint32_t type = 0;
  try {
    CheckFileHeader(w, read);
    const size_t header = w.old_header ? kRecordHeaderSizeOld : kRecordHeaderSize;
    pos = kFileHeaderSize;
    std::vector<uint8_t> fields, payload;
    for (;; ++index) {
      type = 0;
      uint8_t h[kRecordHeaderSize];
      if (size - pos < header) return "";  // cut short: sound up to here
      read(pos, header, h);
      if (U32(h) != kRecordMagic) throw Problem("no record magic \"NIR\"");
      type = U32(h + 4);
      const uint32_t node = U32(h + 8), fields_size = U32(h + 12), payload_size = U32(h + 16);
      const uint64_t undo = w.old_header ? U32(h + 20) : U64(h + 20);
      if (type < kNodeAdded1004 || type > kSeekTable) throw Problem("record type " + std::to_string(type) + ", expected 2..14");
      if (fields_size < header || uint64_t{fields_size} + payload_size > kMaxRecordSize) {
        throw Problem("fields of " + std::to_string(fields_size) + " bytes and payload of " + std::to_string(payload_size) +
                      ", expected fields of at least " + std::to_string(header) + " and at most " +
                      std::to_string(kMaxRecordSize) + " bytes in all");
      }
      if (type == kNewData && payload_size > kMaxDataSize) throw Problem("frame payload larger than the driver's buffer");
      if (undo >= pos && undo != 0) throw Problem("undo position " + std::to_string(undo) + " not before the record");
      if (type == kEnd) return "";  // what follows the end record is not read
      if (uint64_t{fields_size} + payload_size > size - pos) return "";  // the last record, cut short
      fields.resize(fields_size);
      read(pos, fields_size, fields.data());
      CheckFields(w, type, node, fields, header);
      if (type == kSeekTable) {
        payload.resize(payload_size);
        read(pos + fields_size, payload_size, payload.data());
        CheckSeekTable(w, payload);
      }
      pos += uint64_t{fields_size} + payload_size;
    }
  } catch (const Problem& p) {
    if (pos == 0) return p.what();
    return "byte " + std::to_string(pos) + ": record " + std::to_string(index) + " (" + TypeName(type) + "): " + p.what();
  }
}

}  // namespace

std::string OniStructureProblem(const uint8_t* data, size_t size) {
  return WalkContainer(size, [&](uint64_t offset, size_t n, uint8_t* dst) {
    if (offset > size || n > size - offset) return false;
    if (n > 0) std::memcpy(dst, data + offset, n);  // an empty payload's buffer may be null
    return true;
  });
}

void CheckOniStructure(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path.string(), "", "not a regular .oni file");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw InputError(path.string(), "", std::string("cannot be opened: ") + std::strerror(errno));
  const uint64_t size = std::filesystem::file_size(path, ec);
  int read_errno = 0;
  const std::string problem = WalkContainer(ec ? 0 : size, [&](uint64_t offset, size_t n, uint8_t* dst) {
    size_t done = 0;
    while (done < n) {
      const ssize_t got = ::pread(fd, dst + done, n - done, static_cast<off_t>(offset + done));
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) {
        read_errno = got < 0 ? errno : 0;
        throw Problem(read_errno != 0 ? std::string("cannot be read: ") + std::strerror(read_errno)
                                      : std::string("ends while it is read"));
      }
      done += static_cast<size_t>(got);
    }
    return true;
  });
  ::close(fd);
  if (!problem.empty()) throw InputError(path.string(), "", "not a readable .oni recording: " + problem);
}

std::filesystem::path OniTrialReadProgram() {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path beside = ec ? std::filesystem::path() : self.parent_path() / kOniTrialReadProgramName;
  if (!beside.empty() && std::filesystem::is_regular_file(beside, ec)) return beside;
  const std::filesystem::path built = ROMUNECT_ONI_TRIAL_READ_PROGRAM;
  if (std::filesystem::is_regular_file(built, ec)) return built;
  return beside.empty() ? built : beside;
}

void TrialReadOni(const std::filesystem::path& path, const std::vector<std::string>& arguments, double limit_s) {
  const std::filesystem::path program = OniTrialReadProgram();
  std::vector<std::string> strings{program.string()};
  strings.insert(strings.end(), arguments.begin(), arguments.end());
  std::vector<char*> argv;
  for (std::string& a : strings) argv.push_back(a.data());
  argv.push_back(nullptr);
  // The trial read is silent: what it would say, the caller's own read says.
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  pid_t child = -1;
  const int spawned = ::posix_spawn(&child, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) {
    throw InputError(path.string(), "",
                     "cannot start its trial read, the program " + program.string() + " (built beside romunect): " +
                         std::strerror(spawned));
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(limit_s);
  int status = 0;
  for (;;) {
    const pid_t done = ::waitpid(child, &status, WNOHANG);
    if (done == child) break;
    if (done < 0 && errno != EINTR) throw InputError(path.string(), "", std::string("its trial read was lost: ") + std::strerror(errno));
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(child, SIGKILL);
      while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
      }
      std::ostringstream s;
      s << "libOpenNI2 did not finish a trial read of this recording within " << limit_s
        << " s; the file is damaged or not a recording it can play";
      throw InputError(path.string(), "", s.str());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (WIFSIGNALED(status)) {
    throw InputError(path.string(), "",
                     std::string("libOpenNI2's file driver crashed in a trial read of this recording (") +
                         strsignal(WTERMSIG(status)) + "); the file is damaged or not a recording it can play");
  }
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  if (code == kOniTrialReadUsage) {
    throw InputError(path.string(), "",
                     "its trial read, the program " + program.string() +
                         ", refused its arguments: it is not the one built with this romunect");
  }
  if (code != kOniTrialReadOk && code != kOniTrialReadInputError && code != kOniTrialReadOtherError) {
    throw InputError(path.string(), "",
                     "libOpenNI2 ended a trial read of this recording abnormally (exit status " + std::to_string(code) +
                         "); the file is damaged or not a recording it can play");
  }
}

}  // namespace romunect::openni2
