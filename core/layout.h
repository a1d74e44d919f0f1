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

namespace canopy {

struct NodeRecord {
    Box box;
    uint32_t begin;
    uint32_t count;  // 0: inner node; otherwise the leaf's primitive count
    uint32_t parent_begin;
    uint8_t depth;
    uint8_t rights;
    uint8_t is_right;
    uint8_t pad = 0;

    static NodeRecord of(const NodeTask& t, bool leaf) {
        return {t.bounds, t.begin, leaf ? t.size() : 0u, t.parent_begin,
                static_cast<uint8_t>(t.depth), t.rights, static_cast<uint8_t>(t.is_right)};
    }
};
static_assert(sizeof(NodeRecord) == 40);

// Rank queries over a bitmap with one bit per permutation slot, set where a
// leaf begins.
class LeafRank {
public:
    explicit LeafRank(uint32_t n) : words_((size_t(n) + 63) / 64 + 1), prefix_(words_.size() + 1) {}

    // Thread-safe: several workers may mark leaves at once.
    void mark(uint32_t begin) {
        std::atomic_ref<uint64_t>(words_[begin / 64]).fetch_or(uint64_t(1) << (begin % 64),
                                                               std::memory_order_relaxed);
    }
    void finish() {
        prefix_[0] = 0;
        for (size_t i = 0; i < words_.size(); ++i)
            prefix_[i + 1] = prefix_[i] + static_cast<uint32_t>(std::popcount(words_[i]));
    }
    // Number of leaves starting strictly before `pos`.
    uint32_t rank(uint32_t pos) const {
        const uint64_t below = (uint64_t(1) << (pos % 64)) - 1;
        return prefix_[pos / 64] + static_cast<uint32_t>(std::popcount(words_[pos / 64] & below));
    }

private:
    std::vector<uint64_t> words_;
    std::vector<uint32_t> prefix_;
};

inline uint32_t first_child_slot(uint32_t depth, uint32_t leaves_before, uint32_t rights) {
    return 1 + 2 * (depth + leaves_before - rights);
}

// The canonical index of the node a record describes. `rank.rank(pos)`: the
// number of leaves starting before pos.
template <class Rank>
uint32_t canonical_slot(const NodeRecord& r, const Rank& rank) {
    if (r.depth == 0) return 0;
    const uint32_t pbegin = r.is_right ? r.parent_begin : r.begin;
    const uint32_t prights = r.rights - r.is_right;
    return first_child_slot(r.depth - 1u, rank.rank(pbegin), prights) + r.is_right;
}

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

// A subtree one worker built inline (see the top of this file). Its nodes
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

// L(v) from the pieces that tile the permutation (leaf records and blocks):
// sorted by where they begin, with a prefix sum of their leaves. A node's
// range is a union of whole pieces, so the leaves before it are those of
// the pieces that begin before it. Pieces are few (one per task), not one
// per leaf.
class PieceRank {
public:
    void add(uint32_t begin, uint32_t leaves) { pieces_.push_back({begin, leaves}); }
    void finish() {
        std::sort(pieces_.begin(), pieces_.end(), [](const Piece& a, const Piece& b) { return a.begin < b.begin; });
        begins_.resize(pieces_.size());
        prefix_.resize(pieces_.size() + 1);
        prefix_[0] = 0;
        for (size_t i = 0; i < pieces_.size(); ++i) {
            begins_[i] = pieces_[i].begin;
            prefix_[i + 1] = prefix_[i] + pieces_[i].leaves;
        }
    }
    uint32_t rank(uint32_t pos) const {
        return prefix_[size_t(std::lower_bound(begins_.begin(), begins_.end(), pos) - begins_.begin())];
    }

private:
    struct Piece {
        uint32_t begin, leaves;
    };
    std::vector<Piece> pieces_;
    std::vector<uint32_t> begins_, prefix_;
};

// dst[j] = src[j] for j < k, with `shift` added to the child index of every
// inner node (count 0). With AVX2 one 256-bit load and store per node.
inline void copy_shifted(const Node* src, size_t k, uint32_t shift, Node* dst) {
    size_t j = 0;
#if defined(__AVX2__)
    static_assert(offsetof(Node, index) == 24 && offsetof(Node, count) == 28);
    const __m256i add = _mm256_set_epi32(0, int(shift), 0, 0, 0, 0, 0, 0);
    const __m256i zero = _mm256_setzero_si256();
    for (; j < k; ++j) {
        const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(src + j));
        // Lane 7 (count) == 0 gives all ones in lane 7; moved to lane 6 (index).
        const __m256i inner = _mm256_bsrli_epi128(_mm256_cmpeq_epi32(v, zero), 4);
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(dst + j), _mm256_add_epi32(v, _mm256_and_si256(inner, add)));
    }
