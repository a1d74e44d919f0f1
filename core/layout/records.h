// canopy: the arithmetic of the canonical layout: the record a worker keeps
// of a node it ran as a task, and the slot the record's node goes to (the
// formula at the top of core/layout.h), from the leaves that begin before it.
#pragma once

#include "../bvh.h"
#include "../kernel.h"

#include <atomic>
#include <bit>
#include <cstdint>
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

}  // namespace canopy
