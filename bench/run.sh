#!/bin/sh
# make bench: runs the benchmarks and writes docs/BENCHMARKS.md (measured table, the
# command that produced each line, and the machine). Sized for a 2-core machine: about
# 10 minutes. BENCH_QUICK=1 runs a reduced set (smaller images) for a smoke test.
set -eu
usage="usage: bench/run.sh (no arguments; BENCH_QUICK=1 for the reduced set). Writes docs/BENCHMARKS.md."
case "${1-}" in
  "") ;;
  -h|--help) echo "$usage"; exit 0 ;;
  *) echo "bench/run.sh: unknown argument '$1'" >&2; echo "$usage" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
B=build/rel/bench
make -s $B/bench_readout $B/bench_direct_error $B/bench_survey $B/bench_profile $B/bench_pages $B/bench_cores $B/bench_coadd $B/rss bin/wfisim >/dev/null
out=docs/BENCHMARKS.md
REF="${WFISIM_REFERENCE:-../shared/reference}/galsim"
DATA="${WFISIM_DATA:-../shared/data}"
tmp=$(mktemp)
N=4088
[ "${BENCH_QUICK:-0}" = 1 ] && N=1024
cpu=$(grep -m1 'model name' /proc/cpuinfo | sed 's/.*: //')
mem=$(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)
field() { echo "$1" | tr ' ' '\n' | sed -n "s/^$2=//p"; }
# median, min and max of numbers on standard input, one a line: "median (min-max)"
spread() { sort -n | awk '{a[NR] = $1} END {m = NR % 2 ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2; printf "%.3f (%.3f-%.3f)", m, a[1], a[NR]}'; }
median() { spread | cut -d' ' -f1; }

row_readout() { # label, args...
  label=$1; shift
  line=$($B/bench_readout "$@")
  echo "| $label | \`bench_readout $*\` | $(field "$line" wall_s) | $(field "$line" cpu_s) | $(field "$line" Mpixreads_per_cpu_s) | $(field "$line" arena_MiB) | $(field "$line" peak_rss_MiB) |" >>"$tmp"
  echo "  $label: $line" >&2
}

{
  echo "# Benchmarks"
  echo
  echo "Written by \`make bench\` (bench/run.sh) on $(date -u +%Y-%m-%d). Machine: $cpu, $(nproc) cores, $mem, $(uname -sr)."
  echo "Compiler: $(cc --version | head -n 1). Numbers are single runs on a machine that may"
  echo "be doing other work; compare orders of magnitude, not the last digit."
  echo
  echo "## Firmware path: full SCA, Y106 deep-field sky only, MA table 6 (300 s)"
  echo
  echo "Packets go to a null link, so this is the readout alone (scene source, detector chain,"
  echo "resultant averaging, deflate). Pixel-reads per CPU-second count every digitised read"
  echo "(per-read) or every drawn resultant (direct, moments)."
  echo
  echo "| case | command | wall s | CPU s | M pixel-reads / CPU-s | arena MiB | peak RSS MiB |"
  echo "|---|---|---|---|---|---|---|"
} >"$tmp"
for t in 16 64 256; do
  row_readout "per-read, ${t}-row tiles, 2 threads" $N $N $t per-read 6 2
done
for t in 16 64 256; do
  row_readout "direct, ${t}-row tiles, 2 threads" $N $N $t direct 6 2
