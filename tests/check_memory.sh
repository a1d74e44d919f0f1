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

# A tree that outgrows the records' storage: random small triangles make
# 1.86 nodes per triangle against the 1.1 slots the storage has. The
# sequential driver grows the storage without holding the old and the new
# at once (a page mapping that grows in place, from 32 MiB; heap storage
# copied into a mapping a piece at a time, giving back each piece copied:
# NodeArray::expand() in core/node_array.h): 67.2 measured (102.4 when it
# copied into a second array). The parallel drivers keep the subtrees'
# nodes past their records in the overflow area and copy the tree into a
# new array while the storage and the area give their pages up as they go
# (to the new array or back to the system: place_beside_records() in
# core/layout.h): 70.2 measured at 1.1M, 70.9 at 200,000 (91.9 at 1.1M
# when the grown storage and the workers' chunks were held at once, 127
# with a fresh array on top, 132 at 100,000). 1.1M: the storage a mapping,
# the new array on huge pages, pages moved into it; 200,000 and 100,000:
# the storage on the heap, the new array on 4 KiB pages, and the peak at
# the end of the build, which the storage's unused front no longer reaches
# (given back once the blocks outnumber its slots: OverflowArea::
# watch_front()): 67.7 and 70.5 measured (70.9 and 73.7 before). 50,000:
# a lower task cutoff keeps the workers' scratch arrays small, the bin sets
# hold only the bins the scene's root uses, and the blocks' nodes past their
# records sit on whole pages of the area (sched::scratch_cutoff(),
# BinSet, SubtreeBlock::area_at()): 69.7 to 70.9 measured (76.5 before;
# up to 72.59 on a loaded machine until a worker's scratch array stopped
# holding its old and new storage at once, 6412a93: 69.9 to 71.7 after).
# All build the same tree per scene.
for scene in gen:random:1100000 gen:random:200000 gen:random:100000 gen:random:50000; do
  hashes=
  for scheduler in sequential tbb omp_tasks; do
    json=$("$canopy" build "$scene" --scheduler "$scheduler" --threads 2 --json)
    per_tri=$(printf '%s\n' "$json" | sed -n 's/.*"peak_bytes_per_triangle":\([0-9.]*\).*/\1/p')
    hash=$(printf '%s\n' "$json" | sed -n 's/.*"tree_hash":"\([0-9a-f]*\)".*/\1/p')
    echo "$scene, $scheduler: $per_tri bytes per triangle, tree $hash"
    awk -v b="$per_tri" -v s="$scheduler" -v c="$scene" 'BEGIN {
      if (b == "" || !(b > 60 && b <= 72)) { print c ", " s ": peak " b " bytes per triangle, want (60, 72]"; exit 1 }
    }'
    hashes="$hashes $hash"
  done
  set -- $hashes
  if [ -z "$1" ] || [ "$1" != "$2" ] || [ "$1" != "$3" ]; then echo "$scene: the drivers' trees differ ($*)"; exit 1; fi
done
