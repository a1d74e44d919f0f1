// canopy: tree quality and statistics.
#pragma once

#include "bvh.h"

#include <cstdint>
#include <vector>

namespace canopy {

// (sum over inner nodes of A(n) + sum over leaves of A(l) * |l|) / A(root),
// with A the half area, the root counted as an inner node, and traversal and
// intersection costs both 1 whatever the build used, so that the number
// compares across libraries. 0 for an empty tree; for a root of zero area
// the unnormalised sum is returned.
double sah_cost(const Bvh& bvh);

struct TreeStats {
    uint32_t nodes = 0;
    uint32_t leaves = 0;
    uint32_t depth = 0;  // deepest leaf, root at depth 0
    std::vector<uint32_t> leaf_size_histogram;  // [k] = leaves with k primitives
};

TreeStats tree_stats(const Bvh& bvh);

}  // namespace canopy
