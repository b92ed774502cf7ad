#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/) with clang, ASan and UBSan in build-fuzz/ (only the modules
# they need), then runs each over its seed corpus (fuzz/corpus/<target>/) for a bounded time and
# prints the executions per target. Exits non-zero when any target finds a crash, a leak, a hang
# or a sanitizer report; the input that did it is left in build-fuzz/findings/.
#   scripts/fuzz.sh [seconds per target]   (default 20: eleven targets in ~4 minutes)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-20}"
targets=(frame_manifest exr png height_map camera calibration mesh pose_log rig oni scene)

bash scripts/setup.sh
launcher=()
if command -v ccache > /dev/null; then launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
echo "fuzz: configuring build-fuzz/ (clang)"
CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DROMUNECT_FUZZ=ON \
  -DROMUNECT_BUILD_TESTS=OFF -DROMUNECT_BUILD_BENCHMARKS=OFF "${launcher[@]}" > /dev/null
echo "fuzz: building ${#targets[@]} targets with 2 jobs"
cmake --build build-fuzz -j2 --target "${targets[@]/%/_fuzz}"

export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
mkdir -p build-fuzz/findings
failed=0
printf '%-16s %12s %10s  %s\n' target executions exec/s result
for t in "${targets[@]}"; do
  work="build-fuzz/corpus/$t"  # new inputs go here; the seeds in the repository stay as they are
  mkdir -p "$work"
  log="build-fuzz/findings/$t.log"
  result=ok
  # -rss_limit_mb and -timeout: a reader that allocates what a file claims or loops on it is a finding.
  if ! "build-fuzz/bin/${t}_fuzz" -max_total_time="$seconds" -rss_limit_mb=1024 -timeout=10 -print_final_stats=1 \
      -artifact_prefix="build-fuzz/findings/${t}-" "$work" "fuzz/corpus/$t" > "$log" 2>&1; then
    result="FAILED (see $log)"
    failed=1
  fi
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  printf '%-16s %12s %10s  %s\n' "$t" "${runs:-?}" "${rate:-?}" "$result"
  if [[ "$result" != ok ]]; then  # a clean clone's CI keeps only this output: show the finding here
    grep -E -m1 -A12 '^==[0-9]+==|^ALARM|^SUMMARY' "$log" | sed 's/^/    /' || true
    for a in build-fuzz/findings/"$t"-*; do
      [[ -f "$a" ]] && echo "    input ($a, first 256 bytes as hex):" && head -c 256 "$a" | od -An -tx1 | sed 's/^/    /'
    done
  fi
done
exit "$failed"
