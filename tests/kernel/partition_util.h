// What the partition tests and the size-split tests share: splits counted by
// hand, the canonical partition written out plainly, and the blocked and
// two-ended partitions run the way a team runs them.
#pragma once

#include "kernel_test_util.h"

namespace canopy::kernel_test {

// A split on `axis` at bin `index`, with left_count counted by hand from
// the scalar centroid() and the mapping (partition() relies on it).
inline Split make_split(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, const BinMapper& m, int axis,
                 uint32_t index) {
    Split s;
    s.axis = axis;
    s.index = index;
    for (uint32_t i = begin; i < end; ++i) s.left_count += left_of(refs[i], m, s);
    return s;
}

// The canonical partition written out plainly: mid = begin + the number of
// records going left; the k-th record of [begin, mid) going right swaps with
// the k-th record of [mid, end) going left.
template <class Pred>
inline std::vector<PrimRef> reference_partition(std::vector<PrimRef> refs, uint32_t begin, uint32_t end,
                                                Pred goes_left) {
    uint32_t mid = begin;
    for (uint32_t i = begin; i < end; ++i) mid += goes_left(refs[i]);
    std::vector<uint32_t> right_in_left, left_in_right;
    for (uint32_t i = begin; i < mid; ++i)
        if (!goes_left(refs[i])) right_in_left.push_back(i);
    for (uint32_t i = mid; i < end; ++i)
        if (goes_left(refs[i])) left_in_right.push_back(i);
    EXPECT_EQ(right_in_left.size(), left_in_right.size());
    for (size_t k = 0; k < right_in_left.size(); ++k) std::swap(refs[right_in_left[k]], refs[left_in_right[k]]);
    return refs;
}

// A block size of the order the team-parallel node uses.
inline constexpr uint32_t kBlock = 16384;

// Both children's bounds, centroid bounds and largest areas equal.
inline void expect_same_children(const PartitionResult& got, const PartitionResult& want) {
    EXPECT_EQ(got.left_bounds(), want.left_bounds());
    EXPECT_EQ(got.left_cbounds(), want.left_cbounds());
    EXPECT_EQ(got.left_max_area(), want.left_max_area());
    EXPECT_EQ(got.right_bounds(), want.right_bounds());
    EXPECT_EQ(got.right_cbounds(), want.right_cbounds());
    EXPECT_EQ(got.right_max_area(), want.right_max_area());
}

// The partition as a team-parallel node runs it, on `refs`: mark_sides() on
// consecutive `ranges` (starting at multiples of 64 from the first), in a
// shuffled order; plan_swaps() with `per_piece`; the pieces swapped in a
// shuffled order. Returns the merged bounds, mid = the node's mid.
inline PartitionResult blocked_partition(std::vector<PrimRef>& refs,
                                  const std::vector<std::pair<uint32_t, uint32_t>>& ranges, const BinMapper& m,
                                  const Split& s, uint32_t per_piece, uint32_t seed = 1) {
    const uint32_t begin = ranges.front().first, end = ranges.back().second;
    std::vector<uint64_t> sides((end - begin + 63) / 64, 0x5555555555555555u);  // garbage: all overwritten
    std::vector<size_t> order(ranges.size());
    std::iota(order.begin(), order.end(), size_t(0));
    std::mt19937 rng(seed);
    std::shuffle(order.begin(), order.end(), rng);
    PartitionResult merged;
    for (size_t k : order) {
        EXPECT_EQ((ranges[k].first - begin) % 64, 0u);
        merged.merge(canopy::mark_sides(refs.data(), ranges[k].first, ranges[k].second, begin, m, s, sides.data()));
    }
    uint32_t right_in_left = 0;  // records to swap out of the left part
    for (uint32_t i = begin; i < begin + s.left_count; ++i) right_in_left += !canopy::goes_left(refs[i], m, s);
    std::vector<canopy::SwapPiece> pieces;
    canopy::plan_swaps(sides.data(), begin, begin + s.left_count, per_piece, pieces);
    uint32_t pairs = 0;
    for (const auto& p : pieces) {
        EXPECT_GT(p.count, 0u);
        EXPECT_LE(p.count, per_piece);
        pairs += p.count;
    }
    std::shuffle(pieces.begin(), pieces.end(), rng);
    for (const auto& p : pieces) canopy::swap_misplaced(refs.data(), sides.data(), begin, p);
    // Every misplaced pair was in some piece: afterwards all sides are right.
    uint32_t misplaced = 0;
    for (uint32_t i = begin; i < begin + s.left_count; ++i) misplaced += !canopy::goes_left(refs[i], m, s);
    EXPECT_EQ(misplaced, 0u);
    EXPECT_EQ(pairs, right_in_left);
    merged.mid = begin + s.left_count;
    return merged;
}

// The two-ended partition as a team of two runs it: both halves (in the
// order given; they touch disjoint records), then their leftovers paired.
inline PartitionResult halves_partition(std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                 const Split& s, bool back_first, uint32_t& leftovers) {
    canopy::HalfLeftovers front, back;
    PartitionResult r0, r1;
    if (back_first) r1 = canopy::partition_half<1>(refs.data(), begin, end, m, s, back);
    r0 = canopy::partition_half<0>(refs.data(), begin, end, m, s, front);
    if (!back_first) r1 = canopy::partition_half<1>(refs.data(), begin, end, m, s, back);
    EXPECT_EQ(front.count, back.count);
    leftovers = front.count;
    canopy::swap_leftovers(refs.data(), front, back);
    r0.merge(r1);
    r0.mid = begin + s.left_count;
    return r0;
}

}  // namespace canopy::kernel_test
