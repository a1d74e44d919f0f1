#!/bin/sh
# The memory target of issue 4, on scenes where canopy meets it: a build's
# heap high-water mark beyond the input mesh (`peak_bytes_per_triangle` of
# `canopy build --json`, see tools/alloc_probe.h) is at most 72 bytes per
# triangle, for the sequential driver and two parallel ones at 2 threads.
# 2.2M triangles: until d3dde09 so that the parallel drivers' node chunks
# were big enough (2 MiB and more) to take the 2 MiB-aligned path of
# core/memory.h, whose untouched alignment padding the probe must not
# count; since then a one-off build's chunks hold only the nodes that do
# not fit over their records and are about 270 KiB here, so that path is
# no longer exercised by this script (a warm Builder's chunks still take
# it). The lower bound
# (the records and the permutation alone are 36 bytes per triangle) keeps
# a probe that stopped counting from passing. A one-off build holds its
# tree once (the sequential driver's nodes over its records since 12a7c68,
# the parallel drivers' subtrees since 825a86f: 39.2 and 41.5 measured),
# so the upper bound here is 48, not the target's 72: a build that held the
# tree twice again (68 and more) fails.
set -eu
canopy="$1"
for scheduler in sequential tbb omp_tasks; do
  json=$("$canopy" build gen:sphere:2200000 --scheduler "$scheduler" --threads 2 --json)
  per_tri=$(printf '%s\n' "$json" | sed -n 's/.*"peak_bytes_per_triangle":\([0-9.]*\).*/\1/p')
  echo "$scheduler: $per_tri bytes per triangle"
  awk -v b="$per_tri" -v s="$scheduler" 'BEGIN {
    if (b == "" || !(b > 36 && b <= 48)) { print s ": peak " b " bytes per triangle, want (36, 48]"; exit 1 }
  }'
done

# A tree that outgrows the records' storage: 1.1M random small triangles
# make 1.86 nodes per triangle against the 1.1 slots the storage has, and
# their node array (from 32 MiB, NodeArray in core/node_array.h) is a page
# mapping that grows in place. The sequential driver then holds the grown
# storage and the permutation (67.2 measured; 102.4 when it copied into a
# second array); a parallel driver also holds the workers' chunks of the
# nodes that did not fit over their records when the storage grows (91.9;
# 127 with a fresh array). Both build the same tree.
hashes=
for case in sequential:72 tbb:96; do
  scheduler=${case%:*} limit=${case#*:}
  json=$("$canopy" build gen:random:1100000 --scheduler "$scheduler" --threads 2 --json)
  per_tri=$(printf '%s\n' "$json" | sed -n 's/.*"peak_bytes_per_triangle":\([0-9.]*\).*/\1/p')
  hash=$(printf '%s\n' "$json" | sed -n 's/.*"tree_hash":"\([0-9a-f]*\)".*/\1/p')
  echo "random, $scheduler: $per_tri bytes per triangle, tree $hash"
  awk -v b="$per_tri" -v s="$scheduler" -v l="$limit" 'BEGIN {
    if (b == "" || !(b > 60 && b <= l)) { print "random, " s ": peak " b " bytes per triangle, want (60, " l "]"; exit 1 }
  }'
  hashes="$hashes $hash"
done
set -- $hashes
if [ -z "$1" ] || [ "$1" != "$2" ]; then echo "random: the drivers' trees differ ($1, $2)"; exit 1; fi
