#!/usr/bin/env bash
# False-alarm rate of `esg diagnose` (docs/discovery.md, "Proof"): SEEDS (default 300)
# effect-free 30 h recordings, seeds from FIRST_SEED (default 1001), diagnosed with the default
# options on JOBS (default 2) threads; prints the count, the rate and its exact one-sided 95%
# upper bound, one line per recording to stderr. About a minute of CPU per recording with the sun's
# and the channels' families (33 s each on two cores, 2026-11-30: nearly 3 h for 300). Builds
# esg_bench in BUILD_DIR (default build). ORBIT=1 gives each diagnosis the spacecraft's orbit (as
# `esg diagnose --orbit`: the sun's regressors see the Earth's shadow, the sunlit family is
# tried). EFFECT=none_with_channels adds irrelevant housekeeping channels to each recording
# (default none).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$BUILD_DIR" -j2 --target esg_bench >/dev/null
ESG_FALSE_ALARM_SEEDS="${SEEDS:-300}" ESG_FALSE_ALARM_FIRST_SEED="${FIRST_SEED:-1001}" \
  ESG_FALSE_ALARM_ORBIT="${ORBIT:-0}" ESG_FALSE_ALARM_EFFECT="${EFFECT:-none}" \
  ESG_DISCOVERY_JOBS="${JOBS:-2}" "$BUILD_DIR/tests/bench/esg_bench" \
  --benchmark_filter=DiscoveryFalseAlarms
