#!/usr/bin/env bash
# Discovery confusion matrix (docs/discovery.md): builds esg_bench in BUILD_DIR (default build)
# and runs BM_DiscoveryConfusionMatrix; the Markdown table goes to stdout, one line per diagnosis
# to stderr. SEEDS (default 10) recordings per true effect; ROWS=library (the library's effects,
# `two`), ROWS=time (`none` and the time behaviours: drift_step, random_walk_one_gyro,
# random_walk_15x, readout_jump), ROWS=basis (`none` and the open-ended stage's classes:
# orbital_drift, growing_displacement, readout_scale, switching_drift, hidden_driver),
# ROWS=combined (a switching drift beside a library effect: switching_and_gyro_misalignment,
# switching_and_st_misalignment) or library and time (default). Several minutes on two cores.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$BUILD_DIR" -j2 --target esg_bench >/dev/null
ESG_DISCOVERY_SEEDS="${SEEDS:-10}" ESG_DISCOVERY_ROWS="${ROWS:-}" "$BUILD_DIR/tests/bench/esg_bench" \
  --benchmark_filter=DiscoveryConfusionMatrix
