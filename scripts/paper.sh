#!/bin/sh
# make paper: a reduced reproduction of the deep-tier analysis (issue 26; docs/ANALYSIS.md,
# "make paper"). Every stage is a wfisim command; this script only chooses the inputs, runs
# the stages in order, gathers the numbers into OUT/summary.json and prints the time by stage.
#
#   scripts/paper.sh [--area RA,DEC,R] [--out DIR] [--threads N] [--visits N] [--seed S]
#                    [--sn-boost K] [--singles N] [--patch ARCSEC] [--template-days D]
#                    [--coadd-thresh S] [--diff-thresh S] [--synthetic 'SETS']
#                    [--set KEY=VALUE ...]   (--set: every wfisim command that renders or plans)
#
# WFISIM names the program (default bin/wfisim); the Roman and SALT data come from --data DIR
# or $WFISIM_DATA (required: the SNe need the SALT model).
set -eu

WFISIM=${WFISIM:-bin/wfisim}
AREA=71.2,-53.05,0.01   # RA, Dec, radius (deg): products whose SCA overlaps this circle (one SCA
                        # a visit here: 146 products; on the field centre, a chip gap, 292)
OUT=out/paper
THREADS=2
VISITS=                 # empty: the plan's 146 visits (two years)
SEED=1
SN_BOOST=100            # the SN rate law times this (a small area holds ~2 SNe otherwise)
SINGLES=12              # single exposures detected for the single-epoch efficiency
PATCH=100               # side of a coadd/difference patch (arcsec): bounds memory
TEMPLATE_DAYS=100       # a template: the epochs of the first (last) this many days
# Detection thresholds, in sigma: SExtractor's 1.5 everywhere. Drizzling correlates
# neighbouring output pixels, which ERR leaves out, so on the coadds and difference images the
# sigma is measured (`detect --noise-scale auto`: the filtered sky's width over what ERR
# predicts; docs/ANALYSIS.md, "Detection thresholds"); the single exposures keep ERR's.
COADD_THRESH=1.5
DIFF_THRESH=1.5
# The synthetic field fainter than its defaults (H 26, V 27, 2.5 stars per arcmin^2): a coadd
# of 146 epochs reaches ~2.7 mag deeper than one, and its 50% point needs objects beyond it.
SYNTH="--set scene.synthetic.h_faint=29.5 --set scene.synthetic.star_density=40 --set scene.synthetic.star_v_faint=32"
# Persistence off: each product's earlier exposures within the hour (the visit's other
# pointings, which this area does not render) would be drawn for it alone, 8.8 of the 15.8
# CPU-s of a product here (docs/ANALYSIS.md, "make paper"); `--set
# detector.effects.persistence=true` puts it back
DETECTOR="--set detector.effects.persistence=false"
DATA=${WFISIM_DATA:-}
SETS=

die() { echo "paper.sh: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
    [ $# -ge 2 ] || die "$1 needs a value"
    case $1 in
    --area) AREA=$2 ;;
    --out) OUT=$2 ;;
    --threads) THREADS=$2 ;;
    --visits) VISITS=$2 ;;
    --seed) SEED=$2 ;;
    --sn-boost) SN_BOOST=$2 ;;
    --singles) SINGLES=$2 ;;
    --patch) PATCH=$2 ;;
    --template-days) TEMPLATE_DAYS=$2 ;;
    --coadd-thresh) COADD_THRESH=$2 ;;
    --diff-thresh) DIFF_THRESH=$2 ;;
    --data) DATA=$2 ;;
    --synthetic) SYNTH=$2 ;;
    --set) SETS="$SETS --set $2" ;;
    *) die "unknown option $1" ;;
    esac
    shift 2
