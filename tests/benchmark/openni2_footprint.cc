// What an OpenNI2 program maps into memory once libOpenNI2 has loaded its drivers: the shared
// libraries and the megabytes of file-backed mappings in /proc/self/maps. Run once with the
// build tree's libOpenNI2 (its driver folder holds the virtual device and links to the stock
// drivers) and once with the system's (the stock drivers alone); the difference is what the
// virtual device's driver costs every OpenNI2 program that loads it (docs/performance.md).
//
//   openni2_footprint <libOpenNI2.so.0> [URI]   prints: libraries N, mapped_mb M
// With a URI it opens that device first (what a program pays once it uses the device).
#include <dlfcn.h>

#include <cstdio>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3) {
    std::fprintf(stderr, "usage: %s <path of libOpenNI2.so.0> [device URI]\n", argv[0]);
    return 2;
  }
  void* openni = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (openni == nullptr) {
    std::fprintf(stderr, "cannot load %s: %s\n", argv[1], dlerror());
    return 2;
  }
  using Initialize = int (*)(int);
  auto initialize = reinterpret_cast<Initialize>(dlsym(openni, "oniInitialize"));
  if (initialize == nullptr || initialize(2000) != 0) {  // ONI_API_VERSION 2.0, ONI_STATUS_OK 0
    std::fprintf(stderr, "oniInitialize failed\n");
    return 1;
  }
  if (argc == 3) {
    using DeviceOpen = int (*)(const char*, void**);
    auto open = reinterpret_cast<DeviceOpen>(dlsym(openni, "oniDeviceOpen"));
    void* device = nullptr;
    if (open == nullptr || open(argv[2], &device) != 0) {
      std::fprintf(stderr, "cannot open %s\n", argv[2]);
      return 1;
    }
  }
  // Sum each file's mappings once per address range: start-end, permissions, offset, dev, inode, path.
  std::ifstream maps("/proc/self/maps");
  std::set<std::string> libraries;
  std::map<std::string, unsigned long long> bytes;
  for (std::string line; std::getline(maps, line);) {
    std::istringstream fields(line);
    std::string range, perms, offset, dev, inode, path;
    fields >> range >> perms >> offset >> dev >> inode >> path;
    if (path.empty() || path[0] != '/') continue;
    const size_t dash = range.find('-');
    bytes[path] += std::stoull(range.substr(dash + 1), nullptr, 16) - std::stoull(range.substr(0, dash), nullptr, 16);
    if (path.find(".so") != std::string::npos) libraries.insert(path);
  }
  unsigned long long total = 0;
  for (const auto& [path, size] : bytes) total += size;
  std::printf("libraries %zu, mapped_mb %.1f\n", libraries.size(), total / (1024.0 * 1024.0));
  return 0;
}
