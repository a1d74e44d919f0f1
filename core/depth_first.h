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
    const size_t base = nodes.size();
    const uint32_t cutoff = ctx.options->tuning.task_cutoff;
    // Pending right children: one per level at most, and depth <= kMaxDepthCap.
    // A left child is processed straight from where run_node() wrote it (the
    // two `pair` buffers take turns, so the task being run is never the one
    // written), and only a right child is copied, once, onto the stack
    // (pushing and popping both children's 72-byte tasks made the cow's
    // sequential build run 0.7% more instructions).
    std::array<NodeTask, kMaxDepthCap + 2> stack;
    std::array<uint32_t, kMaxDepthCap + 2> stack_node;  // relative to base
    NodeTask pair[2][2];
    uint32_t top = 0, leaves = 0, turn = 0;
    const NodeTask* task = &root;
    uint32_t at = 0;  // task's node, relative to base
    nodes.emplace_back();
    for (;;) {
        NodeTask* children = pair[turn];
        bool split;
        {
            const TraceScope trace(task->size() < cutoff ? nullptr : ctx.trace, *task, track, TraceSpan::Task);
            split = run_node(ctx, *task, children, bins, skip);
        }
        Node& node = nodes[base + at];
        node.set_box(task->bounds);
        if (split) {
            const uint32_t c = static_cast<uint32_t>(nodes.size() - base);
            node.index = c;
            node.count = 0;
            if (nodes.capacity() - nodes.size() < 2) grow_on_huge_pages(nodes);  // `node` dangles from here
            nodes.emplace_back();
            nodes.emplace_back();
            // `task` may be the stack's top slot, which this overwrites: it
            // is not read again.
            stack[top] = children[1];
            stack_node[top++] = c + 1;
            task = &children[0];
            at = c;
            turn ^= 1;
            continue;
        }
        node.index = task->begin;
        node.count = task->size();
        ++leaves;
        if (top == 0) break;
        --top;
        task = &stack[top];
        at = stack_node[top];
    }
    return leaves;
}

}  // namespace canopy