done
[ -n "$DATA" ] || die "no data folder: give --data DIR or set WFISIM_DATA (the SNe need the SALT model)"
case $WFISIM in /*) ;; *) WFISIM=$(pwd)/$WFISIM ;; esac
case $DATA in /*) ;; *) DATA=$(pwd)/$DATA ;; esac
[ -x "$WFISIM" ] || die "$WFISIM is not built (make)"
IFS=, read -r RA DEC RADIUS <<EOF
$AREA
EOF
[ -n "${RADIUS:-}" ] || die "--area wants RA,DEC,R (degrees)"
export WFISIM_DATA="$DATA"
mkdir -p "$OUT"
cd "$OUT"
: > times.txt
# plan and survey settings every rendering command shares
PSETS="--set seed=$SEED $SYNTH $DETECTOR $SETS"

now() { date +%s.%N; }
T0=$(now)
stage() { # name: close the running stage
    t=$(now)
    awk -v n="$1" -v a="$T0" -v b="$t" 'BEGIN { printf "%-12s %8.1f s\n", n, b - a }' >> times.txt
    T0=$t
    echo "paper.sh: $1 done" >&2
}
fail_if() { if [ -s "$1" ]; then cat "$1" >&2; die "$2"; fi; }

# 1. plan: the deep tier's visits in Y106 only (the Y106 pass opens every visit, so its
#    exposures fall on the same dates as in the four-filter plan)
set -- --set survey.filters=Y106 --set survey.exptimes=300
[ -n "$VISITS" ] && set -- "$@" --set "survey.visits=$VISITS"
# shellcheck disable=SC2086
"$WFISIM" survey plan "$@" $SETS --out plan.fits > plan.log 2>&1 || { cat plan.log >&2; die "survey plan failed"; }
stage plan

# 2. SNe over a cap a little larger than the circle (every SCA that reaches the circle holds
#    some of them), peak dates over the plan padded by SALT3's phase range at z 3 (50 rest
#    days before, 20 after: 200 and 80 observer days), the plan's dates from its header
card() { head -c 28800 plan.fits | fold -w 80 | sed -n "s/^$1 *= *\([^ /]*\).*/\1/p" | head -n 1; }
MJDSTART=$(card MJDSTART); NV=$(card NVISITS); VDT=$(card VISITDT)
[ -n "$MJDSTART" ] && [ -n "$NV" ] && [ -n "$VDT" ] || die "plan.fits: no MJDSTART, NVISITS or VISITDT"
eval "$(awk -v r="$RADIUS" -v m="$MJDSTART" -v n="$NV" -v dt="$VDT" -v b="$SN_BOOST" 'BEGIN {
    pi = 3.141592653589793; rr = r + 0.01
    printf "SN_AREA=%.8f SN_START=%.4f SN_DAYS=%.4f\n", pi * rr * rr, m - 200, (n - 1) * dt + 1 + 280
    printf "RATE1=\"%g 1.5 0 1\" RATE2=\"%g -0.5 1 3\"\n", 2.5e-5 * b, 9.7e-5 * b }')"
# shellcheck disable=SC2086
"$WFISIM" sn generate --area "$SN_AREA" --ra "$RA" --dec "$DEC" --start "$SN_START" --days "$SN_DAYS" \
    --seed "$SEED" --rate "$RATE1" --rate "$RATE2" $SYNTH $SETS --out sne.fits > sne.log 2>&1 ||
    { cat sne.log >&2; die "sn generate failed"; }
stage sne

# 3. render every SCA that overlaps the circle on every exposure of the plan, single frame
# shellcheck disable=SC2086
"$WFISIM" survey run --plan plan.fits --area "$AREA" --sne sne.fits --mode single --threads "$THREADS" \
    --quiet --on-change redo $PSETS --out render > render.log 2>&1 || { cat render.log >&2; die "survey run failed"; }
stage render

# The products: EXPID SCA MJD FILE TRUTH RA_SCA DEC_SCA, from the run's index
awk -F, 'NR > 1 { print $1, $2, $4, $15, $16, $12, $13 }' render/survey_index.csv > products.txt
[ -s products.txt ] || die "no products rendered"

