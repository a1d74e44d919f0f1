// canopy: placing nodes in the canonical layout by arithmetic.
//
// Parallel schedulers create nodes in whatever order their workers happen to
// run; none of that order may reach the output. Each worker appends a
// NodeRecord per node to its own arena, and place_records() computes every
// node's canonical position from facts that do not depend on timing:
//
//   c(v) = 1 + 2 * (depth(v) + L(v) - rights(v))
//
// is the position of the first child of inner node v, where L(v) is the
// number of leaves whose range starts before v's range (leaves tile the
// permutation), and rights(v) the number of right turns from the root to v.
// (In depth-first pre-order, the child pairs allocated before v's are those
// of v's ancestors and of the inner nodes of the subtrees left of v's path;
// those subtrees hold L(v) leaves and rights(v) roots, hence L - rights
// inner nodes.) A left child sits at c(parent), a right child at
// c(parent) + 1, where the parent's begin, depth and rights follow from the
// child's record.
#pragma once

#include "bvh.h"
#include "kernel.h"
#include "memory.h"

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

// The canonical index of the node a record describes.
inline uint32_t canonical_slot(const NodeRecord& r, const LeafRank& rank) {
    if (r.depth == 0) return 0;
    const uint32_t pbegin = r.is_right ? r.parent_begin : r.begin;
    const uint32_t prights = r.rights - r.is_right;
    return first_child_slot(r.depth - 1u, rank.rank(pbegin), prights) + r.is_right;
}

// Writes one arena's records into their canonical slots of `nodes`.
inline void place_arena(std::span<const NodeRecord> arena, const LeafRank& rank, Node* nodes) {
    for (const NodeRecord& r : arena) {
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
}

// Places all arenas. `for_each(k, fn)` runs fn(i) for i in [0, k), possibly
// in parallel; the result does not depend on how.
template <class ForEach>
void place_records(std::span<const std::vector<NodeRecord>> arenas, uint32_t primitive_count,
                   std::vector<Node>& nodes, ForEach&& for_each) {
    size_t total = 0;
    for (const auto& a : arenas) total += a.size();
    nodes.clear();
    nodes.reserve(total);
    advise_huge_pages(nodes.data(), total * sizeof(Node));
    nodes.resize(total);
    LeafRank rank(primitive_count);
    for_each(arenas.size(), [&](size_t i) {
        for (const NodeRecord& r : arenas[i])
            if (r.count) rank.mark(r.begin);
    });
    rank.finish();
    for_each(arenas.size(), [&](size_t i) { place_arena(arenas[i], rank, nodes.data()); });
}

}  // namespace canopy