done
row_readout "moments, 64-row tiles, 2 threads" $N $N 64 moments 6 2
row_readout "per-read, MA table 11 (977 s), 64-row tiles, 2 threads" $N $N 64 per-read 11 2
row_readout "direct, MA table 11 (977 s), 64-row tiles, 2 threads" $N $N 64 direct 11 2
row_readout "moments, MA table 11 (977 s), 64-row tiles, 2 threads" $N $N 64 moments 11 2
{
  echo
  echo "## Error of direct-resultant sampling (knob: exposure.sampling)"
  echo
  echo "Flat fields through the whole chain (readout, assembly with linearity correction, ramp"
  echo "fit) on a 256x256 SCA, cosmic rays off; per-read sampling is the high-fidelity reference."
  echo "\`bench_direct_error 256 6\` and \`bench_direct_error 256 11\`:"
  echo
  $B/bench_direct_error 256 6
  $B/bench_direct_error 256 11 | tail -n +3
  echo
  echo "## Error of moments sampling (knob: exposure.sampling)"
  echo
  echo "The same on a 1024x1024 SCA at a sky-like, a faint-source and two bright-source rates:"
  echo "\`bench_direct_error 1024 6 moments 0.4,5,300,3000\`:"
  echo
  $B/bench_direct_error 1024 6 moments 0.4,5,300,3000
  echo
  echo "## Peak RSS against image size (per-read, 64-row tiles, 1 thread)"
  echo
  echo "The firmware reserves its arena from the tile height, the row width and the MA table;"
  echo "it must not grow with the image height. A tile is a band of whole rows, so it does"
  echo "grow with the row width (the SCA is 4088 wide; narrower images are test sizes)."
  echo
  echo "| case | command | wall s | CPU s | M pixel-reads / CPU-s | arena MiB | peak RSS MiB |"
  echo "|---|---|---|---|---|---|---|"
} >>"$tmp"
for n in 1024 2048; do
  row_readout "4088 wide x ${n} rows" 4088 $n 64 per-read 6 1
done
[ $N = 4088 ] && row_readout "4088 wide x 4088 rows" 4088 4088 64 per-read 6 1
for n in 1024 2048; do
  row_readout "${n}x${n}" $n $n 64 per-read 6 1
done
{
  echo
  echo "## Single-frame mode (GalSim allDetectorEffects order), full SCA, 300 s"
  echo
  echo "GalSim 2.8.4's detector chain on the same kind of machine: 1.9 s wall, 2.0 s CPU"
  echo "(../shared/reference/galsim/README.md)."
  echo
  echo "| case | command | wall s | CPU s | M pixels / CPU-s | arena MiB | peak RSS MiB |"
  echo "|---|---|---|---|---|---|---|"
} >>"$tmp"
row_readout "single frame, 1 thread" $N $N 64 single 6 1
row_readout "single frame, 2 threads" $N $N 64 single 6 2
{
  echo
  echo "## First touch of fresh memory: 4 KiB pages against huge pages"
  echo
  echo "Why the arenas and the host's large buffers are on transparent huge pages"
  echo "(\`wf_arena_host_alloc\`, \`wf_arena_host_realloc\` in hal/arena.h): filling fresh memory"
  echo "the first time, page faults and the kernel's zeroing included, against filling it again."
  echo "\`bench_pages 64 3\` (64 MiB, best of 3):"
  echo
  echo "| pages | first fill, ms per MiB | second fill, ms per MiB | page faults | µs per fault |"
  echo "|---|---|---|---|---|"
} >>"$tmp"
$B/bench_pages 64 3 | while read -r line; do
  echo "| $(field "$line" pages) | $(field "$line" first_touch_ms_per_MiB) | $(field "$line" refill_ms_per_MiB) | $(field "$line" faults) | $(field "$line" us_per_fault) |" >>"$tmp"
done
{
  echo
  echo "## What a second core gives on this machine"
  echo
  echo "\`bench_cores 3\`: each task on one thread alone, then on two threads at once (each doing"
  echo "the whole task); throughput = 2 × alone / at once, 2 where the cores share nothing. Best"
  echo "of 3 rounds. On this kind of virtual machine the answer changes from one run to the next,"
  echo "even for arithmetic in the first-level cache (the second vCPU is not always a core of its own)."
  echo
  echo "| task | alone, ms | at once, ms (the slower thread) | throughput of two cores |"
  echo "|---|---|---|---|"
} >>"$tmp"
$B/bench_cores 3 | while read -r line; do
  name=$(echo "$line" | sed -n 's/^case="\([^"]*\)".*/\1/p')
  echo "| $name | $(field "$line" alone_ms) | $(field "$line" both_ms) | $(field "$line" throughput_x) |" >>"$tmp"
done
{
  echo
  echo "## Whole program: \`wfisim demo\` (readout + in-process assembly + ramp fit + FITS)"
  echo
  echo "| case | command | wall s | CPU s | peak RSS MiB |"
  echo "|---|---|---|---|---|"
} >>"$tmp"
for th in 1 2; do
  d=$(mktemp -d)
  r=$($B/rss bin/wfisim demo --quiet --threads $th --out "$d" --set paths.data=$DATA --set readout.ncols=$N --set readout.nrows=$N 2>&1 | grep '^rss:')
  echo "| demo (synthetic scene, up the ramp), $th thread(s) | \`wfisim demo --threads $th\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  echo "  demo $th: $r" >&2
  rm -rf "$d"
