// Inserts metric depth maps into a VotingGrid, frame by frame, with the exact traversal that
// voting_grid.h defines. The inserter owns a workspace (ray table, per-ray setup, threads)
// reused every frame, so the 30 Hz loop allocates nothing after the first frame.
//
// Speed: instead of one 3D Amanatides-Woo step per voxel, the walk steps in (x, y) from column
// to column and, inside a column, jumps straight to the last z plane crossed before leaving it
// (found from the crossing formula and then confirmed against the same comparisons the 3D walk
// makes), then applies the misses to that contiguous run of votes as one SIMD block (masked 32
// votes with AVX-512; 16 with AVX2, 8 with SSE2, the last block masked). The voxels visited are
// the same as the 3D walk's (tests/fusion compares against the plain reference, vote for vote,
// for every kernel). One ray's walk is a chain of dependent steps, so AVX-512 walks eight rays at
// once in lanes (AVX2 four); a frame's misses commute (voting_grid.h), so rays may interleave.
// A frame's rays are cast in 32 px tiles: a tile's rays cross neighbouring columns, which stay
// in cache. Threads own disjoint slabs of rows (y), balanced on the rays' positions, and each
// applies the hits in its rows after its misses: the votes do not depend on the thread count or
// the kernel. With AVX-512 every thread sets the whole frame up (a tenth of the work) and walks
// what touches its slab; the other kernels share one set-up frame. Each instruction set's walk
// is a translation unit of its own (fusion/src/insert_kernel.h).
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/pose.h"

namespace romunect::fusion {

// Per-frame counters (also summed over frames with Add). Per-pixel junk is counted, never thrown.
struct InsertStats {
  size_t frames = 0;
  size_t pixels = 0;              // pixels seen
  size_t no_measurement = 0;      // depth exactly 0
  size_t invalid_depth = 0;       // NaN, inf or negative depth: skipped
  size_t rays = 0;                // valid measurements cast
  size_t rays_missing_box = 0;    // the segment camera -> point never enters the box
  size_t points_outside_box = 0;  // the point lies outside the box: misses only, no hit
  size_t hits = 0;                // votes +1 (points inside the box)
  size_t misses = 0;              // votes -1
  // CPU time of the busiest thread (ms): the frame's wall time on free cores. On a loaded
  // machine it separates the work from waiting for a core.
  double critical_path_cpu_ms = 0.0;

  void Add(const InsertStats& other);
  std::string BriefReport() const;
};

struct InserterOptions {
  int threads = 1;  // worker threads including the caller, 1..256
  // The instruction set of the walk (cpu_features.h). Every one gives the same votes bit for bit
  // (tests/fusion compares them); kAuto takes AVX-512 (F, BW, DQ) where the CPU has it, else AVX2
  // (checked at run time, the build never assumes either), else SSE2 (x86-64), else scalar.
  Isa isa = Isa::kAuto;
  // Names the field when unusable, e.g. kAvx2 on a CPU without AVX2.
  std::string Problem() const;
};

class FrameInserter {
 public:
  // The grid must outlive the inserter. Throws InputError (source "fusion inserter") on bad
  // options.
  FrameInserter(VotingGrid* grid, const InserterOptions& options);
  ~FrameInserter();
  FrameInserter(const FrameInserter&) = delete;
  FrameInserter& operator=(const FrameInserter&) = delete;

  // Casts every pixel of depth_m (CV_32FC1, camera-sized, metres along the optical axis,
  // 0 = none) from the camera at T_W_C (rigid) into the grid. Adds to *stats when not null.
  // The camera's per-pixel rays are computed on the first call and whenever the camera changes.
  void Insert(const CameraModel& camera, const cv::Mat& depth_m, const Pose& T_W_C, InsertStats* stats);

  // The columns (x = ix, y = iy) whose votes the last Insert may have changed: the others kept
  // theirs, so CompletenessTracker looks again at just these (voting_grid.h). Empty before the
  // first frame and after one whose rays all missed the box.
  const cv::Rect& changed_columns() const { return changed_columns_; }

  int threads() const { return options_.threads; }
  // The instruction set in use (kAuto resolved). Where a column holds fewer votes than its block
  // (nz < 32 for AVX-512, 16 for AVX2, 8 for SSE2), the walk takes the next narrower kernel.
  Isa isa() const { return isa_; }

 private:
  struct Workspace;
  VotingGrid* grid_;
  InserterOptions options_;
  Isa isa_ = Isa::kScalar;
  cv::Rect changed_columns_;
  std::unique_ptr<Workspace> ws_;
};

}  // namespace romunect::fusion
