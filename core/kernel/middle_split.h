// canopy: the middle split, which halves a node's range in its current order:
// for nodes whose centroids coincide (no plane separates them) or that no
// SAH split was found for, and for nodes at the depth cap.
#pragma once

#include "partition.h"

#include <cstdint>

namespace canopy {

// Bounds of refs[b, e) as one side of a middle split.
inline void grow_range(const PrimRef* refs, uint32_t b, uint32_t e, ChildBounds4& acc, int side) {
    for (uint32_t i = b; i < e; ++i) {
        const __m128 lo = simd::lo(refs[i]);
        acc.add(side, lo, simd::hi_area(refs[i]), simd::centroid(lo, simd::hi(refs[i])));
    }
}

// The middle split: [begin, mid) and [mid, end) in their current order, for
// nodes with no SAH split and for the depth cap. Bounds by one pass.
inline PartitionResult middle_split(const PrimRef* refs, uint32_t begin, uint32_t end) {
    ChildBounds4 acc;
    const uint32_t mid = begin + (end - begin) / 2;
    grow_range(refs, begin, mid, acc, 0);
    grow_range(refs, mid, end, acc, 1);
    return result_of(acc, mid);
}

}  // namespace canopy
