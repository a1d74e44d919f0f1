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

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <immintrin.h>
#include <span>
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

// A subtree one worker built inline (see the top of this file).
struct SubtreeBlock {
    NodeRecord root;      // where the subtree's root sits in the tree
    uint32_t chunk = 0;   // its nodes: the arena's chunks[chunk] from `first` on, then the
                          // following chunks from their start (it filled each but its last)
    uint32_t first = 0;
    uint32_t size = 0;
    uint32_t leaves = 0;
};

// A chunk of a worker's nodes: from 2 MiB on, 2 MiB-aligned memory, so
// that a chunk of whole huge pages faults only in huge pages (see
// allocate_huge() and Workers::reset(), which sizes the chunks).
using NodeChunk = std::vector<Node, HugePageAllocator<Node>>;

// What one worker leaves for the placement.
//
// A worker's subtree blocks go one after another into chunks of nodes, and
// a block that fills a chunk goes on in a new one (ChunkedNodes below), so
// every chunk but the last ends full, and trim() gives back the last one's
// unused end before the placement. (Until late on 2026-12-02 a block needed
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
    // Gives back the unused end of the last chunk (a copy into an array of
    // the exact size), once no block will be added.
    void trim() {
        if (chunks.empty() || chunks.back().capacity() == chunks.back().size()) return;
        NodeChunk exact;
        exact.reserve(chunks.back().size());
        exact.insert(exact.end(), chunks.back().begin(), chunks.back().end());
        chunks.back().swap(exact);
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
        for (const auto& c : chunks) n += c.size();
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

// Writes one arena's records and blocks into their canonical slots of `nodes`.
template <class Rank>
void place_arena(const PlacementArena& arena, const Rank& rank, Node* nodes) {
    for (const NodeRecord& r : arena.records) {
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
    for (const SubtreeBlock& b : arena.blocks) {
        // The block's nodes: chunk b.chunk from b.first on, then the next
        // chunks from their start, as many as it filled.
        uint32_t k = b.chunk;
        const Node* src = arena.chunks[k].data() + b.first;
        size_t left_here = arena.chunks[k].size() - b.first;
        // Block node i >= 1 goes to c + i - 1, c the root's first child slot;
        // an inner node's relative child index j becomes c + j - 1.
        const uint32_t c = src[0].is_leaf() ? 0 : first_child_slot(b.root.depth, rank.rank(b.root.begin), b.root.rights);
        Node root = src[0];
        if (!root.is_leaf()) root.index = c + root.index - 1;
        nodes[canonical_slot(b.root, rank)] = root;
        Node* dst = nodes + c;
        ++src;
        --left_here;
        for (uint32_t i = 1; i < b.size;) {
            if (left_here == 0) {
                ++k;
                src = arena.chunks[k].data();
                left_here = arena.chunks[k].size();
            }
            const size_t take = std::min<size_t>(left_here, b.size - i);
            copy_shifted(src, take, c - 1, dst);
            src += take;
            dst += take;
            left_here -= take;
            i += static_cast<uint32_t>(take);
        }
    }
}

// Places all arenas into `nodes`. `for_each(k, fn)` runs fn(i) for i in
// [0, k), possibly in parallel; the result does not depend on how.
template <class ForEach>
void place_nodes(std::span<const PlacementArena* const> arenas, std::vector<Node>& nodes, ForEach&& for_each) {
    size_t total = 0;
    PieceRank rank;
    for (const PlacementArena* a : arenas) {
        total += a->node_count();
        for (const NodeRecord& r : a->records)
            if (r.count) rank.add(r.begin, 1);
        for (const SubtreeBlock& b : a->blocks) rank.add(b.root.begin, b.leaves);
    }
    rank.finish();
    nodes.clear();
    reserve_on_huge_pages(nodes, total);
    nodes.resize(total);
    for_each(arenas.size(), [&](size_t i) { place_arena(*arenas[i], rank, nodes.data()); });
}

}  // namespace canopy
