#!/bin/sh
# Installs canopy from the build directory into a temporary root, builds a
# tiny consumer against the canopy.pc found there, with -O2 as users do, and
# checks that its tree is the one the canopy tool ($3) builds, on a scene
# whose build takes tree rotations (kernel/rotate.h).
set -eu
build="$1"; src="$2"; tool="$3"
scene=gen:stadium:200000:1
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
c++ -std=c++20 -O2 ${CONSUMER_FLAGS:-} "$src/consumer.cpp" -o "$tmp/consumer" $flags
"$tmp/consumer" "$scene" > "$tmp/out"
cat "$tmp/out"
mine=$(sed -n 's/^tree_hash //p' "$tmp/out")
theirs=$("$tool" build "$scene" --json | sed -n 's/.*"tree_hash" *: *"\([0-9a-f]*\)".*/\1/p')
echo "canopy build: tree_hash $theirs"
[ -n "$mine" ] && [ "$mine" = "$theirs" ] || { echo "the consumer's tree differs from the canopy tool's" >&2; exit 1; }
