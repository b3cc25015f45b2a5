#!/usr/bin/env bash
# A PostgreSQL outage under an idle esgd, measured from outside (docs/service.md "Reconnects and
# retries", issue 33): a PostgreSQL 15 of its own on a free port, one esgd with --node-id on it
# (the alert relay listening), then the postmaster killed with -9 for OUTAGE seconds and started
# again. Prints esgd's CPU time and log lines during the outage, and how long after the database
# accepts connections again esgd logs relay_recovered.
#
#   scripts/postgres_outage.sh [ESGD] [OUTAGE_SECONDS]     (defaults: build/server/esgd, 30)
#
# Runs initdb/pg_ctl as the user postgres when run as root (Debian's postgresql-15 creates it).
set -euo pipefail
cd "$(dirname "$0")/.."
esgd=$(realpath "${1:-build/server/esgd}")
outage=${2:-30}
bin=${ESG_PG_BINDIR:-/usr/lib/postgresql/15/bin}
dir=$(mktemp -d /tmp/esg-outage-XXXXXX)
as_pg=()
if [ "$(id -u)" = 0 ]; then
  chown postgres "$dir"
  as_pg=(runuser -u postgres --)
fi
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
esgd_pid=
cleanup() {
  [ -n "$esgd_pid" ] && kill "$esgd_pid" 2>/dev/null && wait "$esgd_pid" 2>/dev/null || true
  "${as_pg[@]}" "$bin/pg_ctl" -D "$dir/data" -m immediate stop >/dev/null 2>&1 || true
  rm -rf "$dir"
}
trap cleanup EXIT
pg_start() {
  "${as_pg[@]}" "$bin/pg_ctl" -D "$dir/data" -l "$dir/pg.log" -w \
    -o "-p $port -c listen_addresses=127.0.0.1 -k $dir/data" start >/dev/null
}
"${as_pg[@]}" "$bin/initdb" -D "$dir/data" -E UTF8 --locale=C -A trust -U esg >/dev/null
pg_start
"$bin/psql" -q -h 127.0.0.1 -p "$port" -U esg -d postgres -c 'CREATE DATABASE esg' >/dev/null

"$esgd" --listen 127.0.0.1:0 --db "postgresql://esg@127.0.0.1:$port/esg" --node-id outage \
  --log-format json >"$dir/esgd.out" 2>"$dir/esgd.log" &
esgd_pid=$!
for _ in $(seq 100); do grep -q "listening on port" "$dir/esgd.out" && break; sleep 0.1; done
sleep 2

ticks() { awk '{print $14 + $15}' "/proc/$esgd_pid/stat"; }
hz=$(getconf CLK_TCK)
lines_before=$(wc -l <"$dir/esgd.log")
cpu_before=$(ticks)
postmaster=$(head -1 "$dir/data/postmaster.pid")
kill -9 "$postmaster"
# The backends notice the postmaster's death and exit.
while pgrep -f "postgres: .*esg" >/dev/null 2>&1 && pgrep -P "$postmaster" >/dev/null 2>&1; do
  sleep 0.05
done
sleep "$outage"
cpu_after=$(ticks)
lines_after=$(wc -l <"$dir/esgd.log")
bytes_after=$(wc -c <"$dir/esgd.log")
rm -f "$dir/data/postmaster.pid"
pg_start
up=$(date +%s.%N)
recovered=-1
for _ in $(seq 1000); do
  # relay_recovered; before issue 33 the relay's first WARN after a reconnect said "reconnected".
  if tail -n 20 "$dir/esgd.log" | grep -q -e '"event":"relay_recovered"' -e 'reconnected: notif'; then
    recovered=$(echo "$(date +%s.%N) - $up" | bc)
    break
  fi
  sleep 0.01
done
echo "esgd $esgd, PostgreSQL down ${outage} s:"
echo "  log lines during the outage: $((lines_after - lines_before)) (log size ${bytes_after} bytes)"
echo "  esgd CPU during the outage: $(echo "scale=3; ($cpu_after - $cpu_before) / $hz" | bc) s" \
  "($(echo "scale=2; 100 * ($cpu_after - $cpu_before) / $hz / $outage" | bc) % of a core)"
echo "  relay_recovered logged ${recovered} s after PostgreSQL accepts connections again" \
  "(-1: not within 10 s)"
echo "  events during the outage:"
tail -n +"$((lines_before + 1))" "$dir/esgd.log" | head -n "$((lines_after - lines_before))" |
  grep -o '"event":"[a-z_]*"' | sort | uniq -c | sed 's/^/   /'
