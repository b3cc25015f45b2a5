#!/usr/bin/env bash
# Discovery confusion matrix (docs/discovery.md): builds esg_bench in BUILD_DIR (default build)
# and runs BM_DiscoveryConfusionMatrix; the Markdown table goes to stdout, one line per diagnosis
# to stderr. SEEDS (default 10) recordings per true effect; a few minutes on two cores.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
fi
cmake --build "$BUILD_DIR" -j2 --target esg_bench >/dev/null
ESG_DISCOVERY_SEEDS="${SEEDS:-10}" "$BUILD_DIR/tests/bench/esg_bench" \
  --benchmark_filter=DiscoveryConfusionMatrix
