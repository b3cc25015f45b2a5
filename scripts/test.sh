#!/usr/bin/env bash
# Runs every test (ctest: unit and integration labels) after a full build, and prints how long
# the build and the tests took.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
bash scripts/build.sh
built=$SECONDS
bash scripts/check-architecture.sh
ctest --test-dir build --output-on-failure -j2 --timeout 900
echo "test.sh: install and build $((built - start)) s, tests $((SECONDS - built)) s"
