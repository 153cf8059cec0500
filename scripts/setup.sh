#!/usr/bin/env bash
# Installs every Debian package slshadow needs to build, test and run. Idempotent and
# non-interactive: run it as root on a fresh Debian 12 machine (or again at any time).
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build ccache pkg-config git
  # formatting and lint (scripts/format.sh, .clang-format, .clang-tidy)
  clang-format clang-tidy
  # core
  libeigen3-dev libopencv-dev libopencv-contrib-dev libyaml-cpp-dev nlohmann-json3-dev
  # image files (core/image_io.h) through the system codecs, not opencv_imgcodecs
  libpng-dev libjpeg62-turbo-dev libtiff-dev
  # calibration, simulation, comparison
  libceres-dev libembree-dev libtbb-dev libpcl-dev libplplot-dev plplot-driver-cairo
  # C2C cross-check and benchmark peer (compare tests skip without it; runs headless)
  cloudcompare
  # command line
  libcli11-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # libFuzzer harnesses (fuzz/, docs/fuzzing.md): clang with its libFuzzer and sanitizer runtimes
  clang
  # benchmark peer: the digital-model paper's Python/Open3D approach (bench/paper_peer)
  python3-open3d
  # the slshadow Python module (python/, docs/python.md) and its pytest suite (tests/python/)
  pybind11-dev python3-dev python3-numpy python3-pytest python3-matplotlib python3-pil
  # mypy stubtest: the type stubs match the module (tests/python/test_stubs.py)
  python3-mypy
  # devices and their mocks
  libaravis-dev aravis-tools aravis-tools-cli libusb-1.0-0-dev umockdev libumockdev-dev
  libsdl2-dev xvfb x11-apps
  # private loopback-only network namespaces for the GigE Vision fake-camera tests (unshare, ip)
  util-linux iproute2
  # window projector: X screen read-back (XGetImage, MIT-SHM)
  libx11-dev libxext-dev
  # window projector on a second display in tests: Xorg with the dummy driver, xrandr
  xserver-xorg-core xserver-xorg-video-dummy x11-xserver-utils
  # HTML reports (report/): three.js embedded at build time; headless Chromium for their tests
  libjs-three chromium
  # sweeps: shards run through GNU parallel (tests/studies/sweep_test.cc, docs/sweeps.md)
  parallel
  # sweeps: a single-node Slurm started by tests/studies/slurm_sweep.sh (array shards, dependent merge)
  slurm-wlm munge
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed'; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages present"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "setup: installing ${#missing[@]} packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
echo "setup: done"