done
if [ -f "$REF/scene_catalog_sca1_pointingA.csv.gz" ] && [ $N = 4088 ]; then
  {
    echo
    echo "## GalSim's benchmark scene (8,400 galaxies, 140 stars, 5 SNe as stars; SCA 1, pointing A, Y106, 300 s)"
    echo
    echo "GalSim 2.8.4 on the same kind of machine (../shared/reference/galsim/README.md): FFT"
    echo "drawing 184 s wall / ≈184 CPU-s, 1.98 GB; photon shooting 16.3 s wall / ≈21 CPU-s,"
    echo "2.32 GB; detector chain alone 1.9 s. wfisim draws in Fourier space (stamps holding"
    echo "≥ 99.5% of the flux; faint objects with the knobs their sky noise allows,"
    echo "\`scene.noise_tolerance\` 1, and the split PSF), single-frame detector chain. \"every"
    echo "object exact\" sets \`scene.noise_tolerance=0\`. An empty scene (sky only) shows what the"
    echo "detector chain and sky cost alone."
    echo
    echo "| case | command | wall s | CPU s | peak RSS MiB |"
    echo "|---|---|---|---|---|"
  } >>"$tmp"
  SC="--quiet --mode single --set exposure.exptime=300 --set paths.data=$DATA"
  for th in 1 2; do
    d=$(mktemp -d)
    r=$($B/rss bin/wfisim expose $SC --set scene.kind=galsim --set scene.catalog=$REF/scene_catalog_sca1_pointingA.csv.gz --threads $th --out "$d" 2>&1 | grep '^rss:')
    echo "| GalSim scene, $th thread(s) | \`wfisim expose --mode single --set scene.kind=galsim ... --threads $th\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
    echo "  galsim scene $th: $r" >&2
    rm -rf "$d"
  done
  d=$(mktemp -d)
  r=$($B/rss bin/wfisim expose $SC --set scene.kind=galsim --set scene.catalog=$REF/scene_catalog_sca1_pointingA.csv.gz --set run.uncached_writes=false --threads 1 --out "$d" 2>&1 | grep '^rss:')
  echo "| GalSim scene, 1 thread, the product through the page cache | \`wfisim expose ... --set run.uncached_writes=false\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  echo "  galsim scene cached: $r" >&2
  rm -rf "$d"
  d=$(mktemp -d)
  r=$($B/rss bin/wfisim expose $SC --set scene.kind=galsim --set scene.catalog=$REF/scene_catalog_sca1_pointingA.csv.gz --set scene.noise_tolerance=0 --set scene.stamp_pool=48 --threads 1 --out "$d" 2>&1 | grep '^rss:')
  echo "| GalSim scene, every object exact (whole stamps: a pool that holds them), 1 thread | \`wfisim expose ... --set scene.noise_tolerance=0 --set scene.stamp_pool=48\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  echo "  galsim scene exact: $r" >&2
  rm -rf "$d"
  # time against the number of objects: the first N rows of the catalog (galaxies)
  sub=$(mktemp -d)
  for n in 1000 2000 4000 8000; do
    { gzip -dc "$REF/scene_catalog_sca1_pointingA.csv.gz" | head -n $((n + 1)); } >"$sub/first$n.csv"
    d=$(mktemp -d)
    r=$($B/rss bin/wfisim expose $SC --set scene.kind=galsim --set scene.catalog="$sub/first$n.csv" --threads 1 --out "$d" 2>&1 | grep '^rss:')
    echo "| first $n galaxies of the scene, 1 thread | \`wfisim expose ... (first $n rows)\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
    echo "  scaling $n: $r" >&2
    rm -rf "$d"
  done
  rm -rf "$sub"
  d=$(mktemp -d)
  r=$($B/rss bin/wfisim expose $SC --set scene.kind=grid --set scene.grid.flux=0 --out "$d" 2>&1 | grep '^rss:')
  echo "| empty scene (sky only), 1 thread | \`wfisim expose --mode single --set scene.kind=grid --set scene.grid.flux=0\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  rm -rf "$d"
  # The ceiling for --threads 2: two independent one-thread jobs at once do twice the work
  # with no serial part and nothing shared, so a two-thread run of one job can hardly beat
  # half their time. Rounds alternate, so that the three see the same spells of the machine.
  pr=$(mktemp -d)
  GS="$SC --set scene.kind=galsim --set scene.catalog=$REF/scene_catalog_sca1_pointingA.csv.gz"
  for i in 1 2 3 4 5 6; do
    rm -rf "$pr/solo" "$pr/a" "$pr/b" "$pr/two"
    r=$($B/rss bin/wfisim expose $GS --threads 1 --out "$pr/solo" 2>&1 | grep '^rss:')
    echo "$(field "$r" wall_s)" >>"$pr/solo.t"
    $B/rss bin/wfisim expose $GS --threads 1 --out "$pr/a" >"$pr/a.r" 2>&1 &
    pa=$!
    rb=$($B/rss bin/wfisim expose $GS --threads 1 --out "$pr/b" 2>&1 | grep '^rss:')
    wait $pa
    ra=$(grep '^rss:' "$pr/a.r")
    wa=$(field "$ra" wall_s)
    wb=$(field "$rb" wall_s)
    awk -v a="$wa" -v b="$wb" 'BEGIN {print (a > b ? a : b)}' >>"$pr/pair.t"
    r=$($B/rss bin/wfisim expose $GS --threads 2 --out "$pr/two" 2>&1 | grep '^rss:')
    echo "$(field "$r" wall_s)" >>"$pr/two.t"
    echo "  ceiling round $i: alone $(tail -n 1 "$pr/solo.t") pair $(tail -n 1 "$pr/pair.t") two $(tail -n 1 "$pr/two.t")" >&2
  done
  solo=$(median <"$pr/solo.t")
  pair=$(median <"$pr/pair.t")
  two=$(median <"$pr/two.t")
  {
    echo
    echo "What two cores allow for this job: six rounds, each a one-thread run alone, two one-thread"
    echo "runs started together (the later one's wall time), and one \`--threads 2\` run; wall s,"
    echo "median (min-max), fresh output folders."
    echo
    echo "| case | wall s |"
    echo "|---|---|"
    echo "| one job, 1 thread, alone | $(spread <"$pr/solo.t") |"
    echo "| two jobs of 1 thread at once | $(spread <"$pr/pair.t") |"
    echo "| one job, \`--threads 2\` | $(spread <"$pr/two.t") |"
    echo
    awk -v s="$solo" -v p="$pair" -v t="$two" 'BEGIN {
      printf "Two cores give this job %.2f× the throughput of one (2 × alone / at once). `--threads 2`\n", 2 * s / p
      printf "is %.2f× faster than one thread; its wall time is %.2f× half of \"at once\", the most a\n", s / t, t / (p / 2)
      printf "split of one job into two could expect. Halving the wall time needs 2× from the pair first.\n" }'
  } >>"$tmp"
  rm -rf "$pr"
