// canopy: step 4 of the node task: the two child tasks of a split node,
// and the children's bounds taken from the bins after a partition by keys.
#pragma once

#include "bins.h"
#include "partition.h"
#include "task.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace canopy {

// After a partition by keys of node t by plane split s (mapping m), the
// children's bounds from the node's bins: each child's box and largest area
// from the bins of the split axis (bins [0, s.index) hold the left child's
// records, the others the right child's), bit for bit as a partition grows
// them from the records. Each child's centroid bounds are a box holding its
// centroids: its box, within the node's centroid bounds, and on the split
// axis within the child's non-empty bins there (widened by a margin above
// the mapping's roundings). Not the tight box of the centroids a partition
// grows, so the children's mappings differ by up to half a primitive's
// extent on the other axes, and by less than a bin width on the split axis;
// on the meshes of ../shared/scenes the trees' SAH moved by -0.19% to
// +0.12%. (Taking the children's bounds on the split axis as loosely as on
// the others, Šibenik's tree was 3.9% worse.) Should a centroid round
// outside, BinMapper clamps it into the first or last bin.
inline void bounds_from_bins(const BinArrays& bins, const BinMapper& m, const NodeTask& t, const Split& s,
                             PartitionResult& p) {
    const int axis = s.axis;
    simd::MinBox side[2] = {BinArrays::empty(), BinArrays::empty()};
    for (uint32_t b = 0; b < m.bins; ++b) side[b >= s.index].grow(bins.at(axis, b));
    Box c[2];
    for (int k = 0; k < 2; ++k) {
        p.acc.bounds[k] = side[k].box4();
        const Box b = p.acc.bounds[k].box();
        c[k] = Box{glm::max(b.lo, t.cbounds.lo), glm::min(b.hi, t.cbounds.hi)};
    }
    // The non-empty bins of each side: [first, lmax] left, [rmin, last]
    // right (both sides hold records).
    uint32_t first = 0, lmax = s.index - 1, rmin = s.index, last = m.bins - 1;
    while (bins.count(axis, first) == 0) ++first;
    while (bins.count(axis, lmax) == 0) --lmax;
    while (bins.count(axis, rmin) == 0) ++rmin;
    while (bins.count(axis, last) == 0) --last;
    const double w = 1.0 / double(m.scale[axis]);  // a bin's width
    const double o = double(m.origin[axis]);
    const double big = std::max(std::abs(o), std::abs(o + double(m.bins) * w));
    // Bins k..l span [o + k w, o + (l + 1) w], give or take the mapping's
    // roundings: a few float ulps of the coordinates and of the extent, well
    // inside `margin` where bins are wide against the coordinates (not
    // narrowed otherwise, nor for a prescaled mapping).
    if (m.prescale[axis] == 1.0f && w >= 0x1p-20 * big) {
        const double margin = 0x1p-21 * (big + double(m.bins) * w);
        const uint32_t from[2] = {first, rmin}, to[2] = {lmax, last};
        for (int k = 0; k < 2; ++k) {
            c[k].lo[axis] = std::max(c[k].lo[axis], float(o + double(from[k]) * w - margin));
            c[k].hi[axis] = std::min(c[k].hi[axis], float(o + double(to[k] + 1) * w + margin));
        }
    }
    for (int k = 0; k < 2; ++k) {
        for (int a = 0; a < 3; ++a)
            if (!(c[k].lo[a] <= c[k].hi[a])) {  // cannot happen while the boxes hold the centroids
                const Box b = p.acc.bounds[k].box();
                c[k].lo[a] = b.lo[a];
                c[k].hi[a] = b.hi[a];
            }
        p.acc.cbounds[k] = simd::Box4::of(c[k]);
    }
}

// Where the children of t sit in the tree: their depth, parent and turns,
// for the layout's arithmetic.
inline void link(const NodeTask& t, NodeTask out[2]) {
    for (int k = 0; k < 2; ++k) {
        out[k].depth = t.depth + 1;
        out[k].parent_begin = t.begin;
        out[k].is_right = k == 1;
        out[k].rights = static_cast<uint8_t>(t.rights + k);
    }
}

// Step 4: the two child tasks of a split node.
inline void emit(const NodeTask& t, const PartitionResult& p, NodeTask out[2]) {
    out[0].begin = t.begin;
    out[0].end = p.mid;
    out[0].bounds = p.left_bounds();
    out[0].cbounds = p.left_cbounds();
    out[1].begin = p.mid;
    out[1].end = t.end;
    out[1].bounds = p.right_bounds();
    out[1].cbounds = p.right_cbounds();
    out[0].max_area = p.left_max_area();
    out[1].max_area = p.right_max_area();
    out[0].carried = out[1].carried = false;
    link(t, out);
}

}  // namespace canopy
