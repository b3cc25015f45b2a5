#!/usr/bin/env bash
# The acknowledgement-invariant property test (tests/end_to_end/ack_invariant_test.cc) over many
# seeds: two concurrent senders, random interleavings of in-order, duplicate, late, conflicting,
# unstorable and oversized frames, kill -9 of esgd twice per seed.
#   bash scripts/ack_invariant.sh [FIRST_SEED] [COUNT]     (default 1 100)
set -euo pipefail
cd "$(dirname "$0")/.."
first=${1:-1}
count=${2:-100}
seeds=$(seq -s, "$first" $((first + count - 1)))
cmake --build build --target end_to_end_tests -j"${ESG_JOBS:-2}" >/dev/null
ESG_ACK_INVARIANT_SEEDS=$seeds build/tests/end_to_end/end_to_end_tests \
  --gtest_filter='AckInvariant.*' 2>/dev/null | grep -E '^seed |OK \]|FAILED'
