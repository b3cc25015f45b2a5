#!/usr/bin/env bash
# estimator/ stays free of I/O, gRPC, protobuf, SQLite and JSON libraries.
set -euo pipefail
cd "$(dirname "$0")/.."
bad=$(grep -rlE '#include[[:space:]]*[<"](fstream|iostream|cstdio|grpcpp/|grpc/|google/protobuf/|sqlite3\.h|nlohmann/)' estimator || true)
if [ -n "$bad" ]; then
  echo "estimator/ must stay free of I/O, gRPC, protobuf, SQLite and nlohmann; offending files:" >&2
  echo "$bad" >&2
  exit 1
fi
echo "architecture check: estimator/ is free of I/O and service types"
