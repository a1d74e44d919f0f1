#!/bin/sh
# canopy bench on a small generated scene, 3 rounds at 1 and 2 threads: the
# command succeeds, and its CSV has one row per (threads, builder) with the
# columns the README documents, every canopy scheduler's SAH the same, the
# ratios positive, and the ratios that must be 1 exactly 1 (a builder against
# itself at the first thread count; Embree's scene build against itself).
set -eu
canopy="$1"; out="$2"
"$canopy" bench gen:sphere:3000 --threads 1,2 --repeat 3 --gap 0 --csv "$out" >"$out.txt"
# The last column (the speedup over the core check's ideal) is filled on
# the rows at as many threads as the process may use CPUs (Linux, 2 or more
# CPUs), and empty on the others.
cpus=1
if [ "$(uname -s)" = Linux ]; then cpus="$(nproc)"; fi
awk -F, -v cpus="$cpus" '
NR == 1 {
  want = "scene,triangles,threads,builder,median_ms,min_ms,sah,ratio_vs_embree_scene,speedup_vs_T1," \
         "ratio_vs_embree_scene_per_round,speedup_vs_T1_per_round,speedup_over_ideal_per_round"
  if ($0 != want) { print "unexpected header: " $0; bad = 1 }
  next
}
{
  rows++
  if (NF != 12) { print "row " NR ": " NF " fields"; bad = 1 }
  if (cpus > 1 && $3 == cpus) {
    if (!($12 > 0)) { print "row " NR ": speedup over the ideal " $12; bad = 1 }
    over_ideal++
  } else if ($12 != "") { print "row " NR ": speedup over the ideal at " $3 " threads: " $12; bad = 1 }
  if (tris == "") tris = $2
  if ($1 != "gen:sphere:3000" || !($2 > 0) || $2 != tris) { print "row " NR ": scene " $1 " " $2; bad = 1 }
  if (!($5 > 0 && $6 > 0 && $6 <= $5)) { print "row " NR ": median " $5 ", min " $6; bad = 1 }
  if (!($9 > 0 && $11 > 0)) { print "row " NR ": speedups " $9 " " $11; bad = 1 }
  if ($3 == 1 && ($9 != "1.0000" || $11 != "1.0000")) { print "row " NR ": 1-thread speedup not 1"; bad = 1 }
  if ($4 == "embree_scene") {
    embree = 1
    if ($8 != "1.0000" || $10 != "1.0000") { print "row " NR ": Embree against itself not 1"; bad = 1 }
  }
  if ($4 != "embree_scene" && $4 != "embree_builder") {
    canopy_rows++
    if (sah == "") sah = $7
    if ($7 != sah || sah == "") { print "row " NR ": SAH " $7 " against " sah; bad = 1 }
  }
  if (($8 != "") != ($10 != "")) { print "row " NR ": one Embree ratio without the other"; bad = 1 }
  if ($8 != "" && !($8 > 0 && $10 > 0)) { print "row " NR ": Embree ratios " $8 " " $10; bad = 1 }
}
END {
  # Five schedulers at two thread counts, and Embree'"'"'s two builders when
  # compiled in.
  if (canopy_rows != 10) { print canopy_rows " canopy rows, want 10"; bad = 1 }
  if (rows != (embree ? 14 : 10)) { print rows " rows"; bad = 1 }
  if (cpus == 2 && over_ideal != rows / 2) { print over_ideal " rows with the speedup over the ideal"; bad = 1 }
  if (bad) exit 1
  print "bench CSV ok: " rows " rows"
}' "$out"

# The core check (Linux): a time for each CPU the process may use (nproc),
# each positive, over the 3 rounds; the CPU of each of the 15 timed
# 1-thread canopy builds (3 rounds, 5 drivers) noted; with more than one
# CPU, the ideal speedup per round, above 1 (a build on every CPU), and
# each of the 7 builders' (5 without Embree) speedup over it.
if [ "$(uname -s)" = Linux ]; then
  awk -v cpus="$(nproc)" -v builders="$(awk -F, 'NR > 1 && $3 == 1' "$out" | wc -l)" '
  /^cores: / {
    seen = 1
    if ($0 !~ /medians of 3 rounds:/) { print "core check: " $0; bad = 1 }
    n = 0
    for (i = 1; i < NF; i++) if ($i ~ /^cpu[0-9]+$/) { n++; if (!($(i + 1) > 0)) { print "core check: " $i " " $(i + 1); bad = 1 } }
    if (n != cpus) { print "core check: " n " CPUs, want " cpus; bad = 1 }
  }
  /^  1-thread builds ended on:/ {
    ended = 1; sum = 0
    for (i = 5; i <= NF; i += 2) sum += $(i + 1)
    if (sum != 15) { print "core check: " sum " 1-thread builds noted, want 15: " $0; bad = 1 }
  }
  /^  ideal speedup/ {
    ideal = 1
    split($0, p, "per round: "); split(p[2], v, " ")
    if (!(v[1] > 1)) { print "core check: ideal " v[1]; bad = 1 }
  }
  /^  speedup at / {
    scaled = 1
    split($0, p, "ratios: "); k = split(p[2], v, ", ")
    if (k != builders) { print "core check: " k " builders over the ideal, want " builders; bad = 1 }
    for (i = 1; i <= k; i++) { split(v[i], w, " "); if (!(w[2] > 0)) { print "core check: " v[i]; bad = 1 } }
  }
  END {
    if (!seen || !ended) { print "core check: no cores: lines"; bad = 1 }
    if (cpus > 1 && (!ideal || !scaled)) { print "core check: no ideal speedup lines"; bad = 1 }
    if (bad) exit 1
    print "core check ok: " cpus " CPUs"
  }' "$out.txt"
fi

# --shuffle: the same triangles in another order, so the scene is named as
# shuffled, has as many triangles, every canopy driver builds the same tree
# (the same SAH), and that SAH is within 1% of the ordered scene's (big
# nodes choose their split axis from a sample of every fourth record by
# position, so a tree depends on the input order a little; see README,
# "The input order").
sah=$(awk -F, '$3 == 1 && $4 == "sequential" { print $2 "," $7 }' "$out")
"$canopy" bench gen:sphere:3000 --shuffle 5 --threads 1 --repeat 1 --gap 0 --prefault 0 --no-core-check \
  --csv "$out.shuffled" >"$out.shuffled.txt"
if grep -q '^cores: ' "$out.shuffled.txt"; then echo "--no-core-check printed the core check"; exit 1; fi
awk -F, -v want="$sah" '
NR > 1 && $4 != "embree_scene" && $4 != "embree_builder" {
  rows++
  if ($1 != "gen:sphere:3000 shuffled:5") { print "shuffled row " NR ": scene " $1; bad = 1 }
  split(want, w, ",")
  if ($2 != w[1]) { print "shuffled row " NR ": " $2 " triangles, want " w[1]; bad = 1 }
  if (first == "") first = $7
  if ($7 != first) { print "shuffled row " NR ": SAH " $7 ", the first driver had " first; bad = 1 }
  if ($7 > w[2] * 1.01 || $7 < w[2] * 0.99) { print "shuffled row " NR ": SAH " $7 ", ordered " w[2]; bad = 1 }
}
END {
  if (rows != 5) { print rows " canopy rows in the shuffled run, want 5"; bad = 1 }
  if (bad) exit 1
  print "shuffled bench ok: " rows " canopy rows, SAH " first " (ordered " want ")"
}' "$out.shuffled"
