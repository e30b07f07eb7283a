#!/bin/sh
# Runs every Check test program given, then prints one closing line:
#   tests: N passed, N failed, N skipped
# A test that printed "SKIP:" (its data were absent) counts as skipped, not passed.
# Check's failure lines are repeated just above the closing line, so that a log cut to its
# last lines (CI keeps only the tail) still says which test failed and why.
set -u
# Check's own default is 4 s a test, which a loaded or slow machine can exceed in a test
# that is right; test cases that need longer set their own.
export CK_DEFAULT_TIMEOUT="${CK_DEFAULT_TIMEOUT:-60}"
passed=0; failed=0; skipped=0; status=0
tmp=$(mktemp -d); export TMPDIR="$tmp"
fails="$tmp/failures"; : >"$fails"
for t in "$@"; do
  out="$tmp/$(basename "$t").log"
  "$t" >"$out" 2>&1; rc=$?
  cat "$out"
  line=$(grep -E '^[0-9]+%: Checks: ' "$out" | tail -n 1)
  n=$(echo "$line" | sed -n 's/.*Checks: \([0-9]*\).*/\1/p')
  f=$(echo "$line" | sed -n 's/.*Failures: \([0-9]*\).*/\1/p')
  e=$(echo "$line" | sed -n 's/.*Errors: \([0-9]*\).*/\1/p')
  s=$(grep -c '^SKIP:' "$out")
  if [ -z "$n" ]; then
    echo "$t: no Check summary (exit $rc)"; failed=$((failed + 1)); status=1
    echo "$t: no Check summary (exit $rc); its last lines:" >>"$fails"
    tail -n 5 "$out" >>"$fails"; continue
  fi
  grep -E ':[FE]:' "$out" >>"$fails"
  passed=$((passed + n - f - e - s)); failed=$((failed + f + e)); skipped=$((skipped + s))
  [ "$rc" -ne 0 ] && status=1
done
if [ -s "$fails" ]; then echo "failed:"; cat "$fails"; fi
rm -rf "$tmp"
echo "tests: $passed passed, $failed failed, $skipped skipped"
exit $status
