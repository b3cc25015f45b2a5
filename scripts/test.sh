#!/usr/bin/env bash
# Runs every test (ctest: unit and integration labels) after a full build.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
bash scripts/check-architecture.sh
ctest --test-dir build --output-on-failure -j2 --timeout 900
