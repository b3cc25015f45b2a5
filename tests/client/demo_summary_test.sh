#!/usr/bin/env bash
# The demo's printed summary (scripts/demo.sh after the build, scripts/demo_summary.py) fits one
# terminal screen, at most 40 lines of 100 columns, and says what a newcomer needs: the
# calibrated coefficients against the simulated truth as a table with their 1-sigma, the gap
# comparison of model (1) and (10), the prediction with its source named, the alerts as
# sentences ('above'/'below' as the numbers are, no unit '1'); nothing of the build or of
# progress, nothing on stderr.
#   ESG_BUILD=build bash tests/client/demo_summary_test.sh
set -euo pipefail
build=$(cd "${ESG_BUILD:?ESG_BUILD: the build directory}" && pwd)
cd "$(dirname "$0")/../.."
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "FAIL: $*" >&2; echo "--- demo output:" >&2; cat "$work/out.txt" >&2; exit 1; }

ESG_BUILD_DIR=$build ESG_DEMO_DIR=$work/demo ESG_DEMO_PORT=0 \
  bash scripts/demo.sh --no-serve >"$work/out.txt" 2>"$work/err.txt" ||
  { cat "$work/err.txt" >&2; fail "scripts/demo.sh --no-serve failed"; }
out=$work/out.txt
[ ! -s "$work/err.txt" ] || { cat "$work/err.txt" >&2; fail "the demo wrote to stderr"; }

lines=$(wc -l <"$out")
width=$(awk '{ if (length($0) > m) m = length($0) } END { print m + 0 }' "$out")
echo "demo summary: $lines lines, widest $width columns"
[ "$lines" -le 40 ] || fail "$lines lines (at most 40)"
[ "$width" -le 100 ] || fail "a line of $width columns (at most 100)"

grep -q '^term  *g1 truth  *estimate  *1-sigma  *g2 truth' "$out" || fail "no coefficient table"
rows=$(grep -cE '^(k0|C1 [xyz]|C2 [xyz]) +[-+][0-9.]+ +[-+][0-9.]+ +[0-9.]+ ' "$out" || true)
[ "$rows" = 7 ] || fail "$rows coefficient rows (k0, C1 x..z, C2 x..z expected)"
grep -q 'at most [0-9.]* sigma' "$out" || fail "no comparison of the estimates with the truth"
grep -qE '^  model \(1\) .* error after the gap +[0-9.]+ arcmin' "$out" || fail "no model (1) gap"
grep -qE '^  model \(10\) .* error after the gap +[0-9.]+ arcmin' "$out" || fail "no model (10) gap"
grep -q 'source: inertial hold' "$out" || fail "the prediction's source is not named"
grep -q 'held inertially fixed' "$out" || fail "the hold is not explained"
grep -qE '^Alerts raised: [0-9]+$' "$out" || fail "no alerts section"
# The demo's flight raises no alert today (its one alert had come from a jump of the simulated
# attitude in the 18 h slew, now continuous, docs/scenario.md);
# any alert it raises is printed as a sentence (the format itself is checked below).
alerts=$(sed -nE 's/^Alerts raised: ([0-9]+)$/\1/p' "$out")
if [ "$alerts" -gt 0 ]; then
  grep -qE '(above|below) its threshold of [0-9.e-]+( arcsec)? \((once|[0-9]+ times)\)\.$' "$out" ||
    fail "$alerts alerts raised, none printed as a sentence"
fi
if grep -qE 'Built target|[0-9]+%|SESSION_STATE_|ALERT_[A-Z]+_|ATTITUDE_SOURCE_' "$out"; then
  fail "build output, progress or an enum value name in the summary"
fi

# The comparison word follows the numbers, and a dimensionless value has no unit.
python3 - <<'PY' || fail "alert_sentence"
import sys
sys.path.insert(0, 'scripts')
import demo_summary
below = demo_summary.alert_sentence({
    'sequence': 4, 'severity': 'ALERT_SEVERITY_DISTRESS', 'reason': 'ALERT_REASON_FILTER_WIDENED',
    'subsystem': 'filter', 'value': 0.5, 'threshold': 2.0, 'unit': '1', 'repeatCount': '3',
    'firstTime': '2019-03-01T00:00:00.000Z', 'cleared': False})
assert below[0] == '#4 DISTRESS, active: filter widened on filter, first at 2019-03-01T00:00:00.000Z', below
assert below[1] == '   0.5, below its threshold of 2 (3 times).', below
PY
echo "PASS"
