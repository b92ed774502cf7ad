#!/usr/bin/env bash
# Builds romunect and runs every test. Installs missing Debian packages first, so it works as
# the very first command on a fresh Debian 12 machine.
#   scripts/test.sh              Release build in build/, all tests
#   scripts/test.sh --sanitize   AddressSanitizer + UBSan build in build-asan/, all tests
set -euo pipefail
cd "$(dirname "$0")/.."

build_dir=build
cmake_args=(-DCMAKE_BUILD_TYPE=Release)
if [ "${1:-}" = "--sanitize" ]; then
  build_dir=build-asan
  # -O1 with line tables: half the compile time of -O2 -g, a suite as fast (the sanitizers'
  # checks dominate), and reports that still name file and line.
  cmake_args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g1 -DNDEBUG"
              "-DCMAKE_C_FLAGS_RELWITHDEBINFO=-O1 -g1 -DNDEBUG" -DROMUNECT_SANITIZE=ON -DROMUNECT_BUILD_BENCHMARKS=OFF)
  export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1
  export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
fi

bash scripts/setup.sh
echo "test: configuring ${build_dir}/"
cmake -S . -B "${build_dir}" -G Ninja "${cmake_args[@]}" > /dev/null
echo "test: building ${build_dir}/ with 2 jobs"
cmake --build "${build_dir}" -j2
echo "test: running the tests"
ctest --test-dir "${build_dir}" -j2 --output-on-failure --timeout 600
