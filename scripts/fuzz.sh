#!/usr/bin/env bash
# The libFuzzer targets of fuzz/ (docs/fuzzing.md), built with clang-14, ASan and UBSan into
# ./build-fuzz (CMake preset "fuzz"), apart from the normal build.
#
#   bash scripts/fuzz.sh build                 install clang-14 + libFuzzer if missing, build
#   bash scripts/fuzz.sh smoke [SECONDS]       build, run every target SECONDS (default 25) from
#                                              its seed corpus, ESG_JOBS (default 2) at a time;
#                                              fails on any crash or violation
#   bash scripts/fuzz.sh long [RUNS] [TARGET...]  build those targets, run each (default all) for RUNS
#                                              executions (default 10000000), one at a time at
#                                              nice 10; corpus kept in build-fuzz/long/corpus/
#                                              so a later run continues from its coverage; one
#                                              line per target appended to the results file
#                                              ($ESG_FUZZ_RESULTS, default
#                                              build-fuzz/long/results.tsv); ESG_FUZZ_WORK=DIR
#                                              instead of build-fuzz/long runs a second one
#                                              beside it (its own corpus, log and results)
#   bash scripts/fuzz.sh targets               list the targets
#
# A crash leaves its input in build-fuzz/artifacts/<target>/ (reproduce, with full allocation
# stacks: ASAN_OPTIONS=fast_unwind_on_malloc=0 build-fuzz/fuzz/<target> <file>); it then
# becomes a seed in fuzz/corpus/<target>/ and a
# GoogleTest regression test (docs/fuzzing.md, "A finding").
set -euo pipefail
cd "$(dirname "$0")/.."

TARGETS=(recording_csv column_mapping config_json telemetry_frame checkpoint aem oem token_file scenario)

install_fuzz_deps() {
  bash scripts/install-deps.sh
  local packages=(clang-14 libclang-rt-14-dev ninja-build)
  local missing=()
  for p in "${packages[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  local sudo=""
  if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then sudo=sudo; fi
  echo "installing: ${missing[*]}" >&2
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
}

# Builds the targets named (fuzz_<name>), or all of them.
build() {
  install_fuzz_deps
  local launcher=()
  if command -v ccache >/dev/null 2>&1; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
  cmake --preset fuzz "${launcher[@]}" >/dev/null
  local targets=()
  for t in "$@"; do targets+=(--target "fuzz_$t"); done
  cmake --build build-fuzz -j"${ESG_JOBS:-2}" "${targets[@]}"
}

# ASan keeps the allocation stack of every heap block in its stack depot, for the life of the
# process. Its fast unwinder follows frame pointers, which Debian's libprotobuf and libstdc++ do
# not keep, so from the third frame of an allocation made inside them it reads whatever lies on
# the stack: nearly every such stack is new. Measured on config_json, 400,000 executions: 3.1
# million depot entries (192 MB) at 20 frames, 2.8 million at 5, 770,000 at 3 after 100,000
# executions, 603 at 2; a 10-million run would end at -rss_limit_mb (an out-of-memory
# "finding" that is not the product's). A long run keeps 2 frames (the allocating function and
# its caller; docs/fuzzing.md "Memory of a long run"): its findings are re-run from their
# artifacts for full stacks. The smoke run (seconds) keeps 20 for the CI log.
asan_options() {
  echo "${ASAN_OPTIONS_GIVEN:-abort_on_error=1:detect_leaks=1:malloc_context_size=$1}"
}
ASAN_OPTIONS_GIVEN="${ASAN_OPTIONS:-}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"

