#!/bin/sh
# A/B timing of two source trees of canopy in one process (sequential
# builds, default options), for kernel changes whose effect is a few
# percent: on a shared virtual machine, separate runs of two binaries drift
# by more than that, while builds alternated one by one in one process see
# the same machine. Both trees' core/*.cpp and their Sequential builder are
# compiled with -Dcanopy=canopy_a / canopy_b (release flags, -march=native)
# into one program; tree a also loads the scenes.
#
#   git worktree add /tmp/old HEAD~1
#   sh bench/ab/run.sh /tmp/old . [--rounds 9] [--builds 9] [--cold] [--keep FILE] SCENE...
#
# Prints per scene the median (and range) over rounds of each round's median
# ratio b/a of neighbouring builds (< 1: tree b is faster), the fastest build
# of each, and whether the two trees built the same BVH (exit 1 if not).
# --keep FILE also saves the program, to run again as
#   FILE ROUNDS BUILDS warm|cold SCENE...
# Sequential builds only: parallel drivers run this way (two copies sharing
# one OpenMP and one oneTBB runtime) moved by up to 10% in either direction
# between runs of the same program, even a tree against itself.
# Needs the build dependencies (g++, TBB, Assimp, tinyobjloader, GLM).
set -eu
usage() {
    echo "usage: $0 TREE_A TREE_B [--rounds N] [--builds N] [--cold] [--keep FILE] SCENE..." >&2
    exit 2
}
[ $# -ge 3 ] || usage
A=$(cd "$1" && pwd); B=$(cd "$2" && pwd); shift 2
rounds=9; builds=9; mode=warm; keep=
while [ $# -gt 0 ]; do
    case "$1" in
        --rounds) rounds=$2; shift 2 ;;
        --builds) builds=$2; shift 2 ;;
        --cold) mode=cold; shift ;;
        --keep) keep=$2; shift 2 ;;
        -*) usage ;;
        *) break ;;
    esac
done
[ $# -ge 1 ] || usage
for t in "$A" "$B"; do
    [ -f "$t/core/kernel.h" ] || { echo "$0: $t is not a canopy source tree (no core/kernel.h)" >&2; exit 2; }
done
here=$(cd "$(dirname "$0")" && pwd)
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
flags="-std=c++20 -O3 -fno-fast-math -ffp-contract=off -march=native -DNDEBUG -w"
jobs=$(nproc)
compile() {  # side tree
    mkdir -p "$out/$1"
    for f in "$2"/core/*.cpp; do
        echo "c++ $flags -Dcanopy=canopy_$1 -I$2/core -c $f -o $out/$1/$(basename "$f" .cpp).o"
    done
    echo "c++ $flags -Dcanopy=canopy_$1 -DAB_SIDE=$1 -I$2/core -I$2/schedulers -I$2 -c $here/side.cpp -o $out/$1/ab_side.o"
}
{ compile a "$A"; compile b "$B"; echo "c++ $flags -c $here/main.cpp -o $out/main.o"; } > "$out/jobs"
echo "compiling both trees ($(wc -l < "$out/jobs") files)..." >&2
xargs -P "$jobs" -I{} sh -c '{}' < "$out/jobs"
c++ -o "$out/ab" "$out/main.o" "$out"/a/*.o "$out"/b/*.o -ltbb -lassimp -ltinyobjloader -fopenmp -pthread
[ -z "$keep" ] || cp "$out/ab" "$keep"
"$out/ab" "$rounds" "$builds" "$mode" "$@"
