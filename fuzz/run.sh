#!/bin/bash
# Runs the fuzz harnesses (make fuzz / make fuzz-smoke; fuzz/README.md).
#   fuzz/run.sh [--smoke] BIN...     each BIN (build/fuzz/bin/fuzz_T) with fuzz/corpus/T
# Full run: libFuzzer for FUZZ_SECONDS per target (FUZZ_JOBS at a time), new inputs kept in
# build/fuzz/work/T, crashes in build/fuzz/crashes/T; the table goes to
# build/fuzz/summary.md and docs/FUZZ.md (bench/run.sh puts it into docs/BENCHMARKS.md).
# --smoke: every corpus input run once, no fuzzing (CI: the harnesses build and the saved
# regression inputs still pass); writes only build/fuzz/summary.md.
# Exits non-zero when any target crashed, leaked, timed out or ran out of memory.
set -u
cd "$(dirname "$0")/.."
# A request too large to serve returns NULL, as glibc's malloc does, so that the callers'
# (and cfitsio's) out-of-memory paths run; libFuzzer still fails any single request above
# -rss_limit_mb.
export ASAN_OPTIONS="allocator_may_return_null=1${ASAN_OPTIONS:+:$ASAN_OPTIONS}"
out=build/fuzz
secs=${FUZZ_SECONDS:-60}
jobs=${FUZZ_JOBS:-1}

if [ "${1:-}" = --one ]; then
  smoke=$2 bin=$3
  t=${bin##*/fuzz_}
  mkdir -p "$out/work/$t" "$out/crashes/$t" "$out/logs" "$out/tmp"
  log=$out/logs/$t.log
  common="-print_final_stats=1 -artifact_prefix=$out/crashes/$t/ -timeout=20 -rss_limit_mb=2048"
  start=$(date +%s)
  TIMEFORMAT='%U %S'
  if [ "$smoke" = 1 ]; then
    # each seed once (libFuzzer runs named files, it does not fuzz them)
    { time TMPDIR=$out/tmp "$bin" $common fuzz/corpus/"$t"/* >"$log" 2>&1; } 2>"$log.cpu"
  else
    { time TMPDIR=$out/tmp "$bin" $common -max_total_time="$secs" "$out/work/$t" \
        fuzz/corpus/"$t" >"$log" 2>&1; } 2>"$log.cpu"
  fi
  rc=$?
  end=$(date +%s)
  cpu=$(awk '{ printf "%.0f", $1 + $2 }' "$log.cpu")
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -n 1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -n 1 | cut -d' ' -f2)
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -n 1 | cut -d' ' -f2)
  rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$log" | tail -n 1)
  [ "$smoke" = 1 ] && execs=$(ls fuzz/corpus/"$t" | wc -l)
  crashes=$(ls "$out/crashes/$t" | wc -l)
  if [ $rc = 0 ]; then result=clean; else result="FAILED (exit $rc, see $log)"; fi
  printf '| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n' "$t" "$((end - start))" "$cpu" \
    "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "${rss:-?}" "$crashes" "$result" \
    >"$out/logs/$([ "$smoke" = 1 ] && echo smoke/)$t.row"
  echo "fuzz: $t: $result, $((end - start)) s, ${execs:-?} executions, cov ${cov:-?}" >&2
  exit $rc
fi

smoke=0
[ "${1:-}" = --smoke ] && { smoke=1; shift; }
[ $# -gt 0 ] || { echo "usage: fuzz/run.sh [--smoke] build/fuzz/bin/fuzz_T..." >&2; exit 2; }
# smoke rows apart from fuzzing rows: a smoke run never stands in a fuzzing table
rows=$out/logs
[ $smoke = 1 ] && rows=$out/logs/smoke
mkdir -p "$rows"
# the table keeps the last row of every target, so one target can be run again alone
for bin in "$@"; do rm -f "$rows/${bin##*/fuzz_}.row"; done
status=0
printf '%s\n' "$@" | xargs -n 1 -P "$jobs" "$0" --one "$smoke" || status=1

# A full run of some targets keeps the other targets' rows of docs/FUZZ.md (a fresh tree has
# no build/fuzz/logs), so the table always has every target's latest run.
if [ $smoke = 0 ] && [ -f docs/FUZZ.md ]; then
  grep -E '^\| [a-z_]+ \| [0-9]' docs/FUZZ.md | while IFS= read -r row; do
    t=$(echo "$row" | cut -d'|' -f2 | tr -d ' ')
    [ -e fuzz/fuzz_"$t".c ] && [ ! -e "$out/logs/$t.row" ] && printf '%s\n' "$row" >"$out/logs/$t.row"
  done
fi
summary=$out/summary.md
cpu=$(sed -n 's/^model name[^:]*: *//p' /proc/cpuinfo | head -n 1)
cc=$(${FUZZ_CC:-clang} --version | head -n 1)
commit=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
{
  if [ $smoke = 1 ]; then
    echo "Smoke run (each corpus input once), $(date -u '+%Y-%m-%d %H:%M UTC'), commit $commit."
  else
    echo "\`make fuzz FUZZ_SECONDS=$secs FUZZ_JOBS=$jobs\`, last run $(date -u '+%Y-%m-%d %H:%M UTC') at commit"
    echo "$commit: libFuzzer with ASan + UBSan ($cc), $(nproc) cores ($cpu) shared with other"
    echo "builds, $jobs target(s) at a time. Each row is that target's latest run, from its seed"
    echo "corpus (fuzz/corpus/) plus what earlier runs kept (build/fuzz/work/)."
  fi
  echo
  echo "| target | seconds | CPU s | executions | exec/s | cov | features | peak RSS MiB | crash files | result |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
  cat "$rows"/*.row
} >"$summary"
[ $smoke = 1 ] || cp "$summary" docs/FUZZ.md
cat "$summary"
exit $status