#endif
    for (; j < k; ++j) {
        Node n = src[j];
        if (!n.is_leaf()) n.index += shift;
        dst[j] = n;
    }
}

// copy_shifted() for ranges that may overlap: a block whose nodes lie over
// its records moves to slots before or after them (place_over_records()).
// Going up, the nodes are taken from the last one down, so that each is
// read before a store can reach it.
inline void move_shifted(const Node* src, size_t k, uint32_t shift, Node* dst) {
    if (!(dst > src && dst < src + k)) return copy_shifted(src, k, shift, dst);
    for (size_t j = k; j-- > 0;) {
        Node n = src[j];
        if (!n.is_leaf()) n.index += shift;
        dst[j] = n;
    }
}

// Copies `count` nodes of an arena's chunks, from chunks[chunk][first] on
// and at the start of each following chunk (as a block fills them), to dst,
// adding `shift` to inner nodes' child indices.
inline void copy_from_chunks(const PlacementArena& a, uint32_t chunk, uint32_t first, size_t count, uint32_t shift,
                             Node* dst) {
    uint32_t k = chunk;
    const Node* src = a.chunks[k].data() + first;
    size_t left_here = a.chunks[k].size() - first;
    while (count > 0) {
        if (left_here == 0) {
            ++k;
            src = a.chunks[k].data();
            left_here = a.chunks[k].size();
        }
        const size_t take = std::min(left_here, count);
        copy_shifted(src, take, shift, dst);
        src += take;
        dst += take;
        left_here -= take;
        count -= take;
    }
}

// Writes the node a record describes (a task node, or a block's root) into
// its canonical slot.
template <class Rank>
void place_record(const NodeRecord& r, const Rank& rank, Node* nodes) {
    Node& n = nodes[canonical_slot(r, rank)];
    n.set_box(r.box);
    if (r.count) {
        n.index = r.begin;
        n.count = r.count;
    } else {
        n.index = first_child_slot(r.depth, rank.rank(r.begin), r.rights);
        n.count = 0;
    }
}

// The canonical slot of an inner block root's first child: block node i >= 1
// goes to it + i - 1, and an inner node's relative child index j becomes
// it + j - 1.
template <class Rank>
uint32_t block_first_child(const SubtreeBlock& b, const Rank& rank) {
    return first_child_slot(b.root.depth, rank.rank(b.root.begin), b.root.rights);
}

// Copies the nodes after a block's root (block nodes 1 to size - 1) to `dst`,
// its first child's canonical slot `c`, from wherever the arena keeps them
// (`refs`: the records, over which an over_records arena wrote them).
inline void place_block_body(const PlacementArena& a, const SubtreeBlock& b, const PrimRef* refs, uint32_t c,
                             Node* dst) {
    size_t body = b.size - 1;
    if (a.over_records) {
        move_shifted(reinterpret_cast<const Node*>(refs + b.root.begin), b.over_records, c - 1, dst);
        dst += b.over_records;
        body -= b.over_records;
        if (b.in_area > 0) {
            copy_shifted(a.overflow->data() + b.area, b.in_area, c - 1, dst);
            dst += b.in_area;
            body -= b.in_area;
        }
        if (body > 0) copy_from_chunks(a, b.chunk, b.first, body, c - 1, dst);
    } else {
        // The root is the chunks' node (b.chunk, b.first); the body follows.
        copy_from_chunks(a, b.chunk, b.first + 1, body, c - 1, dst);
    }
}

// Writes one arena's records and blocks into their canonical slots of `nodes`.
template <class Rank>
void place_arena(const PlacementArena& arena, const Rank& rank, const PrimRef* refs, Node* nodes) {
    for (const NodeRecord& r : arena.records) place_record(r, rank, nodes);
    for (const SubtreeBlock& b : arena.blocks) {
        place_record(b.root, rank, nodes);
        if (b.size <= 1) continue;
        const uint32_t c = block_first_child(b, rank);
        place_block_body(arena, b, refs, c, nodes + c);
    }
}