fi
if [ -f "$REF/scene_catalog_sca1_pointingA.csv.gz" ]; then
  pd=$(mktemp -d)
  exact=$($B/bench_profile --tol 0 --dump "$pd/exact.bin" 2>&1)
  prof=$($B/bench_profile --compare "$pd/exact.bin" 2>&1)
  rm -rf "$pd"
  {
    echo
    echo "Drawing alone, per object (\`bench_profile\`: every object of the GalSim scene drawn once, as"
    echo "the renderer draws it, no detector chain; by stamp side). Every object exact"
    echo "(\`--tol 0\`), then the defaults compared with it (worst pixel in units of the object's"
    echo "peak and of one pixel's sky noise over 300 s):"
    echo
    echo '```'
    echo "$exact"
    echo "$prof"
    echo '```'
  } >>"$tmp"
fi

# ---- survey plan, footprint selection, survey run, supernovae ------------------------
sd=$(mktemp -d)
rssrow() { # label, shown command, command...
  label=$1; shown=$2; shift 2
  r=$($B/rss "$@" 2>&1 >/dev/null | grep '^rss:')
  echo "| $label | \`$shown\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  echo "  $label: $r" >&2
}
{
  echo
  echo "## Survey plan, footprint selection, survey run"
  echo
  echo "| case | command | wall s | CPU s | peak RSS MiB |"
  echo "|---|---|---|---|---|"
} >>"$tmp"
rssrow "deep-tier plan (146 visits, 9,344 exposures) + coverage + overlap check + PNGs" "wfisim survey plan --out plan.fits" bin/wfisim survey plan --quiet --data "$DATA" --out "$sd/plan.fits"
NEXP=10; [ "${BENCH_QUICK:-0}" = 1 ] && NEXP=2
rssrow "survey run: $NEXP exposures x SCA 1, synthetic scene, single frame, 2 threads" "wfisim survey run --plan plan.fits --exposures 0:$((NEXP - 1)) --scas 1 --mode single --threads 2" bin/wfisim survey run --quiet --data "$DATA" --plan "$sd/plan.fits" --exposures 0:$((NEXP - 1)) --scas 1 --mode single --threads 2 --set readout.ncols=$N --set readout.nrows=$N --out "$sd/run"
rssrow "the same again: every product verifies and is skipped" "wfisim survey run ... (again)" bin/wfisim survey run --quiet --data "$DATA" --plan "$sd/plan.fits" --exposures 0:$((NEXP - 1)) --scas 1 --mode single --threads 2 --set readout.ncols=$N --set readout.nrows=$N --out "$sd/run"
sel=$($B/bench_survey select "$DATA" 2>/dev/null)
{
  echo
  echo "Footprint selection (\`bench_survey select\`), the 18 SCAs of one pointing out of the whole"
  echo "synthetic field:"
  echo
  echo '```'
  echo "$sel"
  echo '```'
  echo
  echo "\`case=index\`: the sky index over the whole field, as for a catalog read from a file"
  echo "(\`select_ms_per_sca\` is one SCA's query); \`case=synth_select\`: the synthetic generator's"
  echo "own path, which generates only the cells under the SCA (what \`expose\` and \`survey run\` do)."
} >>"$tmp"
# Survey products: CPU-s per SCA-exposure, one thread, products written, for the plan's own
# exposures (the second pointing in each filter: EXPID 1, 17, 33, 49 = Y106, J129, H158,
# F184; Y/J/H 300 s -> MA table 6, F184 900 s -> MA table 11), and the deep tier projected
# from them. An item is measured as a run in plan order makes it: its persistence history
# (depth 1 here: the exposure before it) comes from that exposure's own drawing, not drawn
# again. So each row is the CPU of a run of E-1 and E less that of a run of E-1 alone (per-run
# set-up included once). An item alone pays ~1.0 CPU-s an earlier exposure more (a job array's
# task; EXPID 16 alone at depth 8: 13.4 against 4.0 CPU-s). Rounds alternate the cases so that
# they see the same spells of a shared machine; the median is reported.
SR=3; RR=1; [ "${BENCH_QUICK:-0}" = 1 ] && SR=1
pd=$(mktemp -d)
run_cpu() { # mode, exposures, ramp sampling[, scene cache]: prints the run's CPU-s
  rm -rf "$pd/run"
  r=$($B/rss bin/wfisim survey run --quiet --data "$DATA" --plan "$sd/plan.fits" --exposures $2 --scas 1 --mode $1 --threads 1 --set readout.ncols=$N --set readout.nrows=$N --set exposure.sampling=$3 --set detector.persistence.depth=1 --set run.scene_cache=${4:-auto} --out "$pd/run" 2>&1 >/dev/null | grep '^rss:')
  echo "  survey run $1 $3 exposures $2 scene cache ${4:-auto}: $r" >&2
  field "$r" cpu_s
}
product_cpu() { # mode, expid, file to append CPU-s to, ramp sampling (default per-read)
  both=$(run_cpu $1 "$(($2 - 1)):$2" ${4:-per-read}); first=$(run_cpu $1 $(($2 - 1)) ${4:-per-read})
  awk -v a="$both" -v b="$first" 'BEGIN {printf "%.2f\n", a - b}' >>"$3"
}
# A revisit: EXPID E + 64, the same pointing, PA and filter a visit later, its static scene
# (and E + 63's) from the scene cache the first visit's E - 1 and E left (run.scene_cache).
revisit_cpu() { # mode, expid, file, ramp sampling
  c="$pd/cache_$1_$4_$2"
  # sync: the first visit's planes are written back before the revisit is timed (unsynced,
  # the first revisit after it measured up to 4 CPU-s more, session 35)
  [ -d "$c" ] || { run_cpu $1 "$(($2 - 1)):$2" $4 "$c" >/dev/null; sync; }
  both=$(run_cpu $1 "$(($2 + 63)):$(($2 + 64))" $4 "$c"); first=$(run_cpu $1 $(($2 + 63)) $4 "$c")
  awk -v a="$both" -v b="$first" 'BEGIN {printf "%.2f\n", a - b}' >>"$3"
}
for i in $(seq $SR); do
  for e in 1 17 33 49; do product_cpu single $e "$pd/single$e.t"; revisit_cpu single $e "$pd/rsingle$e.t" per-read; done
