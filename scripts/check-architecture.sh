#!/usr/bin/env bash
# The layers of the code (README "Layout and conventions"): estimator/ (the filter) is free of
# I/O, gRPC, protobuf, SQLite and JSON libraries and never includes the discovery built on it; the
# discovery (estimator/discovery/) includes nothing above the estimator, and its files include
# each other in no loop; the file formats (formats/, esg_formats: recording CSV, column mapping,
# AEM) include no store; and the libraries' link lines say the same: each library links
# only libraries of lower layers, esg_estimator Eigen, Abseil and ERFA (the sun's direction)
# only, esg_discovery the estimator only, esg_formats and the CLI's library neither SQLite nor
# libpq; and no function in estimator/ or server/ is over 120 lines without saying why.
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
    Eigen3::Eigen | absl::* | PkgConfig::ERFA) ;;
    *) echo "esg_estimator links $lib: it may link Eigen, Abseil and ERFA only" >&2; fail=1 ;;
  esac
done
for lib in $(links estimator/CMakeLists.txt esg_discovery); do
  case "$lib" in
    esg_estimator | Eigen3::Eigen | absl::*) ;;
    *) echo "esg_discovery links $lib: it may link the estimator only" >&2; fail=1 ;;
  esac
done
# No back-arrows inside the discovery: the graph of its files (a file's .h and .cc together, an
# arrow to each discovery header it includes) has no loop. Arrows not yet removed are listed
# here with their reason; a new loop fails, and so does a listed arrow that is gone. None is
# listed today (the candidate and fit types the fits share are in candidate.h, below the library
# that dispatches to the fits).
pending_arrows=""
arrows=$(for f in estimator/discovery/*.h estimator/discovery/*.cc; do
  mod=$(basename "${f%.*}")
  for dep in $(sed -nE 's|^#include[[:space:]]*"estimator/discovery/([a-z_]+)\.h".*|\1|p' "$f"); do
    [ "$dep" = "$mod" ] || echo "$mod $dep"
  done
done | sort -u)
while read -r arrow; do
  [ -n "$arrow" ] || continue
  if grep -qx "$arrow" <<<"$arrows"; then
    echo "estimator/discovery: arrow $arrow still to be removed (listed)" >&2
  else
    echo "estimator/discovery: arrow $arrow is gone: remove it from the list" >&2
    fail=1
  fi
done <<<"$pending_arrows"
if ! loop=$(grep -vxF "$pending_arrows" <<<"$arrows" | tsort 2>&1 >/dev/null) || [ -n "$loop" ]; then
  echo "estimator/discovery: its files include each other in a loop; move what they share to a" \
    "lower header:" >&2
  echo "$loop" | awk '/input contains a loop/ { n++; next } n == 1 { print "  " $2 }' >&2
  fail=1
fi
# The file formats (formats/, the library esg_formats) include no store and nothing above them:
# no SQLite, libpq, storage/, server/ or client/.
formats_sources=$(awk '/^set\(ESG_FORMATS_SOURCES/ { on = 1; next } on && /\)/ { on = 0 } on { print $1 }' \
  formats/CMakeLists.txt)
if [ -z "$formats_sources" ]; then
  echo "formats/CMakeLists.txt: no ESG_FORMATS_SOURCES list (the sources of esg_formats)" >&2
  fail=1
fi
for src in $formats_sources; do
  [ -f "formats/$src" ] || { echo "formats/CMakeLists.txt lists $src, not in formats/" >&2; fail=1; }
done
for f in formats/*.h formats/*.cc; do
  for inc in $(sed -nE 's|^#include[[:space:]]*[<"]([^">]+)[">].*|\1|p' "$f"); do
    case "$inc" in
      sqlite3.h | libpq-fe.h | storage/* | server/* | client/*)
        echo "$f (esg_formats) includes $inc: the file formats include no store and nothing above" >&2
        fail=1 ;;
    esac
  done
done

# The target graph. Every library of the project has a layer; it links libraries of lower layers
# only (and outside libraries), so the graph has no cycle and no arrow upwards.
layer() {
  case "$1" in
    esg_estimator | esg_strict_json | esg_proto) echo 0 ;;
    esg_discovery | esg_formats | esg_proto_convert) echo 1 ;;
    esg_storage | esg_diagnosis_json) echo 2 ;;
    esg_server_lib | esg_client_lib) echo 3 ;;
    *) echo "" ;;
  esac
}
cmake_files="estimator/CMakeLists.txt proto/CMakeLists.txt formats/CMakeLists.txt
  storage/CMakeLists.txt server/CMakeLists.txt client/CMakeLists.txt"
libraries=$(sed -nE 's/^add_library\((esg_[a-z_]+).*/\1/p' $cmake_files | sort -u)
for lib in $libraries; do
  own=$(layer "$lib")
  if [ -z "$own" ]; then
    echo "library $lib has no layer in scripts/check-architecture.sh: give it one" >&2
    fail=1
    continue
  fi
  for file in $cmake_files; do
    for dep in $(links "$file" "$lib"); do
      [[ "$dep" == esg_* ]] || continue
      below=$(layer "$dep")
      if [ -z "$below" ] || [ "$below" -ge "$own" ]; then
        echo "$lib (layer $own) links $dep (layer ${below:-none}): a library links lower layers only" >&2
        fail=1
      fi
    done
  done
done
for lib in esg_formats esg_client_lib; do
  for dep in $(links formats/CMakeLists.txt "$lib") $(links client/CMakeLists.txt "$lib"); do
    case "$dep" in
      SQLite::SQLite3 | PkgConfig::LIBPQ | esg_storage)
        echo "$lib links $dep: reading a file or calling the server needs no database" >&2
        fail=1 ;;
    esac
  done
done
# Functions over 120 lines in estimator/ and server/ (docs/conventions.md, "Code"): each says why
# at its head, a comment line "// Over 120 lines because" among the 12 lines above its start.
if ! command -v ctags-universal >/dev/null 2>&1; then
  echo "ctags-universal (Debian package universal-ctags) is needed to measure functions" >&2
  fail=1
else
  while read -r length file start name; do
    head=$(sed -n "$((start > 12 ? start - 12 : 1)),$((start - 1))p" "$file")
    if ! grep -q "// Over 120 lines because" <<<"$head"; then
      echo "$file:$start: $name is $length lines (over 120) without its reason at its head" >&2
      fail=1
    fi
  done < <(ctags-universal --languages=C++ --kinds-C++=f --fields=+ne -R -f - estimator server |
    awk -F'\t' '{ start = ""; end = ""
      for (i = 4; i <= NF; i++) {
        if ($i ~ /^line:/) start = substr($i, 6)
        if ($i ~ /^end:/) end = substr($i, 5)
      }
      if (start != "" && end != "" && end - start + 1 > 120) print end - start + 1, $2, start, $1 }')
fi
[ "$fail" -eq 0 ] || exit 1
echo "architecture check: the filter is free of I/O and of the discovery; the discovery of the layers above and of back-arrows; the formats of the stores; every link line points to a lower layer; no function over 120 lines without its reason"