// L(v) for every arena's pieces, and the number of nodes.
inline size_t rank_pieces(std::span<const PlacementArena* const> arenas, PieceRank& rank) {
    size_t total = 0;
    for (const PlacementArena* a : arenas) {
        total += a->node_count();
        for (const NodeRecord& r : a->records)
            if (r.count) rank.add(r.begin, 1);
        for (const SubtreeBlock& b : a->blocks) rank.add(b.root.begin, b.leaves);
    }
    rank.finish();
    return total;
}

// Places all arenas into `nodes`, a fresh array. `for_each(k, fn)` runs fn(i)
// for i in [0, k), possibly in parallel; the result does not depend on how.
// `refs`: the records, for over_records arenas.
template <class ForEach>
void place_nodes(std::span<const PlacementArena* const> arenas, const PrimRef* refs, NodeArray& nodes,
                 ForEach&& for_each) {
    PieceRank rank;
    const size_t total = rank_pieces(arenas, rank);
    nodes.clear();
    nodes.reserve(total);
    nodes.resize(total);
    for_each(arenas.size(), [&](size_t i) { place_arena(*arenas[i], rank, refs, nodes.data()); });
}

// A block of an in-place placement: its arena, and its first child's
// canonical slot.
struct BlockMove {
    const PlacementArena* arena;
    const SubtreeBlock* block;
    uint32_t c;
};

// Moves the blocks' bodies (sorted by range, each to slots at or before its
// records: see place_over_records()) to their slots of `out`, split into
// `groups` runs of consecutive blocks with about equal numbers of nodes,
// run by for_each, in any order or at once. In order within a run, no block
// overwrites another's nodes before they have moved (see below); across
// runs, a block whose slots start before its run's first records may
// overwrite the records of an earlier run's blocks, which may not have
// moved yet: each run first copies such blocks (a prefix of it, since slots
// and records both grow along the run) into a buffer of its own, then
// moves the rest in order, and every buffer goes to its slots once all
// runs are done. A run's own moves stay below its next run's first slot,
// and so below that run's records. The buffers hold about the gap between
// the slots and the records at each run's start: at most the storage's
// slack (a tenth of a node per record).
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

// The step in which place_beside_records() gives back the pages it has
// consumed (of the records' storage and the overflow area): one system call
// per 256 KiB consumed. The new array's pages are counted in units of 2 MiB,
// a huge page, which a first write brings in whole.
inline constexpr size_t kDiscardUnit = size_t(256) << 10;
inline constexpr size_t kTouchUnit = size_t(2) << 20;
inline constexpr size_t kHugeMin = size_t(56) << 20;
inline constexpr size_t kRunsMin = size_t(192) << 20;

// place_beside_records()'s thresholds (tests lower them to reach its paths
// with small trees).
struct BesideRecordsSizes {
    size_t huge_min = kHugeMin;  // the new array on huge pages from here (and pages moved to it)
    size_t runs_min = kRunsMin;  // moving pages, the copies split into runs from here
};

