#!/bin/sh
# canopy quick start: installs what is missing (compiler included) from
# Debian's packages, builds canopy in ./build, and runs it on the built-in
# default scene. Run it as root or as a user who may use sudo.
#   sh tools/quickstart.sh           set up, build, run
#   sh tools/quickstart.sh --no-run  set up and build only
set -eu
cd "$(dirname "$0")/.."

PACKAGES="g++ meson ninja-build pkg-config libglm-dev libtbb-dev libgtest-dev \
libtinyobjloader-dev libbenchmark-dev libembree-dev libcli11-dev nlohmann-json3-dev \
libstb-dev libassimp-dev"

missing=""
for p in $PACKAGES; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "canopy: installing:$missing" >&2
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null 2>&1 || { echo "canopy: need root (or sudo) to install:$missing" >&2; exit 1; }
    SUDO=sudo
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi

if [ ! -f build/build.ninja ]; then
  meson setup build >/dev/null
fi
ninja -C build >/dev/null
echo "canopy: built ./build/tools/canopy" >&2

if [ "${1:-}" != "--no-run" ]; then
  ./build/tools/canopy bench
fi
