// canopy: placing nodes in the canonical layout.
//
// Parallel schedulers create nodes in whatever order their workers happen to
// run; none of that order may reach the output. Each worker keeps two kinds
// of output in its own arena (PlacementArena):
//
//  - a NodeRecord per node it ran as a task (the few big nodes above the
//    task cutoff), placed by arithmetic:
//
//      c(v) = 1 + 2 * (depth(v) + L(v) - rights(v))
//
//    is the position of the first child of inner node v, where L(v) is the
//    number of leaves whose range starts before v's range (leaves tile the
//    permutation), and rights(v) the number of right turns from the root to
//    v. (In depth-first pre-order, the child pairs allocated before v's are
//    those of v's ancestors and of the inner nodes of the subtrees left of
//    v's path; those subtrees hold L(v) leaves and rights(v) roots, hence
//    L - rights inner nodes.) A left child sits at c(parent), a right child
//    at c(parent) + 1, where the parent's begin, depth and rights follow
//    from the child's record;
//
//  - a SubtreeBlock per subtree it ran inline below the cutoff (almost all
//    nodes): the subtree's nodes in the sequential layout
//    (core/depth_first.h), indices relative to the block. In the canonical
//    layout the descendants of a node fill consecutive slots from its first
//    child's, in the same relative order, so the block's root goes to its
//    arithmetic slot and the rest moves there by one offset: a sequential
//    copy that rewrites child indices.
//
// Renumbering blocks this way was measured against placing every node by
// arithmetic (bench/bench_placement.cpp, README "The schedulers"): the final
// pass took 0.27 to 0.37 times as long, whole 2-thread builds 0.87 to 0.96
// times, and workers store 32 bytes per node instead of 40.
#pragma once

#include "bvh.h"
#include "kernel.h"
#include "memory.h"
#include "overflow_area.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <immintrin.h>
#include <span>
#include <utility>
#include <vector>

// The pieces, in this order (the order of the one file they were until
// 2026-12-07, which keeps the compiled code as it was).
#include "layout/records.h"
#include "layout/arena.h"
#include "layout/place.h"
#include "layout/move_blocks.h"
#include "layout/beside_records.h"

namespace canopy {

// Places over_records arenas into `nodes`, whose storage (its capacity; the
// vector is empty) holds the records `refs` and, over them, the blocks'
// nodes: in that same storage when the tree fits in it and every block's
// nodes move towards the front (its canonical slots start at or before its
// records, as when the tree has at most about one node per record up to
// every point: the storage has a tenth more slots than records, in front of
// them). The blocks move in the order of their ranges, each to slots
// before those of every later block's records, so no block is overwritten
// before it has moved; then the task nodes and the blocks' roots are
// written; a tree of at least `parallel_min` nodes moves split over the
// arenas' workers (move_blocks()). A tree that does not fit this way
// (random triangles' trees: 1.86 nodes per record) goes into a new array
// beside the storage, which gives back its pages as the copies consume them
// (place_beside_records()). (Until 2026-12-05 such a tree went into a fresh
// array with the storage and the overflow held whole: 127 bytes per
// triangle at the peak of a 2-thread build of 1M random triangles; then,
// until the new array, the storage grew in place and the blocks moved up on
// one thread, with the overflow held whole: 91.9.)
template <class ForEach>
void place_over_records(std::span<const PlacementArena* const> arenas, const PrimRef* refs, NodeArray& nodes,
                        ForEach&& for_each, size_t parallel_min = 0, BesideRecordsSizes sizes = {}) {
    PieceRank rank;
    const size_t total = rank_pieces(arenas, rank);
    std::vector<BlockMove> moves;
    for (const PlacementArena* a : arenas)
        for (const SubtreeBlock& b : a->blocks)
            if (b.size > 1) moves.push_back({a, &b, 0});
    std::sort(moves.begin(), moves.end(),
              [](const BlockMove& x, const BlockMove& y) { return x.block->root.begin < y.block->root.begin; });
    bool in_place = total <= nodes.capacity();
    const auto at = [](const void* p) { return reinterpret_cast<std::uintptr_t>(p); };
    for (BlockMove& m : moves) {
        m.c = block_first_child(*m.block, rank);
        in_place = in_place && at(nodes.data() + m.c) <= at(refs + m.block->root.begin);
    }
    if (in_place) {
        // Within the capacity: no reallocation, and Node() writes nothing.
        nodes.resize(total);
        move_blocks(moves, refs, nodes.data(), total >= parallel_min ? arenas.size() : 1, for_each);
    } else {
        const size_t groups = total >= parallel_min ? arenas.size() : 1;
        // The storage before the records was never written (a parallel
        // build writes no node there before the placement): given back,
        // unless the overflow area has already (OverflowArea::watch_front()).
        OverflowArea& area = *arenas.front()->overflow;
        area.give_front(nodes, refs);
        nodes = place_beside_records(moves, refs, area, nodes, total, groups, for_each, sizes);
    }
    Node* const out = nodes.data();
    for_each(arenas.size(), [&](size_t i) {
        for (const NodeRecord& r : arenas[i]->records) place_record(r, rank, out);
        for (const SubtreeBlock& b : arenas[i]->blocks) place_record(b.root, rank, out);
    });
}

}  // namespace canopy
