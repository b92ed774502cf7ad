// Checks on .oni recordings before libOpenNI2's file driver reads them. That driver trusts the
// file: a single flipped bit can make it read or write out of bounds and take the process down.
//
// Two layers (docs/hardware.md, "Recordings from elsewhere"):
// - CheckOniStructure walks the container the way the driver does (file header, then a chain
//   of records: magic, type, field and payload sizes, node ids, strings, property sizes, seek
//   tables) and refuses what the driver would read past its buffers or the file.
// - TrialReadOni runs a read of the whole recording in a process of its own first: a recording
//   whose container is sound but whose content still crashes the driver (a renamed property, a
//   codec stream that decodes past its frame) becomes an InputError naming the file, not a crash
//   of the command.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace romunect::openni2 {

// The first structural problem of an .oni container held in memory ("byte N: record K (type):
// what, expected"), or "" when it is sound. A recording cut short (its recorder killed) is
// sound up to its last whole record, as libOpenNI2 plays it to there.
std::string OniStructureProblem(const uint8_t* data, size_t size);

// Reads the file's headers (payloads are skipped, not read) and throws InputError naming the
// file when OniStructureProblem would find a problem; also when it is not a readable file.
void CheckOniStructure(const std::filesystem::path& path);

// The trial read's program, romunect-oni-trial-read, built with the library: a fresh process,
// never a fork of this one, because a process whose libOpenNI2 has started has threads, and a
// forked copy waits for ever on the locks they held. It exits with one of these codes.
inline constexpr const char* kOniTrialReadProgramName = "romunect-oni-trial-read";
inline constexpr int kOniTrialReadOk = 0;
inline constexpr int kOniTrialReadInputError = 3;  // the read refused the file: no verdict here
inline constexpr int kOniTrialReadOtherError = 4;  // another exception: likewise
inline constexpr int kOniTrialReadUsage = 64;      // its arguments were not understood

// Where that program is: beside the running program, else where the build tree put it.
std::filesystem::path OniTrialReadProgram();

// Runs the trial-read program with `arguments` and waits for it, at most limit_s seconds.
// Throws InputError naming the file when the program dies from a signal or runs past the limit.
// A read that ends with an InputError of its own is no verdict: the caller's own read then says
// what is wrong.
void TrialReadOni(const std::filesystem::path& path, const std::vector<std::string>& arguments, double limit_s);

}  // namespace romunect::openni2
