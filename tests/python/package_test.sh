#!/usr/bin/env bash
# The install and the Debian package, tested from outside the checkout (CTest package_deb):
#  1. `cmake --install BUILD --prefix SCRATCH/prefix` lays out the binary, the Python module, the
#     configs and the docs;
#  2. `cpack` builds the .deb; its dependencies name the libraries the binary links and python3;
#  3. `dpkg -x` unpacks it into a scratch root, and from a scratch folder with a minimal
#     environment (no checkout on any path) the unpacked `slshadow demo` runs (on the installed
#     quarter-resolution rig, the embedded scene and patterns) and the unpacked module imports and
#     loads the installed rig.
# usage: package_test.sh BUILD_DIR SCRATCH_DIR
set -euo pipefail
build=$(cd "$1" && pwd)
scratch=$2
rm -rf "$scratch"
mkdir -p "$scratch"
scratch=$(cd "$scratch" && pwd)
fail() { echo "package_test: $*" >&2; exit 1; }

cmake --install "$build" --prefix "$scratch/prefix" >/dev/null
for path in bin/slshadow lib/python3/dist-packages/slshadow/__init__.py \
    lib/python3/dist-packages/slshadow/py.typed share/slshadow/config/demo/rig.yaml \
    share/slshadow/config/studies/quarter_demo_rig.yaml share/doc/slshadow/README.md \
    share/doc/slshadow/formats.md share/doc/slshadow/python.md; do
  [ -e "$scratch/prefix/$path" ] || fail "cmake --install: $path missing"
done
ls "$scratch"/prefix/lib/python3/dist-packages/slshadow/_slshadow*.so >/dev/null ||
  fail "cmake --install: the extension module is missing"

(cd "$scratch" && cpack --config "$build/CPackConfig.cmake" -B "$scratch/pkg" >cpack.log 2>&1) ||
  { cat "$scratch/cpack.log" >&2; fail "cpack failed"; }
deb=$(ls "$scratch"/pkg/slshadow_*.deb)
depends=$(dpkg-deb -f "$deb" Depends)
echo "package: $(basename "$deb")"
echo "Depends: $depends"
for dep in python3-numpy 'python3 (>= 3.11)' plplot-driver-cairo libembree libyaml-cpp libopencv-core libpcl; do
  [[ "$depends" == *"$dep"* ]] || fail "Depends lacks $dep"
done

dpkg -x "$deb" "$scratch/root"
mkdir -p "$scratch/run"
cd "$scratch/run"
root="$scratch/root"
clean_env=(env -i PATH=/usr/bin:/bin HOME="$scratch/run" LANG=C.UTF-8 SLSHADOW_HUGE_PAGES=0)
"${clean_env[@]}" "$root/usr/bin/slshadow" --version
"${clean_env[@]}" "$root/usr/bin/slshadow" demo --out demo \
  --rig "$root/usr/share/slshadow/config/studies/quarter_demo_rig.yaml" | tee demo.txt
grep -q "stereo" demo.txt || fail "demo printed no stereo row"
[ -f demo/projector/report.json ] && [ -f demo/stereo/report.json ] || fail "demo reports missing"
"${clean_env[@]}" PYTHONPATH="$root/usr/lib/python3/dist-packages" /usr/bin/python3 -c "
import slshadow, sys
assert slshadow.__file__.startswith('$root/'), slshadow.__file__
rig = slshadow.Rig.load('$root/usr/share/slshadow/config/demo/rig.yaml')
print(rig.describe().splitlines()[0])
print('import slshadow', slshadow.__version__, 'from', slshadow.__file__)
"
echo "package_test: ok"
