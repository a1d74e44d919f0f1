#!/bin/sh
# canopy fuzzing: builds the libFuzzer targets with clang (ASan + UBSan) in
# ./build-fuzz and runs each for SECONDS (default 30), from a small seed
# corpus written here plus whatever earlier runs kept in
# build-fuzz/fuzz-corpus/NAME. Installs what is missing of Debian's clang,
# libclang-rt-14-dev (libFuzzer) and libomp-14-dev (OpenMP for clang); the
# rest is what tools/quickstart.sh installs.
#   sh fuzz/run.sh [SECONDS]
# Exits 1 if a target finds a bug, naming the input that reproduces it:
#   ./build-fuzz/fuzz/fuzz_NAME FILE
set -eu
cd "$(dirname "$0")/.."
seconds=${1:-30}
dir=build-fuzz
targets="obj ply off build"

missing=""
for p in clang libclang-rt-14-dev libomp-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "canopy fuzz: installing:$missing" >&2
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null 2>&1 || { echo "canopy fuzz: need root (or sudo) to install:$missing" >&2; exit 1; }
    SUDO=sudo
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi

if [ ! -f $dir/build.ninja ]; then
  CC=clang CXX=clang++ meson setup $dir -Dfuzz=true -Dbuildtype=debugoptimized \
    -Dtests=false -Dbenchmarks=false -Dembree=disabled >/dev/null
fi
if ! ninja -C $dir -j2 $(for t in $targets; do printf 'fuzz/fuzz_%s ' "$t"; done) >$dir/fuzz-build.log 2>&1; then
  cat $dir/fuzz-build.log >&2
  exit 1
fi

# ---------------------------------------------------------------------------
# Seeds: a few small valid inputs per target.
seeds=$dir/fuzz-seeds
rm -rf $seeds
mkdir -p $seeds/obj $seeds/ply $seeds/off $seeds/build

# bytes N...: the bytes with these decimal values.
bytes() {
  for b in "$@"; do printf "\\$(printf %03o "$b")"; done
}
# f32le X...: little-endian floats (0..4, -1, +-max: +-FLT_MAX, tiny: the
# smallest denormal).
f32le() {
  for x in "$@"; do
    case $x in
      0) bytes 0 0 0 0 ;; 1) bytes 0 0 128 63 ;; 2) bytes 0 0 0 64 ;;
      3) bytes 0 0 64 64 ;; 4) bytes 0 0 128 64 ;; -1) bytes 0 0 128 191 ;;
      max) bytes 255 255 127 127 ;; -max) bytes 255 255 127 255 ;; tiny) bytes 1 0 0 0 ;;
    esac
  done
}
# u32le N...: little-endian uint32 below 256.
u32le() {
  for n in "$@"; do bytes "$n" 0 0 0; done
}
# pseudo COUNT SEED: COUNT deterministic pseudo-random byte values.
pseudo() {
  awk -v n="$1" -v s="$2" 'BEGIN { for (i = 0; i < n; ++i) { s = (s * 1103515245 + 12345) % 2147483648; printf "%d ", int(s / 65536) % 256 } }'
}

printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' >$seeds/obj/triangle.obj
printf '# a quad\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\ng side\ns off\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -2//1 -1//1\n' \
  >$seeds/obj/quad.obj
printf 'v -1.5e3 2.25 +0.5\r\nv 1e-3 -0 7\r\nv 2 3 4 1\r\nv 5 5 5\r\nf 1 2 3\r\nf 2 3 4 1\r\nl 1 2\r\n' >$seeds/obj/crlf.obj

ply_header() {  # ENCODING LIST_TYPES
  printf 'ply\nformat %s 1.0\ncomment seed\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list %s vertex_indices\nend_header\n' "$1" "$2"
}
{ ply_header ascii 'uchar int'; printf '0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n3 0 2 1\n'; } >$seeds/ply/ascii.ply
{ ply_header binary_little_endian 'uchar int'
  f32le 0 0 0 1 0 0 1 1 0 0 1 0; bytes 4; u32le 0 1 2 3; bytes 3; u32le 0 2 1; } >$seeds/ply/binary_le.ply
{ printf 'ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty uchar red\nproperty float y\nproperty float z\n'
  printf 'element face 1\nproperty list ushort uint vertex_index\nproperty int flags\nend_header\n'
  bytes 63 240 0 0 0 0 0 0 9 0 0 0 0 0 0 0 0  # (1, 0, 0)
  bytes 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0  # (0, 0, 0)
  bytes 0 0 0 0 0 0 0 0 0 63 128 0 0 0 0 0 0  # (0, 1, 0)
  bytes 0 3 0 0 0 0 0 0 0 1 0 0 0 2 255 255 255 255; } >$seeds/ply/binary_be.ply

