#!/usr/bin/env bash
# Configures and builds everything into ./build (Release: -O2 without debug info; -j2: gRPC builds
# are heavy). A new build tree uses Ninja (Debian ninja-build), which starts a target's files as
# soon as the headers they need are generated instead of after the libraries it links are built;
# an existing tree keeps the generator it was configured with.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
generator=()
if [ ! -f build/CMakeCache.txt ] && command -v ninja >/dev/null 2>&1; then
  generator=(-G Ninja)
fi
cmake -S . -B build "${generator[@]}" -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j"${ESG_JOBS:-2}"
