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

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace canopy {

// Where build_depth_first puts a subtree's nodes. `Slot` names one node;
// root() takes the first slot and pair() the next two (a pair's two slots
// follow each other in the subtree's numbering, which starts at 0 with the
// root), number(slot) is a slot's number and at(slot) its node. Slots stay
// valid while the subtree grows.

// One node array that grows by doubling (a warm build's tree, a worker's
// scratch array), so a slot is an index (relative to where the subtree
// starts).
struct GrowingNodes {
    NodeArray& v;
    size_t base;  // the subtree's first node
    using Slot = uint32_t;
    explicit GrowingNodes(NodeArray& nodes) : v(nodes), base(nodes.size()) {}
    Slot root() {
        v.emplace_back();
        return 0;
    }
    std::array<Slot, 2> pair(uint32_t /*live*/) {
        const Slot c = static_cast<Slot>(v.size() - base);
        v.emplace_back();
        v.emplace_back();
        return {c, c + 1};
    }
    static uint32_t number(Slot s) { return s; }
    Node& at(Slot s) { return v[base + s]; }
};

// The sequential driver's node array when the records live at the end of
// its storage (BuildState::allocate_records_after_nodes()): the whole tree,
// appended from the front. A depth-first build consumes the records from the
// left (when a node runs, every record before its range belongs to a finished
// subtree: dead), and a tree of leaves of two or more primitives has about
// one node per record, so the nodes stay behind the live records: record r
// sits at node slot limit + r (in 32-byte units, rounded down), and a pair
// may take slots below limit + live, `live` being the running node's first
// record. Where a tree has more nodes than that (small leaves), grow() moves
// the nodes and the live records into bigger storage. One array of about 1.1
// nodes per primitive instead of a records array (32 bytes a primitive) and a
// node array (35.2); and past the storage's first tenth the nodes are
// written over memory the records had brought in (prepare touched it), not
// into fresh memory, which on this project's virtual machine was at times
// very slow to fault in (README, the memory paragraph).
class NodesBeforeRecords {
public:
    using Slot = uint32_t;
    // `ctx.refs` is the records' address; grow() moves them and updates it.
    NodesBeforeRecords(NodeArray& nodes, KernelContext& ctx, uint32_t n)
        : v_(nodes), ctx_(ctx), n_(n), limit_(limit_of(nodes, ctx.refs)) {}

    Slot root() {
        v_.emplace_back();
        return 0;
    }
    std::array<Slot, 2> pair(uint32_t live) {
        const Slot c = static_cast<Slot>(v_.size());
        if (size_t(c) + 2 > limit_ + live) grow(live);
        v_.emplace_back();
        v_.emplace_back();
        return {c, c + 1};
    }
    static uint32_t number(Slot s) { return s; }
    Node& at(Slot s) { return v_[s]; }

    // Where n records end at the end of `capacity` nodes of storage at
    // `base`: 32-byte aligned (the storage is only 16-byte aligned).
    static PrimRef* records_at_end(Node* base, size_t capacity, uint32_t n) {
        static_assert(sizeof(Node) == sizeof(PrimRef) && alignof(PrimRef) == 32);
        const auto end = reinterpret_cast<std::uintptr_t>(base + capacity);
        return reinterpret_cast<PrimRef*>((end - size_t(n) * sizeof(PrimRef)) & ~std::uintptr_t(31));
    }
    // Nodes to reserve for a tree of n primitives: 1.1 per primitive (the
    // meshes' trees have 0.97 to 1.09), one for the alignment, and room for
    // the slots a few levels ahead of the records near the start.
    static size_t initial_capacity(uint32_t n) { return size_t(n) + n / 10 + 65; }

private:
    // The first node slot record 0 overlaps.
    static size_t limit_of(const NodeArray& v, const PrimRef* refs) {
        return size_t(reinterpret_cast<const char*>(refs) - reinterpret_cast<const char*>(v.data())) / sizeof(Node);
    }
    // Storage for the nodes so far, the live records [live, n) and the nodes
    // still to come, estimated from the nodes per record so far (the random
    // scenes' 1.86), with at least a quarter more room than before.
    [[gnu::noinline]] void grow(uint32_t live) {
        const size_t done = v_.size() + 2, rest = n_ - live;
        const double per_record = double(done) / double(std::max<uint32_t>(live, 1));
        const size_t estimate = done + size_t(per_record * double(rest));
        const size_t capacity = std::max({estimate + estimate / 16 + 65, v_.capacity() + v_.capacity() / 4,
                                          done + rest + 65});
        // expand() keeps the whole storage, records included (moved with it
        // when it moves); the live records then go to the bigger storage's
        // end, up, as a memmove (the two places may overlap). A mapping
        // (from NodeArray::kMapMin bytes) grows without a second copy.
        const PrimRef* const old = v_.expand(capacity, ctx_.refs);
        PrimRef* const refs = records_at_end(v_.data(), v_.capacity(), n_);
        std::memmove(static_cast<void*>(refs + live), old + live, size_t(n_ - live) * sizeof(PrimRef));
        ctx_.refs = refs;
        limit_ = limit_of(v_, refs);
    }

    NodeArray& v_;
    KernelContext& ctx_;
    uint32_t n_;
    size_t limit_;
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
            // May move the node array (and, NodesBeforeRecords, the records
            // and ctx.refs): at() after it. Records before task->begin are dead.
            const std::array<Slot, 2> c = out.pair(task->begin);
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
inline uint32_t build_depth_first(const KernelContext& ctx, const NodeTask& root, NodeArray& nodes,
                                  BinSet& bins, SkipCounts& skip, uint32_t track) {
    GrowingNodes out(nodes);
    return build_depth_first(ctx, root, out, bins, skip, track);
}

}  // namespace canopy
