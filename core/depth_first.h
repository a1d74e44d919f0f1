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
#include <cstddef>
#include <cstdint>
#include <vector>

namespace canopy {

// Where build_depth_first puts a subtree's nodes. `Slot` names one node;
// root() takes the first slot and pair() the next two (a pair's two slots
// follow each other in the subtree's numbering, which starts at 0 with the
// root), number(slot) is a slot's number and at(slot) its node. Slots stay
// valid while the subtree grows.

// The sequential driver's node array: one vector that grows by doubling, so
// a slot is an index (relative to where the subtree starts).
struct GrowingNodes {
    std::vector<Node>& v;
    size_t base;  // the subtree's first node
    using Slot = uint32_t;
    explicit GrowingNodes(std::vector<Node>& nodes) : v(nodes), base(nodes.size()) {}
    Slot root() {
        v.emplace_back();
        return 0;
    }
    std::array<Slot, 2> pair() {
        const Slot c = static_cast<Slot>(v.size() - base);
        if (v.capacity() - v.size() < 2) grow_on_huge_pages(v);
        v.emplace_back();
        v.emplace_back();
        return {c, c + 1};
    }
    static uint32_t number(Slot s) { return s; }
    Node& at(Slot s) { return v[base + s]; }
};

// Builds the subtree of `root` into `out` (see above): the root first, then
// each child pair as its parent splits, the left child processed before the
// right one (the canonical layout of the subtree by construction). Inner
// nodes' child indices are the first child's number in the subtree, so a
// whole tree built into an empty vector has absolute indices. Nodes above
// the task cutoff are traced on `track`. Returns the number of leaves.
template <class Out>
uint32_t build_depth_first(const KernelContext& ctx, const NodeTask& root, Out& out, BinSet& bins,
                           SkipCounts& skip, uint32_t track) {
    using Slot = typename Out::Slot;
    const uint32_t cutoff = ctx.options->tuning.task_cutoff;
    // Pending right children: one per level at most, and depth <= kMaxDepthCap.
    // A left child is processed straight from where run_node() wrote it (the
    // two `pair` buffers take turns, so the task being run is never the one
    // written), and only a right child is copied, once, onto the stack
    // (pushing and popping both children's 72-byte tasks made the cow's
    // sequential build run 0.7% more instructions).
    std::array<NodeTask, kMaxDepthCap + 2> stack;
    std::array<Slot, kMaxDepthCap + 2> stack_node;
    NodeTask pair[2][2];
    uint32_t top = 0, leaves = 0, turn = 0;
    const NodeTask* task = &root;
    Slot at = out.root();  // task's node
    for (;;) {
        NodeTask* children = pair[turn];
        bool split;
        {
            const TraceScope trace(task->size() < cutoff ? nullptr : ctx.trace, *task, track, TraceSpan::Task);
            split = run_node(ctx, *task, children, bins, skip);
        }
        if (split) {
            const std::array<Slot, 2> c = out.pair();  // may move a GrowingNodes array: at() after it
            Node& node = out.at(at);
            node.set_box(task->bounds);
            node.index = out.number(c[0]);
            node.count = 0;
            // `task` may be the stack's top slot, which this overwrites: it
            // is not read again.
            stack[top] = children[1];
            stack_node[top++] = c[1];
            task = &children[0];
            at = c[0];
            turn ^= 1;
            continue;
        }
        Node& node = out.at(at);
        node.set_box(task->bounds);
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

// The same into one growing array (the sequential driver's node array).
inline uint32_t build_depth_first(const KernelContext& ctx, const NodeTask& root, std::vector<Node>& nodes,
                                  BinSet& bins, SkipCounts& skip, uint32_t track) {
    GrowingNodes out(nodes);
    return build_depth_first(ctx, root, out, bins, skip, track);
}

}  // namespace canopy
