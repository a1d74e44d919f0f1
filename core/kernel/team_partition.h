// canopy: the pieces of a partition that a team of threads runs on one big
// node (by chunks, or by halves), each giving the records and bounds that
// partition() gives.
#pragma once

#include "partition.h"

#include <bit>
#include <cstdint>
#include <utility>
#include <vector>

namespace canopy {

// The partition of a node by a team, in two parallel passes (after binning):
//  1. mark_sides() over ranges of the node that start at multiples of 64
//     records from its begin, in any order: each range's side bits (bit
//     i - begin of `sides` set: record i goes left; whole words, zero past
//     the range's end) and its share of the child bounds (merged exactly);
//  2. plan_swaps() (one thread, a popcount walk over the words) cuts the
//     misplaced pairs into pieces by rank, and swap_misplaced() swaps one
//     piece's pairs; pieces touch disjoint records, in any order.
// The pairs are the ones partition() swaps, so the records end the same.
inline PartitionResult mark_sides(const PrimRef* refs, uint32_t b, uint32_t e, uint32_t node_begin,
                                  const BinMapper& m, const Split& s, uint64_t* sides,
                                  const uint32_t* keys = nullptr) {
    return with_side_test(m, s, keys, refs, [&](const auto& side) {
        ChildBounds4 acc;
        for (uint32_t i = b; i < e; i += kSideBlock)
            sides[(i - node_begin) / kSideBlock] = mark_block(refs + i, std::min(kSideBlock, e - i), side, acc);
        return result_of(acc, 0);
    });
}

// The partition of a node by two threads, each reading half of the records
// once (a team of two or three; see ParallelNode). The same pairs as
// partition(): with M misplaced records in each part, the k-th going right
// in [b, mid) trades places with the k-th going left in [mid, e). The front
// half (side 0) pairs ranks upward from 0 over [b, ql) and [mid, qr), in
// position order as partition() does; the back half (side 1) pairs ranks
// downward from M - 1 over [ql, mid) and [qr, e), walking its blocks from
// the end and taking the highest bits first. A half whose two parts held
// unequal numbers of misplaced records (a and a', a > a') keeps a - a' of
// them unpaired in one part: ranks a'..a-1 of that part. The other half
// then keeps the same ranks of the other part (the counts of both parts sum
// to M), so the leftovers of the two halves pair with each other, rank for
// rank, in swap_leftovers(). Child bounds are grown as the records are read
// and merged exactly, as in mark_sides().
struct HalfLeftovers {
    // Unpaired misplaced records, ascending rank: blocks as (first record,
    // bits relative to it).
    std::vector<std::pair<uint32_t, uint64_t>> blocks;
    uint32_t count = 0;

