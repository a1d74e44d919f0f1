// canopy: what a worker leaves for the placement (core/layout.h): its task
// nodes' records, and its subtree blocks with their nodes in chunks of its
// own or over their records.
#pragma once

#include "records.h"
#include "../memory.h"
#include "../overflow_area.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace canopy {

// Where in the overflow area a block puts the `past` nodes past its records
// when its slots there are [lo, hi) (OverflowArea::slot() of its range's
// ends; `past` at most hi - lo): from the first page boundary (128 nodes) in
// them for a left child, up to the last one for a right child (from lo, up
// to hi, where they do not fit so), so that the unused ends of two sibling
// blocks' slots meet and no page holds the nodes of two blocks. The area
// brings in whole pages: with each block's nodes from its range's start,
// the blocks of 33,000 random triangles (subtrees of up to 1,031 records,
// 0.86 nodes past the records per record) left almost no page of the area
// untouched, about 3.4 bytes per triangle of the peak (110 KiB over the
// nodes).
inline uint64_t area_start(uint64_t lo, uint64_t hi, uint64_t past, bool right) {
    constexpr uint64_t kPageNodes = 4096 / sizeof(Node);
    if (!right) {
        const uint64_t at = (lo + kPageNodes - 1) / kPageNodes * kPageNodes;
        return at + past <= hi ? at : lo;
    }
    const uint64_t last = hi / kPageNodes * kPageNodes;
    return last >= lo + past ? last - past : hi - past;
}

// A subtree one worker built inline (see the top of core/layout.h). Its nodes
// are kept one of two ways, as the arena says (PlacementArena::over_records):
//  - all `size` of them in the arena's chunks: chunks[chunk] from `first` on,
//    then the following chunks from their start (it filled each but its last);
//  - over its own records (a one-off build, whose records lie in the final
//    node array's storage): block nodes 1 to `over_records` written over the
//    records [root.begin, root.begin + over_records), which the subtree no
//    longer needs once it is built; the nodes after them, when the block has
//    more nodes than records, `in_area` of them in the overflow area from
//    `area` on, within the block's slots there (area_start()), and the rest
//    in the chunks from (chunk, first) as above: those that do not fit in a
//    dense area's slots, or all of them when they are few
//    (PlacementArena::kSpillMax). There are nodes past the records only when
//    the records are all covered (over_records is the block's record count).
//    Block node 0, the subtree's root, is not stored: `root` describes it
//    (an inner root's first child is block node 1).
struct SubtreeBlock {
    NodeRecord root;      // where the subtree's root sits in the tree
    uint32_t chunk = 0;
    uint32_t first = 0;
    uint32_t size = 0;
    uint32_t leaves = 0;
    uint32_t over_records = 0;
    uint32_t area = 0;     // over_records: the first of its nodes in the overflow area
    uint32_t in_area = 0;  // over_records: how many of its nodes are there

    // over_records: how many nodes follow the area's in the chunks.
    uint32_t in_chunks() const { return size - 1 - over_records - in_area; }
};

// A chunk of a worker's nodes: from 2 MiB on, 2 MiB-aligned memory, so
// that a chunk of whole huge pages faults only in huge pages (see
// allocate_huge() and Workers::reset(), which sizes the chunks).
using NodeChunk = std::vector<Node, HugePageAllocator<Node>>;

// What one worker leaves for the placement.
//
// A worker's subtree blocks go one after another into chunks of nodes, and
// a block that fills a chunk goes on in a new one (ChunkedNodes below), so
// every chunk but the last ends full. (Until 825a86f, 2026-12-05, the last
// one's unused end was given back before the final array was allocated;
// one-off builds no longer allocate one when the tree fits over the
// records, and warm builds keep their chunks. Until late on 2026-12-02 a block needed
// room for its bound, twice its primitives, in one chunk before it started,
// so each chunk's end and the last chunk's unused part were waste that
// depended on which worker built which subtree: the 2-thread peak of
// dragon_vrip_res2 was 79.5 to 86.9 bytes per triangle.)
struct PlacementArena {
    std::vector<NodeRecord> records;        // nodes run one at a time
    std::vector<NodeChunk> chunks;          // the blocks' nodes, block after block
    std::vector<SubtreeBlock> blocks;
    size_t chunk_nodes = size_t(1) << 17;   // chunk size (4 MiB)
    std::vector<NodeChunk> spare;           // emptied chunks of earlier builds
    bool over_records = false;              // blocks are kept over their records (SubtreeBlock)
    NodeArray scratch;                      // one block's nodes while it is built (over_records)
    // over_records: the nodes of blocks that have more nodes than records,
    // past the first `over_records`, at the block's range (shared by every
    // worker's arena).
    OverflowArea* overflow = nullptr;
    // over_records: the nodes past the records of blocks that have fewer
    // than kSpillMax of them go to the chunks (append()), block after
    // block, instead of the overflow area, where each such block would
    // bring in a page or two of its own for a few nodes (a mesh's tree has
    // a few dozen to a few hundred such blocks).
    static constexpr uint32_t kSpillMax = 512;

