// canopy: build options.
#pragma once

#include <cstdint>

namespace canopy {

// Hard limits. Exceeding them is an OptionError / InputError, never a wrap.
inline constexpr uint32_t kMaxBins = 256;
inline constexpr uint32_t kMinBins = 2;
// Leaf sizes are stored in a uint32 field, but a leaf holds at most 255
// primitives (8 bits), as in most traversal kernels.
inline constexpr uint32_t kMaxLeafSize = 255;
// Primitive ids are uint32; one value is kept free so counts fit as well.
inline constexpr uint64_t kMaxPrimitives = 0xFFFFFFFEull;
inline constexpr uint32_t kMaxDepthCap = 255;
// The smallest nonzero BuildOptions::rotate_min (below it a rotation's
// bookkeeping costs more than it can gain).
inline constexpr uint32_t kRotateMinPrims = 256;

// Knobs of the parallel schedulers. They change speed, never the tree: the
// equivalence tests turn them down to drive every code path on small scenes.
struct SchedulerTuning {
    uint32_t prims_per_thread = 16384;   // fewer primitives per thread: use fewer threads
    uint32_t task_cutoff = 4096;         // smaller nodes run their subtree inline
    uint32_t parallel_node_min = 65536;  // smaller nodes never run team-parallel
    uint32_t chunk_nodes = 0;            // nodes per chunk of a worker's subtree blocks; 0: from the scene size
    uint32_t place_parallel_min = 32768; // smaller trees are moved into place on one thread
};

struct BuildOptions {
    // Bins per axis (2..256). Nodes with few primitives use fewer bins:
    // bins_for(n) = min(bins, max(4, bit_ceil(n) / 4)), and never fewer than 2.
    uint32_t bins = 32;  // chosen from `canopy sweep` on the shared meshes: see README, "Accuracy"
    // Largest leaf (1..255): a hard cap.
    uint32_t max_leaf = 4;
    // SAH costs of one traversal step and one primitive intersection.
    float traversal_cost = 1.0f;
    float intersection_cost = 1.0f;
    // Depth cap (root at depth 0). A branch switches to middle splits when
    // its remaining budget max_depth - depth is no more than
    // ceil(log2(primitive count)), so no leaf is deeper than max_depth.
    uint32_t max_depth = 64;
    // Nodes of at least this many primitives look at their children's
    // splits and take a local tree rotation where it lowers the SAH enough
    // (core/kernel/rotate.h); 0: none. At least kRotateMinPrims otherwise.
    uint32_t rotate_min = 65536;
    // Thread upper bound for parallel schedulers (0 = all hardware threads).
    uint32_t threads = 0;
    SchedulerTuning tuning;

    // Throws OptionError when a field is out of range.
    void check() const;
};

}  // namespace canopy
