// canopy: an exact full-sweep SAH builder, the reference the binned build's
// accuracy is measured against.
//
// Every primitive's centroid is sorted once per axis at the root (by
// centroid coordinate, then id); each split partitions the three sorted
// orders stably, so they stay sorted and nothing is sorted again. At every
// node every split position between two distinct centroid coordinates of
// every axis is evaluated, with prefix and suffix sweeps of the boxes and
// the SAH in double precision. The rules are the binned build's (see
// kernel.h): the cost of a split is C_t + C_i (A_L n_L + A_R n_R) / A (the
// sum of extents instead of the half area when the node is flat: zero half
// area); a node is a leaf iff it has at most max_leaf primitives and no split
// is cheaper than C_i n; max_leaf is a hard cap (a node with no split is
// split in the middle of its axis-0 order); the same depth cap (plan() in
// kernel.h); ties go to the lowest axis, then the lowest split position.
//
// The result is a canonical canopy::Bvh (see bvh.h) that passes validate().
// It is single-threaded and slow (O(n) per node and axis, plus the sorts):
// a reference, not a production builder.
#pragma once

#include "bvh.h"
#include "mesh.h"
#include "options.h"

#include <span>

namespace canopy {

// Throws InputError for bad triangles (as build() does) and OptionError for
// bad options. options.bins, threads and tuning are ignored.
Bvh build_sweep_sah(const TriangleView& mesh, const BuildOptions& options = {});
// The same over caller-given primitive boxes.
Bvh build_sweep_sah(std::span<const Box> boxes, const BuildOptions& options = {});

}  // namespace canopy
