#!/usr/bin/env bash
# Installs exactly the Debian 12 packages romunect needs that are missing, and says what it does.
# Idempotent: a second run installs nothing. Uses sudo when not root.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libopencv-dev libceres-dev libgoogle-glog-dev
  libembree-dev libmujoco-dev libopenexr-dev libopenni2-dev
  nlohmann-json3-dev libcli11-dev zlib1g-dev libpng-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  # The fuzz targets (scripts/fuzz.sh): clang and its libFuzzer runtime (libclang_rt.fuzzer).
  clang libclang-rt-14-dev
  # Packaging traps: MuJoCo's CMake target needs qhull and GL; OpenEXR's Imath config
  # needs python3-imath.
  libqhull-dev libgl-dev python3-imath
  # The docs' Python recipe for frame directories (tests/jobs runs it): OpenCV's and NumPy's bindings.
  python3-opencv python3-numpy
)
# --bench-peers: the fusion benchmark's peers (cmake -DROMUNECT_BENCH_PEERS=ON), not needed otherwise.
if [[ " $* " == *" --bench-peers "* ]]; then packages+=(libopen3d-dev liboctomap-dev); fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} Debian packages are already installed"
  exit 0
fi

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
echo "setup: installing ${#missing[@]} missing package(s): ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -q
"${sudo_cmd[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}"
echo "setup: done"