# run TARGET WORKDIR FLAGS...: libFuzzer on a scratch corpus WORKDIR/corpus (new inputs go there)
# with the seeds of fuzz/corpus/TARGET; the log in WORKDIR/TARGET.log.
run() {
  local target=$1 work=$2
  shift 2
  mkdir -p "$work/corpus/$target" "build-fuzz/artifacts/$target"
  local dict=()
  [ -f "fuzz/dict/$target.dict" ] && dict=(-dict="fuzz/dict/$target.dict")
  "build-fuzz/fuzz/fuzz_$target" "$@" "${dict[@]}" -timeout=25 -rss_limit_mb=2560 \
    -print_final_stats=1 -artifact_prefix="build-fuzz/artifacts/$target/" \
    "$work/corpus/$target" "fuzz/corpus/$target" >"$work/$target.log" 2>&1
}

# The figures of a finished run from its log: executions, exec/s, cov, ft, corpus units.
stats() {
  local log=$1
  local execs rate cov ft corp
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  cov=$(grep -Eo 'cov: [0-9]+' "$log" | tail -1 | cut -d' ' -f2)
  ft=$(grep -Eo 'ft: [0-9]+' "$log" | tail -1 | cut -d' ' -f2)
  corp=$(grep -Eo 'corp: [0-9]+' "$log" | tail -1 | cut -d' ' -f2)
  printf '%s\t%s\t%s\t%s\t%s' "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "${corp:-?}"
}

case "${1:-}" in
  build)
    build
    ;;
  targets)
    printf '%s\n' "${TARGETS[@]}"
    ;;
  smoke)
    seconds=${2:-25}
    export ASAN_OPTIONS="$(asan_options 20)"
    build
    work=build-fuzz/smoke
    rm -rf "$work"
    mkdir -p "$work"
    # The targets run ESG_JOBS at a time (default 2, one per core): each is one process of one
    # thread, and each keeps its own scratch corpus and log.
    jobs=${ESG_JOBS:-2}
    for t in "${TARGETS[@]}"; do
      while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do wait -n || true; done
      ( code=0; run "$t" "$work" -max_total_time="$seconds" || code=$?; echo "$code" >"$work/$t.code" ) &
    done
    wait
    failed=()
    printf 'target\texecutions\texec/s\tcov\tft\tcorpus\tresult\n'
    for t in "${TARGETS[@]}"; do
      result=clean
      [ "$(cat "$work/$t.code" 2>/dev/null)" = 0 ] || { result=FAILED; failed+=("$t"); }
      printf '%s\t%s\t%s\n' "$t" "$(stats "$work/$t.log")" "$result"
    done
    if [ ${#failed[@]} -ne 0 ]; then
      for t in "${failed[@]}"; do
        echo "--- $t: last lines of $work/$t.log" >&2
        tail -40 "$work/$t.log" >&2
      done
      echo "fuzz smoke: FAILED (${failed[*]}); inputs in build-fuzz/artifacts/" >&2
      exit 1
    fi
    echo "fuzz smoke: clean (${#TARGETS[@]} targets, ${seconds} s each)"
    ;;
  long)
    runs=${2:-10000000}
    shift $(( $# >= 2 ? 2 : 1 ))
    selected=("$@")
    [ ${#selected[@]} -eq 0 ] && selected=("${TARGETS[@]}")
    export ASAN_OPTIONS="$(asan_options 2)"
    build "${selected[@]}"
    work=${ESG_FUZZ_WORK:-build-fuzz/long}
    results=${ESG_FUZZ_RESULTS:-$work/results.tsv}
    mkdir -p "$work"
    [ -f "$results" ] || printf 'date\ttarget\trequested\texecutions\texec/s\tcov\tft\tcorpus\tseconds\tresult\n' >"$results"
    for t in "${selected[@]}"; do
      start=$(date +%s)
      # libFuzzer exits 72 when interrupted (SIGINT): the figures so far are printed and kept.
      code=0
      nice -n 10 bash -c "$(declare -f run); run $t $work -runs=$runs" || code=$?
      case $code in 0) result=clean ;; 72) result=interrupted ;; *) result=FINDING ;; esac
      printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$(date -u +%FT%TZ)" "$t" "$runs" "$(stats "$work/$t.log")" \
        "$(( $(date +%s) - start ))" "$result" | tee -a "$results"
    done
    ;;
  *)
    sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