# Patches: squares of PATCH arcsec on the tangent plane about the centre, covering the circle
awk -v ra="$RA" -v dec="$DEC" -v r="$RADIUS" -v p="$PATCH" 'BEGIN {
    d2r = 3.141592653589793 / 180; side = p / 3600; n = int(2 * r / side) + 1; k = 0
    for (j = 0; j < n; j++) for (i = 0; i < n; i++) {
        x = (i - (n - 1) / 2) * side; y = (j - (n - 1) / 2) * side
        if (sqrt(x * x + y * y) > r + side / sqrt(2)) continue
        # gnomonic offsets (x east, y north) -> RA, Dec
        xi = x * d2r; eta = y * d2r; rho = sqrt(xi * xi + eta * eta); c = atan2(rho, 1); d0 = dec * d2r
        if (rho == 0) { pra = ra; pdec = dec }
        else {
            pdec = asin_(cos(c) * sin(d0) + eta * sin(c) * cos(d0) / rho) / d2r
            pra = ra + atan2(xi * sin(c), rho * cos(d0) * cos(c) - eta * sin(d0) * sin(c)) / d2r
        }
        printf "p%03d %.8f %.8f\n", k++, pra, pdec
    } }
    function asin_(s) { return atan2(s, sqrt(1 - s * s)) }' > patches.txt
NPIX=$(awk -v p="$PATCH" 'BEGIN { printf "%d", p / 0.0575 + 0.5 }')

# inputs of a patch: products whose SCA (half diagonal 0.09 deg) can reach the square
patch_inputs() { # PRA PDEC -> lines of products.txt
    awk -v ra="$1" -v dec="$2" -v p="$PATCH" 'BEGIN { d2r = 3.141592653589793 / 180 }
        { c = sin($7 * d2r) * sin(dec * d2r) + cos($7 * d2r) * cos(dec * d2r) * cos(($6 - ra) * d2r)
          if (c > 1) c = 1
          s = atan2(sqrt(1 - c * c), c) / d2r
          if (s < 0.0905 + p / 3600 / sqrt(2)) print }' products.txt
}
MJD0=$(awk 'NR == 1 || $3 < m { m = $3 } END { print m }' products.txt)
MJD1=$(awk 'NR == 1 || $3 > m { m = $3 } END { print m }' products.txt)
MID=$(awk -v a="$MJD0" -v b="$MJD1" 'BEGIN { printf "%.6f", (a + b) / 2 }')

# 4. coadds: per patch every epoch (the deep coadd), and the templates: the epochs of the
#    first and of the last TEMPLATE_DAYS
mkdir -p coadd diff cat
: > coadd/jobs.txt
while read -r P PRA PDEC; do
    patch_inputs "$PRA" "$PDEC" > "coadd/$P.inputs"
    awk '{ print "render/" $4 }' "coadd/$P.inputs" > "coadd/$P.all.list"
    [ -s "coadd/$P.all.list" ] || continue
    echo "$P $PRA $PDEC all :" >> coadd/jobs.txt
    awk -v p="$P" -v ra="$PRA" -v dec="$PDEC" -v a="$MJD0" -v b="$MJD1" -v d="$TEMPLATE_DAYS" 'BEGIN {
        printf "%s %s %s early :%.6f\n%s %s %s late %.6f:\n", p, ra, dec, a + d, p, ra, dec, b - d }' >> coadd/jobs.txt
