// canopy: moving the subtree blocks' bodies to their canonical slots in the
// storage that holds them over their records (place_over_records() in
// core/layout.h), split into runs over the workers.
#pragma once

#include "place.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

namespace canopy {

// A block of an in-place placement: its arena, and its first child's
// canonical slot.
struct BlockMove {
    const PlacementArena* arena;
    const SubtreeBlock* block;
    uint32_t c;
};

// Cuts `moves` (in the order of their ranges) into `groups` runs of
// consecutive blocks with about equal numbers of nodes: run r is
// [first[r], first[r + 1]).
inline std::vector<size_t> cut_runs(std::span<const BlockMove> moves, size_t groups) {
    size_t body = 0;
    for (const BlockMove& m : moves) body += m.block->size - 1;
    std::vector<size_t> first(groups + 1, moves.size());
    first[0] = 0;
    size_t done = 0, g = 1;
    for (size_t k = 0; k < moves.size() && g < groups; ++k) {
        while (g < groups && done >= body * g / groups) first[g++] = k;
        done += moves[k].block->size - 1;
    }
    return first;
}

// Moves the blocks' bodies (sorted by range, each to slots at or before its
// records: see place_over_records()) to their slots of `out`, split into
// `groups` runs of consecutive blocks with about equal numbers of nodes,
// run by for_each, in any order or at once. In order within a run, no block
// overwrites another's nodes before they have moved (place_over_records()
// in core/layout.h says why); across runs, a block whose slots start before
// its run's first records may overwrite the records of an earlier run's
// blocks, which may not have moved yet: each run first copies such blocks
// (a prefix of it, since slots and records both grow along the run) into a
// buffer of its own, then moves the rest in order, and every buffer goes to
// its slots once all runs are done. A run's own moves stay below its next
// run's first slot, and so below that run's records. The buffers hold about
// the gap between the slots and the records at each run's start: at most
// the storage's slack (a tenth of a node per record).
template <class ForEach>
void move_blocks(std::span<const BlockMove> moves, const PrimRef* refs, Node* out, size_t groups,
                 ForEach&& for_each) {
    groups = std::clamp<size_t>(groups, 1, std::max<size_t>(moves.size(), 1));
    if (groups == 1) {
        for (const BlockMove& m : moves) place_block_body(*m.arena, *m.block, refs, m.c, out + m.c);
        return;
    }
    const std::vector<size_t> first = cut_runs(moves, groups);
    const auto at = [](const void* p) { return reinterpret_cast<std::uintptr_t>(p); };
    std::vector<NodeChunk> buffer(groups);
    std::vector<size_t> buffered_end(groups);
    for_each(groups, [&](size_t r) {
        size_t k = first[r], e = k;
        if (r > 0 && k < first[r + 1]) {
            // Blocks whose slots start below this run's first records.
            const std::uintptr_t limit = at(refs + moves[k].block->root.begin);
            size_t count = 0;
            for (; e < first[r + 1] && at(out + moves[e].c) < limit; ++e) count += moves[e].block->size - 1;
            buffer[r].reserve(count);  // NodeChunk: whole huge pages from 2 MiB on (allocate_huge())
            buffer[r].resize(count);  // Node() writes nothing
            Node* dst = buffer[r].data();
            for (; k < e; ++k) {
                const BlockMove& m = moves[k];
                place_block_body(*m.arena, *m.block, refs, m.c, dst);
                dst += m.block->size - 1;
            }
        }
        buffered_end[r] = e;
        for (; k < first[r + 1]; ++k) {
            const BlockMove& m = moves[k];
            place_block_body(*m.arena, *m.block, refs, m.c, out + m.c);
        }
    });
    for_each(groups, [&](size_t r) {
        const Node* src = buffer[r].data();
        for (size_t k = first[r]; k < buffered_end[r]; ++k) {
            const size_t size = moves[k].block->size - 1;
            std::memcpy(static_cast<void*>(out + moves[k].c), src, size * sizeof(Node));
            src += size;
        }
    });
}

}  // namespace canopy
