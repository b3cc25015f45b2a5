#!/usr/bin/env bash
# Regenerates the benchmark table of docs/performance.md (between its "performance-table" markers)
# from one run of esg_bench: each benchmark REPETITIONS times (default 3), repetitions interleaved
# at random so that a ratio (durable ingest against the bare gRPC echo) is of runs under the same
# load; the table gives medians, the ratio is the median of the per-repetition ratios, and the
# machine's load average before and after is written under it. Needs python3.
# Usage: scripts/performance_table.sh [BUILD_DIR] [REPETITIONS]
#   OUT=FILE writes the table there instead of into docs/performance.md.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
reps=${2:-3}
bench="$build/tests/bench/esg_bench"
[[ -x "$bench" ]] || { echo "no $bench: cmake --build $build --target esg_bench" >&2; exit 2; }
json=$(mktemp)
trap 'rm -f "$json"' EXIT
filter='^BM_(Simulate24hFourGyrosCalibration|Calibrate24hModel10Plus11|Calibrate24hAtIntegrationRate|Calibrate24hMotionBounded|MeasurementStep|SessionCopy|Predict6hAt60s|PredictSixHoursAt60s|IngestThroughGrpc/[01]/|EchoStream|StorageArchiveFrames/100/1/|StorageFilterEffects/1/1/|Diagnose30h/2/)'
load_before=$(cut -d' ' -f1-3 /proc/loadavg)
"$bench" --benchmark_filter="$filter" --benchmark_repetitions="$reps" \
  --benchmark_enable_random_interleaving=true --benchmark_format=json \
  --benchmark_out="$json" --benchmark_out_format=json >/dev/null 2>&1
load_after=$(cut -d' ' -f1-3 /proc/loadavg)
python3 scripts/performance_table.py "$json" "${OUT:-docs/performance.md}" \
  "$(git rev-parse --short HEAD)" "$load_before" "$load_after" "$(nproc)"
echo "wrote ${OUT:-docs/performance.md}"
