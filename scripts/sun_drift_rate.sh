#!/usr/bin/env bash
# How often `esg diagnose` names a drift that follows the sun (docs/discovery.md, "A drift that
# follows the sun"): SEEDS (default 10) 30 h recordings of the `sun_face_drift` scenario
# (tests/testing/discovery_scenarios.h: a gyro's drift of 0.088 deg/h at full illumination of one
# body face through a thermal lag, the face, the lag and the gyro by the seed), seeds from
# FIRST_SEED (default 101), one line each: right when a sun finding names the gyro and the face,
# holds the true lag in its interval and the amplitude within 3 sigma per case axis; then the
# count. EFFECT=eclipse_drift: the same drift following the eclipses of the scenario's orbit (the
# `sunlit` family), diagnosed with that orbit. EFFECT=none diagnoses effect-free recordings
# instead (any sun finding is false). PROFILE (inertial, orbital, calibration or mixed)
# flies that attitude profile (drawn from the seed) instead of the scenario's mostly orbital one.
# Uses estimator_tests of BUILD_DIR (default build), which it builds.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$BUILD_DIR" -j2 --target estimator_tests >/dev/null
ESG_SUN_SEEDS="${SEEDS:-10}" ESG_SUN_FIRST_SEED="${FIRST_SEED:-101}" \
  ESG_SUN_EFFECT="${EFFECT:-sun_face_drift}" ESG_SUN_PROFILE="${PROFILE:-}" "$BUILD_DIR/tests/estimator/estimator_tests" \
  --gtest_also_run_disabled_tests --gtest_filter='SunDiagnosis.DISABLED_ManySeeds'