// Places a tree that does not fit over its records (place_over_records())
// into a new array of `total` nodes beside the records' storage `nodes`,
// without holding both whole: the blocks are copied in the order of their
// ranges, split into one run per worker (cut as move_blocks() cuts them,
// but into memory of their own, so that the runs never wait for each
// other), and each run gives back to the system the pages of the records'
// storage and of the overflow area (which holds each block's nodes at its
// range too) below the next block's range, as it goes, while the new
// array's pages are counted as they are first written (PageLedger). With
// 1.86 nodes per record the new array grows by about as many bytes as the
// storage and the overflow area give back, so the peak stays near that of
// the end of the build (the storage and the overflow area). Returns the
// new array (the caller swaps it in). `area`: the arenas' overflow area.
template <class ForEach>
NodeArray place_beside_records(std::span<const BlockMove> moves, const PrimRef* refs, OverflowArea& area,
                               NodeArray& nodes, size_t total, size_t groups, ForEach&& for_each,
                               BesideRecordsSizes sizes = {}) {
    // On huge pages from kHugeMin bytes (counted 2 MiB at a time as first
    // written); smaller arrays, for which the 2 MiB a run may have counted
    // ahead of its writes would be a sizeable part, fault in 4 KiB pages
    // (and count them), about five times as slow per byte (a 64 MiB mapping
    // touched in 12.4 ms against 2.6, 2026-12-05). Also on huge pages when
    // the overflow area has huge pages (OverflowArea::any_huge(): random
    // triangles' trees from 983,040 records) and the storage is a mapping,
    // so that the area's huge pages move whole into the new array instead of
    // being held until every 4 KiB of them is consumed.
    const bool huge = total * sizeof(Node) >= sizes.huge_min || (area.any_huge() && nodes.mapped());
    NodeArray out(NodeArray::Uncounted{huge}, total);
    PageLedger touched(out.capacity() * sizeof(Node), huge ? kTouchUnit : 4096, out.mapped());
    // Steps of kDiscardUnit, smaller for small trees (each run may hold up
    // to a step of the storage and of the area that it has consumed).
    const size_t step = std::clamp<size_t>(total / 128, 4096 / sizeof(PrimRef), kDiscardUnit / sizeof(PrimRef));
    // With the new array on huge pages and the storage a mapping (on huge
    // pages too), the storage's consumed huge pages go to the new array
    // (NodeArray::give_pages(): page tables move, nothing is zeroed), and so
    // do the overflow area's consumed 2 MiB (4 KiB pages), before the run
    // writes there: about as many bytes as the new array needs (1.86 nodes
    // per record: 1 from the storage, 0.86 from the area). The storage goes
    // in whole huge pages and the area in whole 2 MiB, each run keeping the
    // last of each for the next huge page it writes; a run takes only huge
    // pages wholly inside its own slots, before it writes them, so no other
    // run writes there. Measured on an AMD EPYC host (2026-12-05): giving
    // back part of a huge page splits it, and a fresh huge page is zeroed
    // by the kernel (which at times must compact memory to find one): the
    // placement of 1M random triangles took 11.3 to 12.8 ms that way
    // against 4.4 to 5.5 (traced 2-thread tbb builds), and alternated builds
    // of 4M random triangles 1.07 times as long as before the new array
    // (0.996 with the pages moved). The area's 2 MiB come with its blocks'
    // unused range ends never brought in, which the run would fault in 4
    // KiB at a time: populated by one system call as they move (on the host
    // of 2026-12-06, where a 4 KiB fault took about 10 us, the placement of
    // 1M random triangles took 12.5 ms against 14.1, and of 4M 38.9 against
    // 43.6; giving the area's pages back instead of moving them took 8.2 and
    // 125: fresh huge pages are slow to come from the host when it has
    // taken back the memory, as for the 4M scene; medians of 7 and 3 traced
    // 2-thread tbb builds, alternated). A dense area's huge pages
    // (core/overflow_area.h) move as one page table entry each. A run then
    // holds up to about 6 MiB it has consumed or not yet written, so below
    // kRunsMin bytes of new array the copies run as one.
    const bool recycle = huge && out.mapped() && nodes.mapped();
    const std::uintptr_t storage_unit = recycle ? (std::uintptr_t(2) << 20) - 1 : std::uintptr_t(4095);
    groups = std::clamp<size_t>(recycle && total * sizeof(Node) < sizes.runs_min ? 1 : groups, 1,
                                std::max<size_t>(moves.size(), 1));
    const std::vector<size_t> first = cut_runs(moves, groups);
    constexpr size_t kHuge = size_t(2) << 20;
    for_each(groups, [&](size_t r) {
        if (first[r] == first[r + 1]) return;
        // This run's records are given back in steps, from the first page
        // (or huge page) boundary in them to the last below what is
        // consumed (the pages it shares with its neighbours go with the
        // storage and the area).
        constexpr size_t kPageNodes = 4096 / sizeof(Node);
        const size_t start = r == 0 ? 0 : moves[first[r]].block->root.begin;
        std::uintptr_t storage_done = (reinterpret_cast<std::uintptr_t>(refs + start) + storage_unit) & ~storage_unit;
        // The first run's records up to that boundary share their huge page
        // with the storage's front, given back before (so the page is split
        // already): given back too as soon as they are consumed, rather than
        // with the storage at the end, since the placement's peak comes
        // while it writes its first new huge pages.
        const std::uintptr_t head_end = r == 0 ? storage_done : 0;
        // The area's slots of records [0, x) end at area.slot(x).
        size_t area_done = (area.slot(start) + kPageNodes - 1) / kPageNodes * kPageNodes, released = start;
        // The run's slots, and its consumed huge pages of the storage not
        // yet handed on or given back (at most one kept).
        const size_t slots_from = size_t(moves[first[r]].c) * sizeof(Node);
        const size_t slots_to = (size_t(moves[first[r + 1] - 1].c) + moves[first[r + 1] - 1].block->size - 1) * sizeof(Node);
        std::uintptr_t spare = 0;
        // Likewise a consumed 2 MiB of the overflow area (4 KiB pages, moved
        // as they are), its first node.
        constexpr size_t kNone = ~size_t(0), kHugeNodes = kHuge / sizeof(Node);
        size_t area_spare = kNone;
        char* const base = reinterpret_cast<char*>(out.data());
        for (size_t k = first[r]; k < first[r + 1]; ++k) {
            const BlockMove& m = moves[k];
            const SubtreeBlock& b = *m.block;
            const size_t from = size_t(m.c) * sizeof(Node), to = (size_t(m.c) + b.size - 1) * sizeof(Node);
            if (recycle && (spare || area_spare != kNone)) {
                for (size_t u = from / kHuge * kHuge; u < to && (spare || area_spare != kNone); u += kHuge) {
                    if (u < slots_from || u + kHuge > slots_to || !touched.untouched(u)) continue;
                    // Counted there by touch() below, as given back here.
                    if (spare) {
                        if (nodes.give_pages(reinterpret_cast<const void*>(spare), base + u, kHuge)) spare = 0;
                    } else {
                        // The area's unused range ends were never brought
                        // in: brought in now, by one system call, rather
                        // than by a fault per 4 KiB page as the run writes.
                        if (area.give(area_spare, base + u, kHuge)) populate_pages(base + u, kHuge);
                        area_spare = kNone;
                    }
                }
            }
            touched.touch(from, to);
            place_block_body(*m.arena, b, refs, m.c, out.data() + m.c);
            // Every record before the next block's is consumed.
            const size_t consumed = k + 1 < moves.size() ? moves[k + 1].block->root.begin
                                                         : size_t(b.root.begin) + b.over_records;
            // Every `step` records, and as soon as a whole 2 MiB of the area
            // or of the storage is consumed, to be handed on to the next new
            // huge page before the run touches it fresh.
            const bool whole_unit = recycle && (area.slot(consumed) / kHugeNodes > area.slot(released) / kHugeNodes ||
                                                (reinterpret_cast<std::uintptr_t>(refs + consumed) & ~storage_unit) >=
                                                    storage_done + kHuge);
            if (consumed >= released + step || whole_unit || k + 1 == first[r + 1]) {
                const std::uintptr_t head = reinterpret_cast<std::uintptr_t>(refs) & ~std::uintptr_t(4095);
                if (head_end > head && released < size_t(head_end - reinterpret_cast<std::uintptr_t>(refs)) / sizeof(PrimRef) &&
                    consumed >= size_t(head_end - reinterpret_cast<std::uintptr_t>(refs)) / sizeof(PrimRef))
                    nodes.discard(reinterpret_cast<const void*>(head), reinterpret_cast<const void*>(head_end));
                std::uintptr_t storage_to = reinterpret_cast<std::uintptr_t>(refs + consumed) & ~storage_unit;
                if (recycle && storage_to > storage_done) {
                    // Keeps the last whole huge page for the next one the run writes.
                    if (spare) nodes.discard(reinterpret_cast<const void*>(spare), reinterpret_cast<const void*>(spare + kHuge));
                    spare = storage_to - kHuge;
                    storage_to = spare;
                }
                if (storage_to > storage_done)
                    nodes.discard(reinterpret_cast<const void*>(storage_done), reinterpret_cast<const void*>(storage_to));
                storage_done = std::max(storage_done, recycle && spare ? spare + kHuge : storage_to);
                // Recycling, the area goes in whole 2 MiB, the last kept
                // for the next huge page the run writes.
                const size_t area_end = area.slot(consumed);
                const size_t area_to = recycle ? area_end / kHugeNodes * kHugeNodes : area_end / kPageNodes * kPageNodes;
                if (recycle && area_to >= area_done + kHugeNodes) {
                    if (area_spare != kNone) area.release(area_spare, area_spare + kHugeNodes);
                    area_spare = area_to - kHugeNodes;
                    area.release(area_done, area_spare);
                } else if (area_to > area_done) {
                    area.release(area_done, area_to);
                }
                area_done = std::max(area_done, area_to);
                released = consumed;
            }
        }
        if (spare) nodes.discard(reinterpret_cast<const void*>(spare), reinterpret_cast<const void*>(spare + kHuge));
        if (area_spare != kNone) area.release(area_spare, area_spare + kHugeNodes);
    });
    touched.count_untouched();
    return out;
}

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
