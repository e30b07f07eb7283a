#!/bin/sh
# The README's commands on a machine without the build packages (issue 27): `make demo` and
# `make test` must install them before any flag is resolved. A copy of the tree is made with
# a pkg-config that knows the packages only after a stand-in install step has run, and a dry
# run of each command must compile with the flags that pkg-config gives afterwards. On a
# Makefile that resolves its flags while it is first read, the compile lines lack them,
# whatever this machine has installed.
set -eu
src=$(cd "$(dirname "$0")/.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir "$tmp/tree" "$tmp/bin"
(cd "$src" && cp -r Makefile hal firmware sim analysis tools tests bench scripts "$tmp/tree/")
rm -rf "$tmp/tree/build"
cat >"$tmp/bin/fake-install" <<EOS
#!/bin/sh
touch "$tmp/installed"
EOS
cat >"$tmp/bin/fake-pkg-config" <<EOS
#!/bin/sh
[ -e "$tmp/installed" ] || exit 1
case "\$1" in
  --exists) exit 0 ;;
  --cflags) echo "-DFRESH_PKG_CFLAGS" ;;
  --libs) echo "-lfresh_pkg_libs" ;;
esac
EOS
chmod +x "$tmp/bin/fake-install" "$tmp/bin/fake-pkg-config"
fail=0
for goal in demo test; do
  rm -f "$tmp/installed"
  out="$tmp/$goal.log"
  if ! (cd "$tmp/tree" && make -n "$goal" PKG_CONFIG="$tmp/bin/fake-pkg-config" \
          INSTALL_DEPS="$tmp/bin/fake-install" >"$out" 2>&1); then
    echo "fresh_make: 'make -n $goal' failed:"; cat "$out"; fail=1; continue
  fi
  [ -e "$tmp/installed" ] || { echo "fresh_make: 'make $goal' did not run the install step"; fail=1; }
  cc_lines=$(grep -c -- ' -c .*\.c -o ' "$out" || true)
  bad=$(grep -- ' -c .*\.c -o ' "$out" | grep -vc -- '-DFRESH_PKG_CFLAGS' || true)
  link_bad=$(grep -E -- ' -o (bin/wfisim|build/rel/tests/test_[a-z_]+) ' "$out" | grep -vc -- '-lfresh_pkg_libs' || true)
  if [ "$cc_lines" -eq 0 ] || [ "$bad" -ne 0 ] || [ "$link_bad" -ne 0 ]; then
    echo "fresh_make: 'make $goal': $cc_lines compile lines, $bad without the installed packages' cflags, $link_bad links without their libs"
    fail=1
  fi
done
[ "$fail" -eq 0 ] && echo "fresh_make: demo and test install the packages before resolving flags"
exit "$fail"
