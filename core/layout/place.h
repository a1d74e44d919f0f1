// canopy: placing the workers' arenas (core/layout/arena.h) into a fresh
// node array: each record's node to its slot, each block's body copied
// after its root's first child with its child indices shifted.
#pragma once

#include "arena.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <immintrin.h>
#include <span>
#include <vector>

namespace canopy {

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

}  // namespace canopy