printf 'OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n3 0 2 1\n' >$seeds/off/quad.off
printf '# colored\nCOFF 3 1\n0 0 0 1 0 0 1\n1 0 0 0 1 0 1\n0 1 0 0 0 1 1\n3 0 1 2 255 0 0\n' >$seeds/off/coff.off
printf '4OFF\n3 1 0\n0 0 0 1\n2 0 0 2\n0 3 0 3\n3 0 1 2\n' >$seeds/off/homogeneous.off
printf 'nOFF 3\n3 1\n0 0 0\n1 0 0\n0 1 0\n3 2 1 0\n' >$seeds/off/ndim.off

# build: header (bins, max_leaf, mode, scale, max_depth, tuning x3, vertex
# count), then vertices and indices (see fuzz_build.cpp).
{ bytes 14 3 0 128 0 0 0 0 4 0; f32le 0 0 0 1 0 0 1 1 0 0 1 0; u32le 0 1 2 0 2 3; } >$seeds/build/quad
{ bytes 6 0 4 128 0 3 3 3 6 0; f32le 0 0 0 2 0 0 0 2 0 0 0 2 -1 -1 -1 4 4 4; u32le 0 1 2 0 1 3 3 4 5 1 2 3; } >$seeds/build/boxes
{ bytes 2 1 0 128 0 0 0 0 8 0; f32le -max -max -max max 0 0 0 max 0 tiny tiny tiny 0 tiny 0 0 0 tiny -max 0 max max 0 -max
  u32le 0 1 2 3 4 5 0 2 4 1 3 5 6 7 0; } >$seeds/build/extremes
{ bytes 30 7 5 126 0 15 15 15 64 0; bytes $(pseudo 192 7); bytes $(pseudo 1200 11); } >$seeds/build/int8
{ bytes 254 0 6 120 12 0 0 0 48 0; bytes $(pseudo 288 3); bytes $(pseudo 1800 5); } >$seeds/build/int16

# ---------------------------------------------------------------------------
# Runs.
status=0
for t in $targets; do
  corpus=$dir/fuzz-corpus/$t
  artifacts=$dir/fuzz-artifacts/$t
  log=$dir/fuzz-logs/$t.log
  mkdir -p "$corpus" "$artifacts" "$(dirname "$log")"
  dict=""
  if [ -f fuzz/$t.dict ]; then dict="-dict=fuzz/$t.dict"; fi
  rc=0
  # OpenMP workers sleep between builds rather than spin against the fuzzer.
  OMP_WAIT_POLICY=passive ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
    ./$dir/fuzz/fuzz_$t -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="$artifacts/" $dict "$corpus" "$seeds/$t" >"$log" 2>&1 || rc=$?
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  speed=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log")
  last=$(grep -E '^#[0-9]+' "$log" | tail -n 1 | sed -E 's/^#[0-9]+[[:space:]]+[A-Z]+[[:space:]]+//')
  if [ "$rc" -eq 0 ]; then
    echo "fuzz_$t: ok, ${runs:-?} runs, ${speed:-?} exec/s; $last"
  else
    status=1
    echo "fuzz_$t: FAILED (exit $rc) after ${runs:-?} runs; log $log"
    grep -E '^(==[0-9]+==ERROR|SUMMARY|canopy fuzz:)|runtime error' "$log" | head -n 5 | sed 's/^/  /'
    for f in $(sed -n 's/.*Test unit written to \(.*\)$/\1/p' "$log"); do
      echo "  reproduce: ./$dir/fuzz/fuzz_$t $f"
    done
  fi
done
exit $status