done < patches.txt
: > coadd/errors.txt
export WFISIM NPIX
# a template is the deep coadd's list within a range of dates (coadd --mjd); a patch none of
# whose inputs reach it, or none of them in the range, has no coadd
# shellcheck disable=SC2016
xargs -P "$THREADS" -L 1 sh -c '"$WFISIM" coadd --center "$1,$2" --size "$NPIX,$NPIX" --mjd "$4" --quiet \
    --out "coadd/$0.$3.fits" "@coadd/$0.all.list" > "coadd/$0.$3.log" 2>&1 ||
    { [ $? -eq 2 ] && grep -q "overlaps\|MJD-OBS within" "coadd/$0.$3.log"; } || cat "coadd/$0.$3.log" >> coadd/errors.txt' \
    < coadd/jobs.txt
fail_if coadd/errors.txt "a coadd failed"
stage coadd

# 4b. the single exposures (a sample of SINGLES, spread over the run) drizzled alone onto the
#    grid of a patch they reach: the reference depth on the 0.0575" grid the coadds and the
#    differences are detected on (a coarser, undersampled grid is detected to another depth;
#    docs/ANALYSIS.md, "Depth on the drizzled grid")
N=$(wc -l < products.txt)
awk -v n="$N" -v k="$SINGLES" 'BEGIN { last = -1 }
    { b = int((NR - 1) * k / n); if (b != last) { print; last = b } }' products.txt > singles.txt
: > coadd/single_jobs.txt
while read -r _ _ _ FILE TRUTH _ _; do
    while read -r P PRA PDEC; do
        if [ -s "coadd/$P.inputs" ] && awk -v f="$FILE" '$4 == f { found = 1 } END { exit !found }' "coadd/$P.inputs"; then
            echo "$P $PRA $PDEC ${FILE%.fits} $TRUTH" >> coadd/single_jobs.txt
            break
        fi
    done < patches.txt
done < singles.txt
# shellcheck disable=SC2016
xargs -P "$THREADS" -L 1 sh -c '"$WFISIM" coadd --center "$1,$2" --size "$NPIX,$NPIX" --quiet \
    --out "coadd/$0.e$3.fits" "render/$3.fits" > "coadd/$0.e$3.log" 2>&1 ||
    { [ $? -eq 2 ] && grep -q "overlaps\|lands on" "coadd/$0.e$3.log"; } || cat "coadd/$0.e$3.log" >> coadd/errors.txt' \
    < coadd/single_jobs.txt
fail_if coadd/errors.txt "a resampled single failed"
stage resample

# 5. difference images: each epoch on each patch it reaches, against the template at the
#    other end of the survey (SNe bright in one are faded in the other)
: > diff/jobs.txt
while read -r P PRA PDEC; do
    [ -f "coadd/$P.early.fits" ] && [ -f "coadd/$P.late.fits" ] || continue
    awk -v p="$P" -v mid="$MID" '{ t = $3 < mid ? "late" : "early"
        sub(/\.fits$/, "", $4); print p, t, $4, $5 }' "coadd/$P.inputs" >> diff/jobs.txt
done < patches.txt
: > diff/errors.txt
# shellcheck disable=SC2016
xargs -P "$THREADS" -L 1 sh -c 'o="diff/$0_$2"
    "$WFISIM" diff --template "coadd/$0.$1.fits" --epoch "render/$2.fits" --out "$o.fits" --quiet > "$o.log" 2>&1 ||
    { [ $? -eq 2 ] && grep -q "overlaps nothing\|share no pixel" "$o.log"; } || cat "$o.log" >> diff/errors.txt' \
    < diff/jobs.txt
fail_if diff/errors.txt "a difference image failed"
stage diff

# 6. detection: the chosen single exposures (on their own grid and resampled), the deep
#    coadds and every difference image
: > cat/jobs.txt
awk '{ print "render/" $4, "cat/" $4, 1.5, 1 }' singles.txt >> cat/jobs.txt
while read -r P _ _ STEM _; do
    [ -f "coadd/$P.e$STEM.fits" ] && echo "coadd/$P.e$STEM.fits cat/$P.e$STEM.fits 1.5 auto" >> cat/jobs.txt
