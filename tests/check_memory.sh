#!/bin/sh
# The memory target of issue 4, on a scene where canopy meets it: a build's
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
