#!/usr/bin/env bash
# Installs the Debian packages this project builds, tests and plots with (root, or sudo if present).
set -euo pipefail
packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libabsl-dev
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libsqlite3-dev sqlite3
  liberfa-dev
  postgresql libpq-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libcli11-dev nlohmann-json3-dev libfmt-dev libcpp-httplib-dev
  libssl-dev openssl gnuplot-nox
  chromium fonts-liberation
  nginx
  python3 python3-yaml
  universal-ctags  # measures functions' lengths (scripts/check-architecture.sh)
  prometheus  # promtool: checks deploy/prometheus/esgd-alerts.yml (tests/server/operations_kit_test.cc)
)
# The console's npm packages (console/package-lock.json, from the npm registry; Node 20 is on the
# machine): installed again only when the lock file changed since the last install.
install_console() {
  if ! command -v npm >/dev/null 2>&1; then
    echo "install-deps: npm (Node 20) not found: the console (console/) cannot be installed" >&2
    exit 1
  fi
  local stamp=console/node_modules/.package-lock.json
  if [ ! -f "$stamp" ] || [ console/package-lock.json -nt "$stamp" ]; then
    (cd console && npm ci --no-audit --no-fund --loglevel=error)
  fi
}
missing=()
for p in "${packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  install_console
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then SUDO=sudo; fi
echo "installing: ${missing[*]}" >&2
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
install_console
