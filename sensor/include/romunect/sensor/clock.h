// The one clock helper of the project: wall time on the steady clock and CPU time of the
// process or the calling thread, all in seconds. Timings in reports and stats use these, so
// every figure means the same thing wherever it is measured.
#pragma once

#include <chrono>

namespace romunect {

using SteadyClock = std::chrono::steady_clock;

// Wall seconds from `since` to now, on the steady clock.
inline double SecondsSince(SteadyClock::time_point since) {
  return std::chrono::duration<double>(SteadyClock::now() - since).count();
}

// A running wall-time measurement: Stopwatch w; ...; w.seconds().
class Stopwatch {
 public:
  Stopwatch() : start_(SteadyClock::now()) {}
  double seconds() const { return SecondsSince(start_); }
  double milliseconds() const { return 1e3 * seconds(); }

 private:
  SteadyClock::time_point start_;
};

double ProcessCpuSeconds();  // CPU time of the whole process (all threads), s
double ThreadCpuSeconds();   // CPU time of the calling thread, s

}  // namespace romunect
