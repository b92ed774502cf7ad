#!/usr/bin/env bash
# The main job on a fresh Debian 12 machine: installs what is missing, builds romunect, and
# runs `romunect scan` on its built-in default. Extra arguments go to `romunect scan`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "scan: configuring build/"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release > /dev/null
echo "scan: building romunect with 2 jobs"
cmake --build build -j2 --target romunect
echo "scan: running build/bin/romunect scan $*"
exec build/bin/romunect scan "$@"
