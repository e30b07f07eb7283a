#!/bin/sh
# The house's arrows (docs/ARCHITECTURE.md): a folder includes only itself and the folders
# ranked below it. hal is the floor; firmware sees only hal; sim/'s folders go numeric and
# fits < optics < survey < draw < sn; analysis reads products through sim/; tools (the
# commands) sit on everything. Prints every include that points the wrong way.
set -eu
cd "$(dirname "$0")/.."
rank() {
  case "$1" in
    hal) echo 0 ;; firmware) echo 1 ;;
    sim/numeric|sim/fits) echo 2 ;; sim/optics) echo 3 ;; sim/survey) echo 4 ;;
    sim/draw) echo 5 ;; sim/sn) echo 6 ;; analysis) echo 7 ;; tools) echo 8 ;;
    *) echo "" ;;
  esac
}
bad=0
for f in hal/*.[ch] firmware/*.[ch] sim/*/*.[ch] analysis/*.[ch] tools/*.[ch]; do
  from=$(dirname "$f"); rf=$(rank "$from")
  [ -n "$rf" ] || { echo "layers: $f is in a folder without a rank ($from)"; bad=1; continue; }
  for inc in $(sed -n 's/^#include "\([a-z_/]*\)\/[a-z_0-9]*\.h".*/\1/p' "$f" | sort -u); do
    [ "$inc" = "$from" ] && continue
    [ "$inc" = tests ] && continue
    ri=$(rank "$inc")
    if [ -z "$ri" ] || [ "$ri" -ge "$rf" ]; then
      echo "layers: $f includes $inc/ (rank ${ri:-none}), which is not below $from/ (rank $rf)"; bad=1
    fi
  done
done
[ "$bad" -eq 0 ] && echo "layers: every include points down"
exit "$bad"