    void clear() {
        blocks.clear();
        count = 0;
    }
    void add(uint32_t first, uint64_t bits) {
        if (!bits) return;
        blocks.push_back({first, bits});
        count += uint32_t(std::popcount(bits));
    }
};

// One part's share in partition_half(): its blocks of up to kSideBlock
// records, read from lo up (side 0) or from hi down (side 1), each leaving
// its misplaced records as bits.
template <int Side>
struct HalfCursor {
    uint32_t lo, hi;
    uint32_t at = Side == 0 ? lo : hi;  // the next block's bound
    uint32_t first = 0;                 // the current block's first record
    uint64_t bits = 0;                  // its misplaced records not yet paired
    // Reads the next block (false when none is left); `right_part`: the
    // misplaced records are those going left, else those going right.
    template <class Test>
    bool next(const PrimRef* refs, const Test& side, ChildBounds4& acc, bool right_part) {
        if (Side == 0 ? at >= hi : at <= lo) return false;
        const uint32_t n = std::min(kSideBlock, Side == 0 ? hi - at : at - lo);
        first = Side == 0 ? at : at - n;
        const uint64_t left = mark_block(refs + first, n, side, acc);
        bits = right_part ? left : ~left & block_bits(n);
        at = Side == 0 ? at + n : at - n;
        if constexpr (std::is_same_v<Test, KeyTest>) {
            // (see prefetch_for_write(): a team's node is one whose lines
            // the other cores read last)
            if constexpr (Side == 0)
                prefetch_up(refs, at, hi);
            else
                prefetch_down(refs, at, lo);
        }
        return true;
    }
    // The next pair's bit: the lowest going up, the highest going down.
    uint32_t take() {
        const uint32_t k = Side == 0 ? uint32_t(std::countr_zero(bits)) : 63u - uint32_t(std::countl_zero(bits));
        bits &= ~(uint64_t(1) << k);
        return first + k;
    }
};

// Side 0: [b, ql) and [mid, qr); side 1: [ql, mid) and [qr, e).
template <int Side, class Test>
PartitionResult partition_half(PrimRef* refs, uint32_t b, uint32_t ql, uint32_t mid, uint32_t qr, uint32_t e,
                               const Test& side, HalfLeftovers& left_over) {
    ChildBounds4 acc;
    left_over.clear();
    HalfCursor<Side> li{Side == 0 ? b : ql, Side == 0 ? ql : mid};   // going right in the left part
    HalfCursor<Side> rj{Side == 0 ? mid : qr, Side == 0 ? qr : e};   // going left in the right part
    for (;;) {
        if (!li.bits && !li.next(refs, side, acc, false)) break;
        if (!rj.bits && !rj.next(refs, side, acc, true)) break;
        while (li.bits && rj.bits) swap_refs(refs[li.take()], refs[rj.take()]);
    }
    // At most one part has misplaced records left: its pending block and
    // the blocks not read yet (the other part's are all read).
    left_over.add(li.first, li.bits);
    while (li.next(refs, side, acc, false)) left_over.add(li.first, li.bits);
    left_over.add(rj.first, rj.bits);
    while (rj.next(refs, side, acc, true)) left_over.add(rj.first, rj.bits);
    if (Side == 1) std::reverse(left_over.blocks.begin(), left_over.blocks.end());  // found from the highest rank down
    return result_of(acc, 0);
}

// Pairs the two halves' leftovers rank for rank (equally many).
inline void swap_leftovers(PrimRef* refs, const HalfLeftovers& front, const HalfLeftovers& back) {
    assert(front.count == back.count);
    size_t fb = 0, bb = 0;
    uint64_t fm = 0, bm = 0;
    for (uint32_t k = 0; k < front.count; ++k) {
        if (!fm) fm = front.blocks[fb++].second;
        if (!bm) bm = back.blocks[bb++].second;
        swap_refs(refs[front.blocks[fb - 1].first + uint32_t(std::countr_zero(fm))],
                  refs[back.blocks[bb - 1].first + uint32_t(std::countr_zero(bm))]);
        fm &= fm - 1;
        bm &= bm - 1;
    }
}

// One half of the two-ended partition of refs[begin, end) split at mid, with
// the split's side test; the halves' shares of the parts are cut at their
// middles.
template <int Side>
PartitionResult partition_half(PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, const Split& s,
                               HalfLeftovers& left_over, const uint32_t* keys = nullptr) {
    const uint32_t mid = begin + s.left_count;
    const uint32_t ql = begin + (mid - begin) / 2, qr = mid + (end - mid) / 2;
    return with_side_test(m, s, keys, refs, [&](const auto& side) {
        return partition_half<Side>(refs, begin, ql, mid, qr, end, side, left_over);
    });
}

// A run of misplaced pairs: the first pair's positions in the left part and
// in the right part, and how many pairs.
struct SwapPiece {
    uint32_t left_at = 0, right_at = 0, count = 0;
};

// Word w of the side bits with the bits equal to `want` set.
inline uint64_t side_word(const uint64_t* sides, uint32_t w, bool want) { return want ? sides[w] : ~sides[w]; }

// The first position at or after `at` whose side bit is `want` (one exists).
inline uint32_t next_side(const uint64_t* sides, uint32_t node_begin, uint32_t at, bool want) {
    uint32_t w = (at - node_begin) / 64;
    uint64_t bits = side_word(sides, w, want) & (~uint64_t(0) << ((at - node_begin) % 64));
    while (!bits) bits = side_word(sides, ++w, want);
    return node_begin + w * 64 + uint32_t(std::countr_zero(bits));
}

// Cuts the misplaced pairs of the node [begin, end) split at mid into
// pieces of `per_piece` pairs (the last may have fewer), in rank order.
inline void plan_swaps(const uint64_t* sides, uint32_t begin, uint32_t mid, uint32_t per_piece,
                       std::vector<SwapPiece>& pieces) {
    pieces.clear();
    // Finds the positions of increasing ranks among one part's `want` bits,
    // from word w on (first_mask: the bits of the part's first word that
    // belong to it).
    struct Walk {
        const uint64_t* sides;
        uint32_t begin;
        bool want;
        uint32_t w, first_word;
        uint64_t first_mask;
        uint32_t seen = 0;  // wanted bits before word w
        uint64_t bits(uint32_t k) const {
            const uint64_t v = side_word(sides, k, want);
            return k == first_word ? v & first_mask : v;
        }
        uint32_t find(uint32_t rank) {
            for (;; seen += uint32_t(std::popcount(bits(w))), ++w) {
                uint64_t v = bits(w);
                if (seen + uint32_t(std::popcount(v)) <= rank) continue;
                for (uint32_t r = rank - seen; r; --r) v &= v - 1;
                return begin + w * 64 + uint32_t(std::countr_zero(v));
            }
        }
    };
    const uint32_t nl = mid - begin;
    uint32_t stay = 0;  // left-going records in [begin, mid)
    for (uint32_t w = 0; w < nl / 64; ++w) stay += uint32_t(std::popcount(sides[w]));
    if (nl % 64) stay += uint32_t(std::popcount(sides[nl / 64] & block_bits(nl % 64)));
    const uint32_t misplaced = nl - stay;
    Walk left{sides, begin, false, 0, 0, ~uint64_t(0)};
    Walk right{sides, begin, true, nl / 64, nl / 64, ~block_bits(nl % 64)};
    for (uint32_t k = 0; k < misplaced; k += per_piece) {
        SwapPiece p;
        p.left_at = left.find(k);
        p.right_at = right.find(k);
        p.count = std::min(per_piece, misplaced - k);
        pieces.push_back(p);
    }
}

inline void swap_misplaced(PrimRef* refs, const uint64_t* sides, uint32_t node_begin, const SwapPiece& p) {
    uint32_t i = p.left_at, j = p.right_at;
    for (uint32_t c = 0; c < p.count; ++c, ++i, ++j) {
        i = next_side(sides, node_begin, i, false);
        j = next_side(sides, node_begin, j, true);
        swap_refs(refs[i], refs[j]);
    }
}

}  // namespace canopy
