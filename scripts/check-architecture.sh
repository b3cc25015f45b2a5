#!/usr/bin/env bash
# The layers of the code (README "Layout and conventions"): estimator/ (the filter) is free of
# I/O, gRPC, protobuf, SQLite and JSON libraries and never includes the discovery built on it; the
# discovery (estimator/discovery/) includes nothing above the estimator; and the libraries' link
# lines say the same: esg_estimator links Eigen and Abseil only, esg_discovery the estimator only.
set -euo pipefail
cd "$(dirname "$0")/.."
fail=0
bad=$(grep -rlE '#include[[:space:]]*[<"](fstream|iostream|cstdio|grpcpp/|grpc/|google/protobuf/|sqlite3\.h|nlohmann/)' estimator || true)
if [ -n "$bad" ]; then
  echo "estimator/ must stay free of I/O, gRPC, protobuf, SQLite and nlohmann; offending files:" >&2
  echo "$bad" >&2
  fail=1
fi
core_up=$(grep -lE '#include[[:space:]]*"estimator/discovery/' estimator/*.h estimator/*.cc || true)
if [ -n "$core_up" ]; then
  echo "the filter (estimator/*) must not include the discovery built on it; offending files:" >&2
  echo "$core_up" >&2
  fail=1
fi
disc_up=$(grep -lE '#include[[:space:]]*"(storage|server|client|proto|console)/' estimator/discovery/* || true)
if [ -n "$disc_up" ]; then
  echo "estimator/discovery/ must include nothing above the estimator; offending files:" >&2
  echo "$disc_up" >&2
  fail=1
fi
# The target graph: the words of a target's target_link_libraries(...) block.
links() {
  awk -v t="$2" '
    $0 ~ "target_link_libraries\\(" t "[ )]" { on = 1 }
    on { print }
    on && /\)/ { on = 0 }' "$1" | tr -s ' ()' '\n' | grep -vE "^(target_link_libraries|$2|PUBLIC|PRIVATE|INTERFACE|)$" || true
}
for lib in $(links estimator/CMakeLists.txt esg_estimator); do
  case "$lib" in
    Eigen3::Eigen | absl::*) ;;
    *) echo "esg_estimator links $lib: it may link Eigen and Abseil only" >&2; fail=1 ;;
  esac
done
for lib in $(links estimator/CMakeLists.txt esg_discovery); do
  case "$lib" in
    esg_estimator | Eigen3::Eigen | absl::*) ;;
    *) echo "esg_discovery links $lib: it may link the estimator only" >&2; fail=1 ;;
  esac
done
[ "$fail" -eq 0 ] || exit 1
echo "architecture check: the filter is free of I/O and of the discovery; the discovery of the layers above; the link lines agree"
