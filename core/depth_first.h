// canopy: one subtree built depth first on one thread, in the sequential
// layout. The sequential driver builds the whole tree this way; the parallel
// drivers build every subtree below their task cutoff this way too, as a
// block that the final placement moves into the canonical layout by one
// offset (core/layout.h).
#pragma once

#include "bvh.h"
#include "kernel.h"
#include "memory.h"
#include "options.h"
#include "trace.h"

#include <array>
#include <cstdint>
#include <vector>

namespace canopy {

// Builds the subtree of `root`, appending its nodes to `nodes`: the root
// first, then each child pair as its parent splits, the left child processed
// before the right one (the canonical layout of the subtree by
// construction). Inner nodes' child indices are relative to where the
// subtree starts (nodes.size() on entry), so a whole tree built from an
// empty vector has absolute indices. Nodes above the task cutoff are traced
// on `track`. Returns the number of leaves.
inline uint32_t build_depth_first(const KernelContext& ctx, const NodeTask& root, std::vector<Node>& nodes,
                                  BinSet& bins, SkipCounts& skip, uint32_t track) {
    struct Item {
        NodeTask task;
        uint32_t node;  // relative to base
    };
    const size_t base = nodes.size();
    const uint32_t cutoff = ctx.options->tuning.task_cutoff;
    // One pending right child per level at most, and depth <= kMaxDepthCap.
    std::array<Item, kMaxDepthCap + 2> stack;
    uint32_t top = 0, leaves = 0;
    stack[top++] = {root, 0};
    nodes.emplace_back();
    NodeTask children[2];
    while (top) {
        const Item it = stack[--top];
        const TraceScope trace(it.task.size() < cutoff ? nullptr : ctx.trace, it.task, track, TraceSpan::Task);
        const bool split = run_node(ctx, it.task, children, bins, skip);
        Node& node = nodes[base + it.node];
        node.set_box(it.task.bounds);
        if (!split) {
            node.index = it.task.begin;
            node.count = it.task.size();
            ++leaves;
            continue;
        }
        const uint32_t c = static_cast<uint32_t>(nodes.size() - base);
        node.index = c;
        node.count = 0;
        if (nodes.capacity() - nodes.size() < 2) grow_on_huge_pages(nodes);  // `node` dangles from here
        nodes.emplace_back();
        nodes.emplace_back();
        stack[top++] = {children[1], c + 1};
        stack[top++] = {children[0], c};
    }
    return leaves;
}

}  // namespace canopy