    // The chunk a new block starts in: the last one (ChunkedNodes moves on
    // when it is full).
    NodeChunk& open_chunk() {
        if (chunks.empty()) return new_chunk();
        return chunks.back();
    }
    // A new last chunk, never grown past its capacity, so node addresses in
    // it stay valid.
    NodeChunk& new_chunk() {
        const size_t cap = std::max<size_t>(chunk_nodes, 1);
        NodeChunk c;
        if (!spare.empty() && spare.back().capacity() >= cap) {
            c = std::move(spare.back());
            spare.pop_back();
        } else {
            c.reserve(cap);  // NodeChunk's allocator advises huge pages itself
        }
        return chunks.emplace_back(std::move(c));
    }
    // Appends k nodes to the chunks, from where the last one has room and
    // on into new ones; returns where they start (chunk, first).
    std::pair<uint32_t, uint32_t> append(const Node* src, size_t k) {
        NodeChunk* c = &open_chunk();
        if (c->size() == c->capacity()) c = &new_chunk();
        const std::pair<uint32_t, uint32_t> at{static_cast<uint32_t>(chunks.size() - 1),
                                               static_cast<uint32_t>(c->size())};
        while (k > 0) {
            if (c->size() == c->capacity()) c = &new_chunk();
            const size_t take = std::min(k, c->capacity() - c->size());
            c->insert(c->end(), src, src + take);
            src += take;
            k -= take;
        }
        return at;
    }
    // Empties the arena for another build; the chunks' memory is kept for
    // new_chunk() to reuse.
    void reset() {
        records.clear();
        blocks.clear();
        for (auto& c : chunks) {
            c.clear();
            spare.push_back(std::move(c));
        }
        chunks.clear();
        // Largest last, the one new_chunk() looks at.
        std::sort(spare.begin(), spare.end(),
                  [](const NodeChunk& a, const NodeChunk& b) { return a.capacity() < b.capacity(); });
    }
    size_t node_count() const {
        size_t n = records.size();
        for (const SubtreeBlock& b : blocks) n += b.size;
        return n;
    }
};

// A worker's subtree block in its arena's chunks, as build_depth_first
// (core/depth_first.h) fills it: slots are node addresses, which stay valid
// because chunks never grow; the block starts where the last chunk has room
// and goes on at the start of a new chunk whenever one is full.
class ChunkedNodes {
public:
    struct Slot {
        Node* node;
        uint32_t number;  // in the block
    };
    explicit ChunkedNodes(PlacementArena& a) : arena_(a), chunk_(&a.open_chunk()) {}

    Slot root() {
        const Slot s = next();
        first_chunk_ = static_cast<uint32_t>(arena_.chunks.size() - 1);
        first_ = static_cast<uint32_t>(chunk_->size() - 1);
        return s;
    }
    std::array<Slot, 2> pair(uint32_t /*live*/) {
        const Slot a = next();
        return {a, next()};
    }
    static uint32_t number(Slot s) { return s.number; }
    static Node& at(Slot s) { return *s.node; }

    // Where the block starts (after root()), and how many nodes it has.
    uint32_t first_chunk() const { return first_chunk_; }
    uint32_t first() const { return first_; }
    uint32_t size() const { return count_; }

private:
    Slot next() {
        if (chunk_->size() == chunk_->capacity()) chunk_ = &arena_.new_chunk();
        return {&chunk_->emplace_back(), count_++};
    }
    PlacementArena& arena_;
    NodeChunk* chunk_;
    uint32_t first_chunk_ = 0, first_ = 0, count_ = 0;
};

}  // namespace canopy
