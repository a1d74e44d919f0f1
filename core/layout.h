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
#include <atomic>
#include <bit>
#include <cstdint>
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
    uint32_t chunk = 0;   // its nodes: the arena's chunks[chunk][first, first + size)
    uint32_t first = 0;
    uint32_t size = 0;
    uint32_t leaves = 0;
};

// What one worker leaves for the placement.
struct PlacementArena {
    std::vector<NodeRecord> records;        // nodes run one at a time
    std::vector<std::vector<Node>> chunks;  // the blocks' nodes, block after block
    std::vector<SubtreeBlock> blocks;
    size_t chunk_nodes = size_t(1) << 17;   // usual chunk size (4 MiB)
    std::vector<std::vector<Node>> spare;   // emptied chunks of earlier builds

    // Node storage for a subtree of `primitives` primitives (at most
    // 2 * primitives - 1 nodes): the last chunk when it has room, else a new
    // one. Chunks never grow past their reserved size, so nodes are never
    // copied and a chunk wastes at most one block's worth.
    std::vector<Node>& chunk_for(uint32_t primitives) {
        const size_t need = 2 * size_t(primitives);
        if (chunks.empty() || chunks.back().capacity() - chunks.back().size() < need) {
            const size_t cap = std::max(chunk_nodes, need);
            if (!spare.empty() && spare.back().capacity() >= cap) {
                chunks.push_back(std::move(spare.back()));
                spare.pop_back();
            } else {
                reserve_on_huge_pages(chunks.emplace_back(), cap);
            }
        }
        return chunks.back();
    }
    // Empties the arena for another build; the chunks' memory is kept for
    // chunk_for() to reuse.
    void reset() {
        records.clear();
        blocks.clear();
        for (auto& c : chunks) {
            c.clear();
            spare.push_back(std::move(c));
        }
        chunks.clear();
        // Largest last, the one chunk_for() looks at.
        std::sort(spare.begin(), spare.end(),
                  [](const std::vector<Node>& a, const std::vector<Node>& b) { return a.capacity() < b.capacity(); });
    }
    size_t node_count() const {
        size_t n = records.size();
        for (const auto& c : chunks) n += c.size();
        return n;
    }
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
        const Node* src = arena.chunks[b.chunk].data() + b.first;
        // Block node i >= 1 goes to c + i - 1, c the root's first child slot;
        // an inner node's relative child index j becomes c + j - 1.
        const uint32_t c = src[0].is_leaf() ? 0 : first_child_slot(b.root.depth, rank.rank(b.root.begin), b.root.rights);
        Node root = src[0];
        if (!root.is_leaf()) root.index = c + root.index - 1;
        nodes[canonical_slot(b.root, rank)] = root;
        Node* dst = nodes + c - 1;
        for (uint32_t i = 1; i < b.size; ++i) {
            Node n = src[i];
            if (!n.is_leaf()) n.index = c + n.index - 1;
            dst[i] = n;
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