done
for i in $(seq $RR); do
  for e in 1 49; do
    product_cpu ramp $e "$pd/ramp$e.t"; product_cpu ramp $e "$pd/mom$e.t" moments
    revisit_cpu ramp $e "$pd/rramp$e.t" per-read; revisit_cpu ramp $e "$pd/rmom$e.t" moments
  done
done
rm -rf "$pd/run"
{
  echo
  echo "## Survey products: CPU-s per SCA-exposure and the deep tier"
  echo
  echo "\`wfisim survey run --plan plan.fits --exposures E --scas 1 --mode single|ramp --threads 1\`"
  echo "(ramp: \`--set exposure.sampling=per-read|moments\`),"
  echo "synthetic deep-field scene, products written tile-compressed (the survey default; single frame 29 MB, up the ramp 213 MB),"
  echo "each product as a run in plan order makes it: the CPU of a run of EXPID E-1 and E less that of"
  echo "E-1 alone, \`--set detector.persistence.depth=1\` (E's history, exposure E-1, comes from E-1's own"
  echo "drawing; an item alone draws it, ~1.0 CPU-s more);"
  echo "CPU-s = user + sys of the whole process (wait4), median (min-max) of"
  echo "$SR (single) and $RR (ramp) alternated rounds on a machine shared with other builds."
  echo
  echo "First visit: the scene drawn (and its plane stored in the scene cache); revisit: EXPID E + 64,"
  echo "the same pointing, PA and filter a visit later, its plane (and E + 63's) read from the cache the"
  echo "first visit left (docs/SURVEY.md \"The scene cache\"); the same bytes either way."
  echo
  echo "| product | plan exposure | MA table | CPU-s, first visit | CPU-s, revisit |"
  echo "|---|---|---|---|---|"
  for c in "1 Y106 300" "17 J129 300" "33 H158 300" "49 F184 900"; do
    set -- $c
    echo "| single frame | EXPID $1, $2 $3 s | - | $(spread <"$pd/single$1.t") | $(spread <"$pd/rsingle$1.t") |"
  done
  echo "| up the ramp, per-read | EXPID 1, Y106 300 s (Y/J/H) | 6 (294 s, 93 reads) | $(spread <"$pd/ramp1.t") | $(spread <"$pd/rramp1.t") |"
  echo "| up the ramp, per-read | EXPID 49, F184 900 s | 11 (977 s, 309 reads) | $(spread <"$pd/ramp49.t") | $(spread <"$pd/rramp49.t") |"
  echo "| up the ramp, moments | EXPID 1, Y106 300 s (Y/J/H) | 6 (294 s, 93 reads) | $(spread <"$pd/mom1.t") | $(spread <"$pd/rmom1.t") |"
  echo "| up the ramp, moments | EXPID 49, F184 900 s | 11 (977 s, 309 reads) | $(spread <"$pd/mom49.t") | $(spread <"$pd/rmom49.t") |"
  echo
  s0=$(median <"$pd/single1.t"); s16=$(median <"$pd/single17.t"); s32=$(median <"$pd/single33.t"); s48=$(median <"$pd/single49.t")
  r0=$(median <"$pd/ramp1.t"); r48=$(median <"$pd/ramp49.t"); m0=$(median <"$pd/mom1.t"); m48=$(median <"$pd/mom49.t")
  v0=$(median <"$pd/rsingle1.t"); v16=$(median <"$pd/rsingle17.t"); v32=$(median <"$pd/rsingle33.t"); v48=$(median <"$pd/rsingle49.t")
  w0=$(median <"$pd/rramp1.t"); w48=$(median <"$pd/rramp49.t"); x0=$(median <"$pd/rmom1.t"); x48=$(median <"$pd/rmom49.t")
  awk -v a="$s0" -v b="$s16" -v c="$s32" -v d="$s48" -v r="$r0" -v f="$r48" -v mr="$m0" -v mf="$m48" \
      -v va="$v0" -v vb="$v16" -v vc="$v32" -v vd="$v48" -v wr="$w0" -v wf="$w48" -v xr="$x0" -v xf="$x48" 'BEGIN {
    n = 168192; hit = 7744 / 9344
    single = (1 - hit) * (a + b + c + d) / 4 + hit * (va + vb + vc + vd) / 4
    ramp = (1 - hit) * (0.75 * r + 0.25 * f) + hit * (0.75 * wr + 0.25 * wf)
    mom = (1 - hit) * (0.75 * mr + 0.25 * mf) + hit * (0.75 * xr + 0.25 * xf)
    printf "The deep tier: 9,344 exposures x 18 SCAs = %d SCA-exposures, a quarter in each filter\n", n
    printf "(Y106, J129, H158 at 300 s, MA table 6 up the ramp; F184 at 900 s, MA table 11). Assumed: CPU-s\n"
    printf "scale linearly over cores and nodes (one one-thread product per core), and the disk is not the\n"
    printf "bottleneck (it is on this 2-core machine: a ramp product takes 3-5x its CPU time in wall time\n"
    printf "here). Up-the-ramp Y/J/H are taken at the Y106 product'"'"'s cost. With the scene cache (room for\n"
    printf "one visit'"'"'s 64 planes per SCA worked on at once) 7,744 of each SCA'"'"'s 9,344 exposures are\n"
    printf "revisits (counted from the plan'"'"'s (RA, Dec, PA, filter) in plan order, docs/SURVEY.md), the rest\n"
    printf "first visits: the mean below weighs the two columns so.\n\n"
    printf "| products | mean CPU-s per SCA-exposure | CPU-hours, whole tier | hours on one 16-core node | hours on 64 such nodes |\n"
    printf "|---|---|---|---|---|\n"
    printf "| single frame | %.2f | %.0f | %.1f | %.2f |\n", single, n * single / 3600, n * single / 3600 / 16, n * single / 3600 / 1024
    printf "| up the ramp (per-read sampling) | %.2f | %.0f | %.1f | %.2f |\n", ramp, n * ramp / 3600, n * ramp / 3600 / 16, n * ramp / 3600 / 1024
    printf "| up the ramp (moments sampling) | %.2f | %.0f | %.1f | %.2f |\n", mom, n * mom / 3600, n * mom / 3600 / 16, n * mom / 3600 / 1024 }'
} >>"$tmp"
rm -rf "$pd"
if [ -d "$DATA/salt3/salt3-k21" ]; then
  {
    echo
    echo "## Supernovae over the full deep-tier plan"
    echo
    echo "| case | command | wall s | CPU s | peak RSS MiB |"
    echo "|---|---|---|---|---|"
  } >>"$tmp"
  rssrow "SN sample over the plan's footprint (hosts from the synthetic field)" "wfisim sn generate --plan plan.fits --out sne.fits" bin/wfisim sn generate --data "$DATA" --plan "$sd/plan.fits" --out "$sd/sne.fits"
  rssrow "truth light curves on every image that holds each SN" "wfisim sn lightcurves --sne sne.fits --plan plan.fits --out lc.fits" bin/wfisim sn lightcurves --data "$DATA" --sne "$sd/sne.fits" --plan "$sd/plan.fits" --out "$sd/lc.fits"
  rssrow "light curves on every plan date in each SN's model window" "wfisim sn lightcurves ... --window" bin/wfisim sn lightcurves --data "$DATA" --sne "$sd/sne.fits" --plan "$sd/plan.fits" --window --out "$sd/lcw.fits"
  n=$(bin/wfisim sn generate --data "$DATA" --plan "$sd/plan.fits" --out "$sd/sne2.fits" | sed -n 's/^wfisim sn: \([0-9]*\) supernovae.*/\1/p')
  inj=$($B/bench_survey inject "$sd/plan.fits" "$sd/sne.fits" "$DATA/salt3/salt3-k21" "$DATA" 200 2>/dev/null)
  {
    echo
    echo "$n SNe. Injection (\`bench_survey inject\`, 200 exposures spread over the plan, all 18 SCAs):"
    echo "the SN lookup and light-curve evaluation per image and per SN found in a footprint."
    echo "Drawing an SN then costs what a star costs in the renderer."
    echo
    echo '```'
    echo "$inj"
    echo '```'
  } >>"$tmp"