done < coadd/single_jobs.txt
for f in coadd/*.all.fits; do [ -f "$f" ] && echo "$f cat/${f#coadd/} $COADD_THRESH auto" >> cat/jobs.txt; done
for f in diff/*.fits; do [ -f "$f" ] && echo "$f cat/${f#diff/} $DIFF_THRESH auto" >> cat/jobs.txt; done
: > cat/errors.txt
# shellcheck disable=SC2016
xargs -P "$THREADS" -L 1 sh -c '"$WFISIM" detect "$0" --out "$1" --thresh "$2" --noise-scale "$3" --data "$WFISIM_DATA" > "$1.log" 2>&1 ||
    cat "$1.log" >> cat/errors.txt' < cat/jobs.txt
fail_if cat/errors.txt "a detection failed"
stage detect

# 7. efficiency per kind, 8. hosts on the deep coadds
awk '{ print "render/" $4, "cat/" $4, "render/" $5 }' singles.txt > single.list
: > coadd.list
while read -r P PRA PDEC; do
    [ -f "coadd/$P.all.fits" ] || continue
    printf 'coadd/%s.all.fits cat/%s.all.fits %s\n' "$P" "$P" \
        "$(awk '{ printf "%s%s", (NR > 1 ? "," : ""), "render/" $5 }' "coadd/$P.inputs")" >> coadd.list
done < patches.txt
: > diff.list
while read -r P _ STEM TRUTH; do
    [ -f "diff/${P}_$STEM.fits" ] && echo "diff/${P}_$STEM.fits cat/${P}_$STEM.fits render/$TRUTH" >> diff.list
done < diff/jobs.txt
: > resampled.list
while read -r P _ _ STEM TRUTH; do
    [ -f "coadd/$P.e$STEM.fits" ] && echo "coadd/$P.e$STEM.fits cat/$P.e$STEM.fits render/$TRUTH" >> resampled.list
done < coadd/single_jobs.txt
[ -s resampled.list ] || die "no single exposure reaches a patch"
[ -s coadd.list ] || die "no deep coadd was made"
[ -s diff.list ] || die "no difference image was made"
"$WFISIM" efficiency --label single --types galaxy,star --out eff single.list > eff.log 2>&1 &&
    "$WFISIM" efficiency --label resampled --types galaxy,star --out eff resampled.list >> eff.log 2>&1 &&
    "$WFISIM" efficiency --label coadd --types galaxy,star,sn --out eff coadd.list >> eff.log 2>&1 &&
    "$WFISIM" efficiency --label diff --types sn --out eff diff.list >> eff.log 2>&1 &&
    "$WFISIM" efficiency --label diff_isolated --types sn --isolated sne.fits --out eff diff.list >> eff.log 2>&1 ||
    { cat eff.log >&2; die "efficiency failed"; }
stage efficiency
"$WFISIM" hosts --out hosts coadd.list > hosts.log 2>&1 || { cat hosts.log >&2; die "hosts failed"; }
stage hosts

# 9. the numbers: one JSON (temporary file, renamed), the plots beside it
key() { # FILE KEY -> the value as the JSON has it (number or null; null when absent)
    v=$(sed -n "s/^ *\"$2\": *\([^,]*\),*\$/\1/p" "$1" | head -n 1)
    echo "${v:-null}"
}
E=eff
H=hosts/hosts_summary.json
NCO=$(cat coadd/*.all.list | sort -u | wc -l)
noise() { # LOGS... -> the median of the measured noise scales ("noise x S" in detect's logs)
    sed -n 's/.*noise x \([0-9.]*\)).*/\1/p' "$@" | sort -n |
        awk '{ v[NR] = $1 } END { if (NR) print (NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2); else print "null" }'
}
{
    printf '{\n'
    printf '  "area": "%s",\n  "filter": "Y106",\n  "visits": %s,\n' "$AREA" "$NV"
    printf '  "products": %s,\n  "singles": %s,\n  "coadd_inputs": %s,\n  "diffs": %s,\n' \
        "$N" "$(wc -l < singles.txt)" "$NCO" "$(wc -l < diff.list)"
    printf '  "sne_generated": %s,\n' "$(sed -n 's/^wfisim sn: \([0-9]*\) supernovae.*/\1/p' sne.log)"
    for k in galaxy star; do
        printf '  "%s_m50_single": %s,\n  "%s_m50_single_err": %s,\n' "$k" "$(key $E/single_summary.json m50_$k)" \
            "$k" "$(key $E/single_summary.json m50_err_$k)"
        printf '  "%s_m50_coadd": %s,\n  "%s_m50_coadd_err": %s,\n' "$k" "$(key $E/coadd_summary.json m50_$k)" \
            "$k" "$(key $E/coadd_summary.json m50_err_$k)"
        printf '  "%s_m50_resampled": %s,\n  "%s_m50_resampled_err": %s,\n' "$k" \
            "$(key $E/resampled_summary.json m50_$k)" "$k" "$(key $E/resampled_summary.json m50_err_$k)"
        for s in single resampled coadd; do
            printf '  "%s_n_true_%s": %s,\n  "%s_n_found_%s": %s,\n' "$k" "$s" "$(key $E/${s}_summary.json n_true_$k)" \
                "$k" "$s" "$(key $E/${s}_summary.json n_found_$k)"
        done
    done
    printf '  "single_n_false": %s,\n  "coadd_n_false": %s,\n' "$(key $E/single_summary.json n_false)" \
        "$(key $E/coadd_summary.json n_false)"
    printf '  "resampled_noise_scale": %s,\n' "$(noise $(awk '{ print $2 ".log" }' resampled.list))"
    printf '  "coadd_noise_scale": %s,\n  "diff_noise_scale": %s,\n' \
        "$(noise cat/*.all.fits.log)" "$(noise $(awk '{ print $2 ".log" }' diff.list))"
    printf '  "sn_m50_diff": %s,\n  "sn_m50_diff_err": %s,\n' "$(key $E/diff_summary.json m50_sn)" \
        "$(key $E/diff_summary.json m50_err_sn)"
    printf '  "sn_n_true_diff": %s,\n  "sn_n_found_diff": %s,\n  "diff_n_false": %s,\n' \
        "$(key $E/diff_summary.json n_true_sn)" "$(key $E/diff_summary.json n_found_sn)" \
        "$(key $E/diff_summary.json n_false)"
    printf '  "sn_m50_diff_isolated": %s,\n  "sn_m50_diff_isolated_err": %s,\n' \
        "$(key $E/diff_isolated_summary.json m50_sn)" "$(key $E/diff_isolated_summary.json m50_err_sn)"
    printf '  "sn_n_true_diff_isolated": %s,\n  "sn_n_not_isolated_diff": %s,\n' \
        "$(key $E/diff_isolated_summary.json n_true_sn)" "$(key $E/diff_isolated_summary.json n_not_isolated_sn)"
    for k in hosts_total hosts_correct hosts_nearest_wrong hosts_undetected hosts_nearest_correct \
        hosts_dlr_wrong sne_total sne_hostless hosts_outside; do
        printf '  "%s": %s,\n' "$k" "$(key $H $k)"
    done
    printf '  "seconds": {'
    awk 'BEGIN { s = "" } { printf "%s\"%s\": %s", s, $1, $2; s = ", " }' times.txt
    printf '}\n}\n'
} > summary.json.tmp
mv summary.json.tmp summary.json
for f in eff/single_efficiency.png eff/coadd_efficiency.png eff/diff_efficiency.png hosts/hosts.png; do
    cp "$f" "$(basename "$f")"
done
stage summary
echo "time by stage ($(pwd)):"
cat times.txt
awk '{ s += $2 } END { printf "%-12s %8.1f s\n", "total", s }' times.txt
cat summary.json
