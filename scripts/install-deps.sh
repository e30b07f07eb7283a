#!/bin/sh
# Installs the Debian packages wfisim builds and tests with, when any is missing.
# As root it runs apt-get; otherwise it prints the exact command and fails.
# Arguments name extra packages one job needs (make fuzz and CI: clang, and libclang-rt-dev:
# its fuzzer and sanitizer runtimes, only recommended by clang and so left out by
# --no-install-recommends).
set -eu
pkgs="build-essential pkg-config libcfitsio-dev libfftw3-dev zlib1g-dev libdeflate-dev check libyaml-dev python3-astropy python3-numpy python3-sncosmo libopenmpi-dev openmpi-bin libsep-dev source-extractor python3-drizzle $*"
missing=""
for p in $pkgs; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
if [ "$(id -u)" = 0 ]; then
  echo "install-deps: installing$missing" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends $missing >/dev/null
else
  echo "install-deps: missing Debian packages:$missing" >&2
  echo "run: sudo apt-get update && sudo apt-get install -y$missing" >&2
  exit 1
fi
