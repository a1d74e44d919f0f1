#!/bin/sh
# Installs canopy from the build directory into a temporary root and builds a
# tiny consumer against the canopy.pc found there.
set -eu
build="$1"; src="$2"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
meson install -C "$build" --destdir "$tmp" --no-rebuild --quiet >/dev/null
pc=$(find "$tmp" -name canopy.pc | head -n 1)
[ -n "$pc" ] || { echo "no canopy.pc installed" >&2; exit 1; }
export PKG_CONFIG_PATH="$(dirname "$pc")"
export PKG_CONFIG_SYSROOT_DIR="$tmp"
flags=$(pkg-config --cflags --libs canopy)
# CONSUMER_FLAGS: e.g. -fsanitize=address,undefined when the installed
# library was built with them.
c++ -std=c++20 -O1 ${CONSUMER_FLAGS:-} "$src/consumer.cpp" -o "$tmp/consumer" $flags
"$tmp/consumer"
