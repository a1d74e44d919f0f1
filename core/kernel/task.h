// canopy: what a node task is (a range of the records and what its parent
// knew of it), the counters of work a build skipped, and how many bins a
// node of n primitives is binned into.
#pragma once

#include "../geometry.h"
#include "../options.h"

#include <algorithm>
#include <bit>
#include <cstdint>

namespace canopy {

// A node task: a range of the permutation and what its parent knew of it.
struct NodeTask {
    uint32_t begin = 0;
    uint32_t end = 0;
    Box bounds;   // union of the primitives' boxes
    Box cbounds;  // union of the primitives' centroids
    float max_area = 0.0f;  // the largest PrimRef::area in the range
    uint32_t depth = 0;
    // Where the node sits, for schedulers that place nodes by arithmetic
    // (see layout.h): the parent's begin, how many right turns lead here,
    // and whether this is a right child.
    uint32_t parent_begin = 0;
    uint8_t rights = 0;
    bool is_right = false;
    // The node's split was chosen before its task runs (by its parent, see
    // kernel/rotate.h) and waits in the build's CarriedSplits.
    bool carried = false;

    uint32_t size() const { return end - begin; }
};
static_assert(sizeof(NodeTask) == 72, "NodeTask is copied by every queue: keep it at 72 bytes");

// Counters of work skipped, summed over a build. Integers only, so the sums
// do not depend on the order workers add them.
struct SkipCounts {
    uint64_t axes_not_binned = 0;     // axes with (numerically) zero centroid extent
    uint64_t coincident_nodes = 0;    // all centroids equal: middle split / leaf, no evaluation
    uint64_t depth_cap_splits = 0;    // middle splits forced by the depth budget
    uint64_t single_leaves = 0;       // one-primitive nodes, no binning
    uint64_t inline_tasks = 0;        // node tasks run inline below the task cutoff
    uint64_t parallel_nodes = 0;      // nodes binned and partitioned by the whole team
    uint64_t bound_leaves = 0;        // leaves found by the SAH lower bound, not binned
    uint64_t size_splits = 0;         // not a skip: nodes split by primitive size (see SizeCuts)
    uint64_t exact_nodes = 0;         // nodes of at most kExactMaxPrims primitives costed exactly, not binned
    uint64_t sampled_axes = 0;        // big nodes binned on one axis, chosen from a sample (samples_axis())
    uint64_t rotations = 0;           // not a skip: nodes regrouped with a child's children (kernel/rotate.h)

    void add(const SkipCounts& o) {
        axes_not_binned += o.axes_not_binned;
        coincident_nodes += o.coincident_nodes;
        depth_cap_splits += o.depth_cap_splits;
        single_leaves += o.single_leaves;
        inline_tasks += o.inline_tasks;
        parallel_nodes += o.parallel_nodes;
        bound_leaves += o.bound_leaves;
        size_splits += o.size_splits;
        exact_nodes += o.exact_nodes;
        sampled_axes += o.sampled_axes;
        rotations += o.rotations;
    }
};

// Nodes of at least this many primitives are binned with twice the bins,
// and from kWidestBinsMin on with four times the bins.
inline constexpr uint32_t kWideBinsMin = 1u << 16;
inline constexpr uint32_t kWidestBinsMin = 1u << 19;

// Bins for a node of n primitives: min(bins, 4) up to 32 primitives, else
// min(bins, bit_ceil(n) / 4), and at least 2; from kWideBinsMin primitives
// up, min(256, 2 * bins); from kWidestBinsMin up, min(256, 4 * bins).
// Small nodes, which are most nodes, use fewer bins: clearing and sweeping
// bins is the fixed cost of a node (with bit_ceil(n) / 2, nodes of 5 to 64
// primitives took 43% of a 1M-sphere build at 600 to 3,700 cycles per node; a
// quarter keeps about 4 primitives per bin). Nodes of 17 to 32 primitives
// had 8 bins until 2026-12-05, when 4-bin nodes came to be binned in
// registers (bin_evaluate_4()): with 4 they took the sequential builds
// 0.978x-0.986x as long (1M sphere, stadium, random; dragon_vrip_res2;
// alternated, 7 rounds) for SAH +0.00% to +0.3% (1M random 383.15 ->
// 384.26, dragon_vrip_res2 43.344 -> 43.423; every mesh of ../shared/scenes
// within 0.9% of the exact sweep, all scenes below Embree's rtcBuildBVH
// but the 1M stadium, as before). 8 bins for 33 to 64 as well (0.968x)
// put Sibenik 2.6% above the exact sweep: not taken. The few huge nodes
// near the root use more: their cost is the pass over their records, not
// the bins, and they are where an object far smaller than the node must not
// be cut by a bin boundary (the 1M stadium's dense sphere sat across the
// middle boundary of the root's 32 bins: SAH 35.19, with 64 there 32.68).
// The 4M stadium needed more in its nodes of one to four million records:
// SAH 39.40 with 64 bins there, 36.76 with 128 (Embree's rtcBuildBVH:
// 37.15).
inline uint32_t bins_for(uint32_t n, uint32_t bins) {
    if (n >= kWidestBinsMin) return std::min(kMaxBins, 4 * bins);
    if (n >= kWideBinsMin) return std::min(kMaxBins, 2 * bins);
    const uint32_t quarter = n <= 32 ? 4 : std::bit_floor(n - 1) / 2;  // bit_ceil(n) / 4 without overflow
    return std::max(kMinBins, std::min(bins, std::max(4u, quarter)));
}

}  // namespace canopy
