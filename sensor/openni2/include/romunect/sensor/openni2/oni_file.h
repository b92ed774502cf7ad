// Checks on .oni recordings before libOpenNI2's file driver reads them. That driver trusts the
// file: a single flipped bit can make it read or write out of bounds and take the process down.
//
// Two layers (docs/hardware.md, "Recordings from elsewhere"):
// - CheckOniStructure walks the container the way the driver does (file header, then a chain
//   of records: magic, type, field and payload sizes, node ids, strings, property sizes, seek
//   tables) and refuses what the driver would read past its buffers or the file.
// - ReadOniInChildProcess runs a read of the whole recording in a child process first: a
//   recording whose container is sound but whose content still crashes the driver (a renamed
//   property, a codec stream that decodes past its frame) becomes an InputError naming the
//   file, not a crash of the command.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

namespace romunect::openni2 {

// The first structural problem of an .oni container held in memory ("byte N: record K (type):
// what, expected"), or "" when it is sound. A recording cut short (its recorder killed) is
// sound up to its last whole record, as libOpenNI2 plays it to there.
std::string OniStructureProblem(const uint8_t* data, size_t size);

// Reads the file's headers (payloads are skipped, not read) and throws InputError naming the
// file when OniStructureProblem would find a problem; also when it is not a readable file.
void CheckOniStructure(const std::filesystem::path& path);

// Runs `read` (which reads `path` through libOpenNI2) in a child process and waits for it, at
// most limit_s seconds. Throws InputError naming the file when the child dies from a signal or
// runs past the limit. A child that ends with an InputError of its own is no verdict: the
// caller's own read then says what is wrong. Called before this process starts libOpenNI2.
void ReadOniInChildProcess(const std::filesystem::path& path, const std::function<void()>& read, double limit_s);

// True in that child process: the reads it runs skip their own checks.
bool InOniCheckChild();

}  // namespace romunect::openni2
