#!/usr/bin/env bash
# Configures and builds everything into ./build (Release: -O2 without debug info; -j2: gRPC builds
# are heavy).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j"${ESG_JOBS:-2}"
