#!/usr/bin/env bash
# Writes cmake/test_costs.txt, the first order of ctest -j in a fresh build tree
# (cmake/build_time.cmake), from the test times of the last full ctest run in BUILD_DIR (default
# build): every current test over 1 s, longest first.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
data=$build/Testing/Temporary/CTestCostData.txt
[ -f "$data" ] || { echo "test_costs.sh: no $data (run ctest first)" >&2; exit 1; }
ctest --test-dir "$build" -N | sed -n 's/^ *Test *#[0-9]*: //p' | sed 's/ .*//' > /tmp/esg-test-names.$$
awk 'NR == FNR { current[$1] = 1; next }
     /^---/ { exit }
     NF == 3 && ($1 in current) && $3 >= 1 { if (!($1 in cost) || $3 > cost[$1]) cost[$1] = $3 }
     END { for (t in cost) printf "%s 1 %.1f\n", t, cost[t] }' /tmp/esg-test-names.$$ "$data" |
  sort -k3,3 -g -r > cmake/test_costs.txt
rm -f /tmp/esg-test-names.$$
echo "test_costs.sh: $(wc -l < cmake/test_costs.txt) tests in cmake/test_costs.txt"
