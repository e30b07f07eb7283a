#!/bin/sh
# Products a survey can keep: bytes of one SCA-exposure in each product mode
# (products.compress, products.quantize_level, products.resultants), the deep tier's total
# (9,344 exposures x 18 SCAs = 168,192 SCA-exposures), the assembly's cost, and the error
# the quantization of SCI puts on aperture photometry of the truth table's objects.
# Prints Markdown on stdout; bench/run.sh appends it to docs/BENCHMARKS.md, and it runs
# alone too (bench/products.sh > section.md). One exposure is rendered once into a packet
# stream and assembled in every mode, so the modes differ by their products alone.
set -eu
cd "$(dirname "$0")/.."
B=build/rel/bench
make -s $B/rss bin/wfisim >/dev/null
DATA="${WFISIM_DATA:-../shared/data}"
N=4088
[ "${BENCH_QUICK:-0}" = 1 ] && N=1024
TIER=168192
d=$(mktemp -d)
trap 'rm -rf "$d"' EXIT
common="--quiet --data $DATA --threads 2 --set readout.ncols=$N --set readout.nrows=$N"
# the demo's exposure (synthetic deep field, SCA 1, Y106, MA table 6) up the ramp and single frame
bin/wfisim expose $common --out "$d/truth" --stream "$d/ramp.wfip" 2>/dev/null
bin/wfisim expose $common --mode single --out "$d/truth1" --stream "$d/single.wfip" 2>/dev/null
truth=$d/truth/wfisim_e000001_sca01_truth.fits
tbytes=$(stat -c %s "$truth")

row() { # label, stream, settings...: prints the table row; the product's path goes to $d/paths
  label=$1; s=$2; shift 2
  o="$d/out$(date +%s%N)"
  sets=""
  for kv in "$@"; do sets="$sets --set $kv"; done
  r=$($B/rss bin/wfisim assemble "$d/$s" --quiet --out "$o" $sets 2>&1 >/dev/null | grep '^rss:')
  f=$(ls "$o"/*.fits)
  bytes=$(stat -c %s "$f")
  cpu=$(echo "$r" | tr ' ' '\n' | sed -n 's/^cpu_s=//p')
  rssm=$(echo "$r" | tr ' ' '\n' | sed -n 's/^peak_rss_MiB=//p')
  shown=$(echo "$*" | sed 's/products\.//g')
  echo "| $label | \`${shown:-(defaults)}\` | $(awk -v b="$bytes" 'BEGIN {printf "%.1f", b / 1e6}') | $(awk -v b="$bytes" -v t="$tbytes" -v n=$TIER 'BEGIN {printf "%.1f", (b + t) * n / 1e12}') | $cpu | $rssm |"
  echo "$label|$f" >>"$d/paths"
}
{
  echo
  echo "## Products a survey can keep (bytes per SCA-exposure, deep tier of $TIER SCA-exposures)"
  echo
  echo "One exposure of the demo's scene (synthetic deep field, SCA 1, Y106, MA table 6: 15 resultants;"
  echo "${N}x${N}) rendered once to a packet stream, then \`wfisim assemble\` in each mode. Tier TB ="
  echo "(product + its truth file, $(awk -v b="$tbytes" 'BEGIN {printf "%.3f", b / 1e6}') MB, always written) x $TIER."
  echo "CPU s and peak RSS are the assembly's (inflate, ramp fit, compression, FITS)."
  echo
  echo "| product | settings | MB per SCA-exposure | deep tier TB | assemble CPU s | peak RSS MiB |"
  echo "|---|---|---|---|---|---|"
}
row "up the ramp, uncompressed" ramp.wfip products.compress=none
row "up the ramp, Rice, lossless floats" ramp.wfip products.compress=rice products.quantize_level=0
row "up the ramp, Rice, q 16 (survey run's default)" ramp.wfip products.compress=rice
row "up the ramp, no resultants, uncompressed" ramp.wfip products.compress=none products.resultants=drop
for q in 4 8 16 32; do
  row "up the ramp, no resultants, Rice, q $q" ramp.wfip products.compress=rice products.quantize_level=$q products.resultants=drop
done
row "single frame, uncompressed" single.wfip products.compress=none
row "single frame, Rice, q 16" single.wfip products.compress=rice
# photometry of the compressed SCI against the uncompressed one
path_of() { sed -n "s/^$1|//p" "$d/paths"; }
ref=$(path_of "up the ramp, no resultants, uncompressed")
args=""
for q in 4 8 16 32; do args="$args $q=$(path_of "up the ramp, no resultants, Rice, q $q")"; done
echo
echo "Quantization error on aperture photometry (\`bench/quant_photometry.py\`): every truth object"
echo "on the SCA away from its edges, flux in a 3-pixel-radius aperture of SCI (e-/s), compressed"
echo "minus uncompressed, against the photometric noise of the aperture (its pixels' ERR in"
echo "quadrature): rms and mean over the objects, and the expectation for the rows' own steps"
echo "(ZSCALE / sqrt 12 per pixel, in quadrature)."
echo
/usr/bin/python3 bench/quant_photometry.py "$ref" "$truth" $args
