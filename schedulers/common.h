// canopy: what the parallel schedulers share. Each driver supplies only its
// own way of running things in parallel; the node work is the kernel's
// (core/kernel.h, core/parallel_node.h) and the node placement is
// arithmetic for task nodes and one offset per inline subtree
// (core/layout.h), so no timing can reach the output.
#pragma once

#include "../core/build.h"
#include "../core/depth_first.h"
#include "../core/layout.h"
#include "../core/parallel_node.h"
#include "../core/trace.h"
#include "../core/workers.h"
#include "sequential.h"

#include <algorithm>
#include <atomic>
#include <cassert>
#include <cstring>
#include <memory>
#include <span>
#include <vector>

namespace canopy::sched {

inline constexpr uint32_t kPrepareBlock = 65536;  // most primitives per prepare block

// Threads worth starting for the build: at most the bound asked for, and
// none beyond what the work can use (small scenes start no threads at all).
inline uint32_t useful_threads(const BuildState& st) {
    const uint32_t per = std::max(1u, st.options.tuning.prims_per_thread);
    return std::max(1u, std::min(st.threads, st.n / per));
}

// A node runs team-parallel when it is big in absolute terms and holds more
// than 1.5 / T of the scene: nodes of a smaller share have enough siblings
// to keep T threads busy with whole nodes (2^d nodes of share 2^-d), which
// costs no merging, no barriers and no cross-thread traffic. The rule was
// set when a team-parallel node made three passes over its records to
// run_node's two (a team of T was only T / 1.5 times as fast as one thread);
// it now makes two as well, and with the former rule (n / (2T)) the 2-thread
// builds measured the same within noise, so the rule was kept. At 2 threads
// only the root and a child of more than 3/4 of the scene qualify. (With
// n / (2T) and three passes, both children of the dragon's root ran
// "team-parallel" at the same time under tbb, each on its own thread.) Only
// speed depends on this: a node's result is the same either way, but for
// nodes of at most kExactMaxPrims primitives, which run_node() costs exactly
// and the team would bin: those never run team-parallel, whatever the tuning.
inline bool team_parallel(uint32_t size, uint32_t n, uint32_t threads, const SchedulerTuning& tu) {
    return threads > 1 && size > kExactMaxPrims && size >= tu.parallel_node_min &&
           2 * uint64_t(size) * threads > 3 * uint64_t(n);
}

inline bool below_cutoff(const NodeTask& t, const SchedulerTuning& tu) { return t.size() < tu.task_cutoff; }

// Blocks [0, parts * per_part) cut into `parts` runs of per_part, one per
// thread of a team. claim(slot), called once per block by whichever thread
// runs the call, returns a block no call has had: the next of the caller's
// own run (slot mod parts) while any is left, else the next of another
// run. Which thread gets which block depends on timing; what a block
// computes must not (it only decides whose caches hold the block's output).
class BlockClaims {
public:
    BlockClaims(uint32_t parts, uint32_t per_part)
        : parts_(std::max(1u, parts)), per_(per_part), next_(new std::atomic<uint32_t>[parts_]) {
        for (uint32_t p = 0; p < parts_; ++p) next_[p].store(0, std::memory_order_relaxed);
    }
    // At most one call per block: then every call finds a block left.
    uint32_t claim(uint32_t slot) {
        for (uint32_t k = 0;; ++k) {
            const uint32_t p = (slot + k) % parts_;
            if (next_[p].load(std::memory_order_relaxed) >= per_) continue;
            const uint32_t i = next_[p].fetch_add(1, std::memory_order_relaxed);
            if (i < per_) return p * per_ + i;
        }
    }

private:
    uint32_t parts_, per_;
    std::unique_ptr<std::atomic<uint32_t>[]> next_;
};

// The thread (of `threads`) whose part of the records prepare_parallel()
// prepared first holds the middle of task t's range.
inline uint32_t home_slot(const NodeTask& t, uint32_t n, uint32_t threads) {
    const uint64_t mid = (uint64_t(t.begin) + t.end) / 2;
    return static_cast<uint32_t>(std::min<uint64_t>(threads - 1, mid * threads / std::max(1u, n)));
}

// Tasks handed out at the top of the tree (the children of the team's
// nodes), at most 64: each call of claim() takes one not yet taken, the
// first whose records the calling thread prepared (home_slot()) if one is
// left, else the first left. Before this, on the 2-core machines, the
// thread that had not prepared them took the dragon's bigger child of the
// root in every traced tbb build: 0.76 ms against 0.53 with the claims
// (medians of 10 traces each; 0.18 to 0.31 in 1-thread builds). Only which
// thread builds a task depends on this, never the tree (see the top of
// this file).
class TaskClaims {
public:
    static constexpr size_t kMax = 64;
    uint32_t claim(std::span<const NodeTask> tasks, uint32_t slot, uint32_t n, uint32_t threads) {
        assert(tasks.size() <= kMax);
        uint64_t taken = taken_.load(std::memory_order_relaxed);
        for (;;) {
            size_t pick = tasks.size();
            for (size_t i = 0; i < tasks.size(); ++i) {
                if (taken >> i & 1) continue;
                if (pick == tasks.size()) pick = i;
                if (home_slot(tasks[i], n, threads) == slot % threads) {
                    pick = i;
                    break;
                }
            }
            assert(pick < tasks.size() && "more claims than tasks");
            if (taken_.compare_exchange_weak(taken, taken | uint64_t(1) << pick, std::memory_order_relaxed))
                return static_cast<uint32_t>(pick);
        }
    }

private:
    std::atomic<uint64_t> taken_{0};
};

using canopy::Worker;
using canopy::Workers;

// Runs one node task sequentially on worker `wk`, recording it. Returns
// whether it split. Traced when above the task cutoff.
inline bool run_recorded(const KernelContext& ctx, const NodeTask& t, NodeTask children[2], Worker& wk) {
    const TraceScope trace(below_cutoff(t, ctx.options->tuning) ? nullptr : ctx.trace, t, wk.id,
                           TraceSpan::Task);
    const bool split = run_node(ctx, t, children, *wk.bins, wk.skip);
    wk.out.records.push_back(NodeRecord::of(t, !split));
    return split;
}

// run_subtree() of a one-off build (PlacementArena::over_records): the
// subtree is built into the worker's scratch array (up to 256 KiB under the
// default task cutoff, less on small scenes: scratch_cutoff()), and then,
// its records being no longer needed (its leaves wrote their ids to the
// permutation), its nodes after the root are copied over them, as many as
// there are records; the rest (a tree of more nodes than primitives) go to
// the overflow area within the subtree's slots (core/overflow_area.h,
// area_start() in core/layout.h), or, if they are few, to the worker's chunks.
// Those records lie in the final node array's storage, in memory the build
// has already brought in, and the placement then moves the nodes towards
// the front of that storage (place_over_records() in core/layout.h): a
// one-off build holds the tree once, instead of once in the chunks and once
// in the final array.
inline void run_subtree_over_records(const KernelContext& ctx, const NodeTask& root, Worker& wk) {
    NodeArray& nodes = wk.out.scratch;
    nodes.clear();
    // At most 2 * size - 1 nodes: reserved whole, so the array never grows
    // by doubling (which held 1.7 times a random subtree's nodes). The old
    // array goes first: its nodes were copied out already, and reserve()
    // held the old and the new at once, a moment that fell at the build's
    // peak on whichever thread's timing (2-thread omp_tasks builds of
    // 50,000 random triangles on a loaded machine peaked at 72.59 bytes per
    // triangle in 5 of 40 builds, 71.06 in 1, against 69.97 otherwise).
    if (nodes.capacity() < 2 * size_t(root.size())) {
        nodes = NodeArray();
        nodes.reserve(2 * size_t(root.size()));
    }
    GrowingNodes out(nodes);
    SubtreeBlock b;
    b.leaves = build_depth_first(ctx, root, out, *wk.bins, wk.skip, wk.id);
    b.size = static_cast<uint32_t>(nodes.size());
    b.root = NodeRecord::of(root, nodes[0].is_leaf());
    const uint32_t body = b.size - 1;
    b.over_records = std::min(body, root.size());
    std::memcpy(static_cast<void*>(ctx.refs + root.begin), nodes.data() + 1, size_t(b.over_records) * sizeof(Node));
    const Node* rest = nodes.data() + 1 + b.over_records;
    // Few nodes past the records go to the chunks, fewer still from small
    // subtrees (scratch_cutoff()): the chunks are held whole until the
    // placement ends, while it gives back the area's pages as it goes, and
    // with the threshold at 512 the 2-thread builds of 33,000 random
    // triangles peaked at 77 to 79 bytes per triangle. So do those that do
    // not fit in the block's slots of a dense area (7/8 of its records).
    const uint32_t spill_max = std::min<uint32_t>(PlacementArena::kSpillMax, ctx.options->tuning.task_cutoff / 8);
    const uint32_t past = body - b.over_records;
    OverflowArea& area = *wk.out.overflow;
    if (past >= spill_max) {
        const uint64_t lo = area.slot(root.begin), hi = area.slot(size_t(root.begin) + b.over_records);
        b.in_area = static_cast<uint32_t>(std::min<uint64_t>(past, hi - lo));
        b.area = static_cast<uint32_t>(area_start(lo, hi, b.in_area, root.is_right));
        if (b.in_area > 0) area.write(b.area, rest, b.in_area, 2 * size_t(past) >= root.size());
    }
    if (past > b.in_area) {
        const auto [chunk, first] = wk.out.append(rest + b.in_area, past - b.in_area);
        b.chunk = chunk;
        b.first = first;
    }
    wk.out.blocks.push_back(b);
    wk.out.overflow->count_block(b.size);
}

// Runs a whole subtree depth-first on worker `wk` (no further parallelism),
// as one block in the sequential layout.
inline void run_subtree(const KernelContext& ctx, const NodeTask& root, Worker& wk) {
    const TraceScope trace(ctx.trace, root, wk.id, TraceSpan::Inline);
    if (wk.out.over_records) return run_subtree_over_records(ctx, root, wk);
    ChunkedNodes out(wk.out);
    SubtreeBlock b;
    b.leaves = build_depth_first(ctx, root, out, *wk.bins, wk.skip, wk.id);
    b.chunk = out.first_chunk();
    b.first = out.first();
    b.size = out.size();
    b.root = NodeRecord::of(root, wk.out.chunks[b.chunk][b.first].is_leaf());
    wk.out.blocks.push_back(b);
}

// Prepares the primitives with for_each over blocks (any order, any
// thread): the merged summary is order-independent. The blocks are of equal
// size and come in a multiple of `threads`, so that every thread gets the
// same share (with blocks of a fixed 65,536, the dragon's 202,520 triangles
// made four blocks, the last of 6,000, and one of two threads prepared
// two thirds of them). `slot()` says which thread calls (its index in the
// team): thread s takes first the blocks of the s-th part of the records,
// in order, and then what is left of the others' parts (BlockClaims), so
// that each thread's records are in its own caches when the top of the
// tree hands it the tasks over them (TaskClaims).
template <class ForEach, class Slot>
void prepare_parallel(BuildState& st, uint32_t threads, ForEach&& for_each, Slot&& slot) {
    const TraceScope trace(st.trace, st.n, 0, TraceSpan::Prepare);
    assert(st.records && "allocate_records_in_tree() first");
    const uint32_t t = std::max(1u, threads);
    const uint32_t rounds = static_cast<uint32_t>((uint64_t(st.n) + uint64_t(t) * kPrepareBlock - 1) /
                                                  (uint64_t(t) * kPrepareBlock));
    const uint32_t blocks = std::max(1u, rounds * t);
    const uint32_t per = static_cast<uint32_t>((uint64_t(st.n) + blocks - 1) / blocks);
    std::vector<PrepareSummary> part(blocks);
    BlockClaims claims(t, std::max(1u, rounds));
    for_each(blocks, [&](uint32_t) {
        const uint32_t b = claims.claim(slot());
        const size_t lo = std::min<size_t>(st.n, size_t(b) * per), hi = std::min<size_t>(st.n, lo + per);
        part[b] = st.prepare_range(lo, hi);
    });
    PrepareSummary all;
    for (const auto& p : part) all.merge(p);
    st.finish_prepare(all);
}

// The task cutoff of a one-off build of n primitives: `cutoff`, or n / 32
// if less (from kScratchCutoffMin), which lowers it below 131,072
// primitives. Each worker builds its inline subtrees in a scratch array of
// up to two nodes per record of the subtree (run_subtree_over_records()),
// held until the end of the build, which is when a one-off build holds the
// most: at most 2 bytes per triangle a worker this way. At 4,096 the two
// workers' scratch arrays were 9.7 bytes per triangle of the peak of a
// 2-thread build of 50,000 random triangles (76.5 against 68.4 by
// `sequential`). Smaller tasks cost time on such scenes: 2-thread builds of
// 50,000 random triangles took 1.04x as long (tbb and omp_tasks, 15
// alternated rounds of --repeat 51, 2026-12-05; the 69,451-triangle bunny
// 0.99x). Only which nodes run as tasks depends on it, never the tree.
inline constexpr uint32_t kScratchCutoffMin = 512;
inline uint32_t scratch_cutoff(uint32_t n, uint32_t cutoff) {
    return std::min(cutoff, std::max(kScratchCutoffMin, n / 32));
}

// Readies `count` workers for a parallel build of st (after
// allocate_records_in_tree()): over the records in a one-off build, whose
// storage's front the overflow area watches (OverflowArea::watch_front()),
// with the task cutoff scratch_cutoff() makes.
inline void start_workers(BuildState& st, Workers& workers, uint32_t count) {
    if (st.records_in_tree())
        st.options.tuning.task_cutoff = scratch_cutoff(st.n, st.options.tuning.task_cutoff);
    workers.reset(count, st.n, st.options.bins, st.options.tuning.chunk_nodes, st.records_in_tree());
    if (st.records_in_tree()) workers.overflow.watch_front(st.bvh.nodes, st.records);
}

// Places the recorded nodes and sums the counters (the leaves wrote the
// permutation as they were made).
template <class ForEach>
void finish_parallel(BuildState& st, Workers& workers, ForEach&& for_each) {
    const TraceScope trace(st.trace, st.n, 0, TraceSpan::Place);
    std::vector<const PlacementArena*> arenas;
    arenas.reserve(workers.size());
    for (auto& wk : workers.w) {
        arenas.push_back(&wk.out);
        st.stats.skipped.add(wk.skip);
    }
    const std::span<const PlacementArena* const> all(arenas);
    auto each = [&](size_t k, auto&& fn) { for_each(static_cast<uint32_t>(k), fn); };
    if (st.records_in_tree()) {
        // The blocks' nodes lie over the records, in bvh.nodes' storage
        // (run_subtree_over_records()). The workers' scratch arrays (a
        // subtree each, up to 256 KiB) go before the placement.
        for (auto& wk : workers.w) wk.out.scratch = NodeArray();
        place_over_records(all, st.records, st.bvh.nodes, each, st.options.tuning.place_parallel_min);
        st.records = nullptr;
        workers.overflow.reset(0);
        return;
    }
    // A warm Builder: the records in their own array, the blocks in chunks.
    place_nodes(all, st.records, st.bvh.nodes, each);
}

}  // namespace canopy::sched