fi
# ---- analysis: detection on a full SCA product -----------------------------------------
{
  echo
  echo "## Analysis"
  echo
  echo "| case | command | wall s | CPU s | peak RSS MiB |"
  echo "|---|---|---|---|---|"
} >>"$tmp"
bin/wfisim demo --quiet --set paths.data="$DATA" --set readout.ncols=$N --set readout.nrows=$N --out "$sd/demo"
rssrow "detection of a full SCA (demo product, $N x $N, SExtractor defaults)" "wfisim detect wfisim_e000001_sca01.fits --out cat.fits" bin/wfisim detect --data "$DATA" "$sd/demo/wfisim_e000001_sca01.fits" --out "$sd/cat.fits"
# ---- analysis: coadd against the number of inputs --------------------------------------
# Synthetic 1024 x 1024 products of SCA 1 (bench/bench_coadd.c: the SCA's WCS at dithered
# pointings, sky and noise, 1 pixel in 500 flagged) drizzled onto one 2700 x 2700 grid at
# 0.0575": the first 2, 8 and 32. Peak RSS must not grow with the number of inputs.
cs=$(mktemp -d)
CS=1024
centre=$($B/bench_coadd "$cs" 32 $CS)
{
  echo
  echo "## Coadd (drizzle, square kernel, pixfrac 0.7) against the number of inputs"
  echo
  echo "Inputs ${CS} x ${CS} (synthetic products, bench/bench_coadd.c), output 2700 x 2700 at 0.0575\", 256-row tiles."
  echo
  echo "| inputs | command | wall s | CPU s | input Mpixel / CPU-s | peak RSS MiB |"
  echo "|---|---|---|---|---|---|"
} >>"$tmp"
for n in 2 8 32; do
  ls "$cs"/wfisim_e*_sca01.fits | head -n $n >"$cs/list$n"
  r=$($B/rss bin/wfisim coadd --quiet --center "$centre" --size 2700,2700 --out "$cs/coadd$n.fits" @"$cs/list$n" 2>&1 >/dev/null | grep '^rss:')
  thr=$(awk -v n=$n -v s=$CS -v c="$(field "$r" cpu_s)" 'BEGIN {printf "%.2f", n * s * s / c / 1e6}')
  echo "| $n | \`wfisim coadd --center RA,DEC --size 2700,2700 @list$n\` | $(field "$r" wall_s) | $(field "$r" cpu_s) | $thr | $(field "$r" peak_rss_MiB) |" >>"$tmp"
  echo "  coadd of $n: $r" >&2
done
rm -rf "$cs"
rm -rf "$sd"
# ---- products a survey can keep: bytes per SCA-exposure and per tier ------------------
bench/products.sh >>"$tmp"
# Fuzzing is not rerun here (minutes per target): the last committed `make fuzz` table.
if [ -f docs/FUZZ.md ]; then
  {
    echo
    echo "## Fuzzing"
    echo
    echo "Not rerun by \`make bench\`: the last committed \`make fuzz\` results (docs/FUZZ.md, written"
    echo "by fuzz/run.sh; the harnesses and what they found: fuzz/README.md). \"seconds\" is the wall"
    echo "time each target ran clean, \"cov\" libFuzzer's count of covered edges at the end."
    echo
    cat docs/FUZZ.md
  } >>"$tmp"
fi
if [ -f docs/BENCHMARKS.notes.md ]; then echo >>"$tmp"; cat docs/BENCHMARKS.notes.md >>"$tmp"; fi
mv "$tmp" "$out"
echo "wrote $out" >&2
