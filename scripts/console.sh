#!/usr/bin/env bash
# Starts the console gateway (docs/console-gateway.md) against any esgd:
#   bash scripts/console.sh --esgd HOST:PORT [--listen HOST:PORT] [--tls-cert F --tls-key F]
#                           [--esgd-ca F] [--esgd-server-name NAME] [--allowed-hosts H,...]
# Installs the console's npm packages first when they are missing or the lock file changed
# (the same check as scripts/install-deps.sh), then runs the gateway in the foreground.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
if ! command -v node >/dev/null 2>&1; then
  echo "console.sh: node (Node 20) not found; run: bash scripts/install-deps.sh" >&2
  exit 1
fi
stamp=$root/console/node_modules/.package-lock.json
if [ ! -f "$stamp" ] || [ "$root/console/package-lock.json" -nt "$stamp" ]; then
  echo "console.sh: installing the console's npm packages (npm ci)" >&2
  (cd "$root/console" && npm ci --no-audit --no-fund --loglevel=error)
fi
exec node "$root/console/gateway/main.js" "$@"
