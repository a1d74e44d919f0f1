// canopy: what the parallel schedulers share. Each driver supplies only its
// own way of running things in parallel; the node work is the kernel's
// (core/kernel.h, core/parallel_node.h) and the node placement is
// arithmetic (core/layout.h), so no timing can reach the output.
#pragma once

#include "../core/build.h"
#include "../core/layout.h"
#include "../core/parallel_node.h"
#include "sequential.h"

#include <algorithm>
#include <memory>
#include <vector>

namespace canopy::sched {

// Tuning constants (they change speed, never the tree).
inline constexpr uint32_t kPrimsPerThread = 16384;  // fewer per thread: use fewer threads
inline constexpr uint32_t kTaskCutoff = 4096;       // smaller nodes recurse inline
inline constexpr uint32_t kParallelNodeMin = 65536; // smaller nodes never run team-parallel
inline constexpr uint32_t kPrepareBlock = 65536;    // primitives per prepare / extract block

// Threads worth starting for n primitives with at most `asked`.
inline uint32_t useful_threads(uint32_t n, uint32_t asked) {
    return std::max(1u, std::min(asked, n / kPrimsPerThread));
}

// A node runs team-parallel when it is big in absolute terms and big
// relative to the scene (so that there are too few such nodes to keep every
// thread busy with whole nodes).
inline bool team_parallel(uint32_t size, uint32_t n, uint32_t threads) {
    return threads > 1 && size >= kParallelNodeMin && size >= n / (2 * threads);
}

// Per-worker scratch: bins, the node records it created, its counters.
struct Worker {
    std::unique_ptr<BinSet> bins = std::make_unique<BinSet>();
    std::vector<NodeRecord> records;
    SkipCounts skip;
};

struct Workers {
    std::vector<Worker> w;
    explicit Workers(uint32_t count) : w(count) {}
    Worker& operator[](size_t i) { return w[i]; }
    size_t size() const { return w.size(); }
};

// Runs one node task sequentially on worker `wk`, recording it. Returns
// whether it split.
inline bool run_recorded(const KernelContext& ctx, const NodeTask& t, NodeTask children[2], Worker& wk) {
    const bool split = run_node(ctx, t, children, *wk.bins, wk.skip);
    wk.records.push_back(NodeRecord::of(t, !split));
    return split;
}

// Runs a whole subtree depth-first on worker `wk` (no further parallelism).
inline void run_subtree(const KernelContext& ctx, const NodeTask& root, Worker& wk) {
    NodeTask stack[2 * (kMaxDepthCap + 2)];
    uint32_t top = 0;
    stack[top++] = root;
    NodeTask children[2];
    while (top) {
        const NodeTask t = stack[--top];
        if (run_recorded(ctx, t, children, wk)) {
            stack[top++] = children[1];
            stack[top++] = children[0];
        }
    }
}

// Prepares the primitives with for_each over blocks (any order, any
// thread): the merged summary is order-independent.
template <class ForEach>
void prepare_parallel(BuildState& st, ForEach&& for_each) {
    const uint32_t blocks = (st.n + kPrepareBlock - 1) / kPrepareBlock;
    std::vector<PrepareSummary> part(blocks);
    for_each(blocks, [&](uint32_t b) {
        const size_t lo = size_t(b) * kPrepareBlock, hi = std::min<size_t>(st.n, lo + kPrepareBlock);
        part[b] = st.prepare_range(lo, hi);
    });
    PrepareSummary all;
    for (const auto& p : part) all.merge(p);
    st.finish_prepare(all);
}

// Places the recorded nodes, writes the permutation and sums the counters.
template <class ForEach>
void finish_parallel(BuildState& st, Workers& workers, ForEach&& for_each) {
    std::vector<std::vector<NodeRecord>> arenas;
    arenas.reserve(workers.size());
    for (auto& wk : workers.w) {
        arenas.push_back(std::move(wk.records));
        st.stats.skipped.add(wk.skip);
    }
    place_records(std::span<const std::vector<NodeRecord>>(arenas), st.n, st.bvh.nodes,
                  [&](size_t k, auto&& fn) { for_each(static_cast<uint32_t>(k), fn); });
    const uint32_t blocks = (st.n + kPrepareBlock - 1) / kPrepareBlock;
    for_each(blocks, [&](uint32_t b) {
        const size_t lo = size_t(b) * kPrepareBlock, hi = std::min<size_t>(st.n, lo + kPrepareBlock);
        st.extract_ids(lo, hi);
    });
}

}  // namespace canopy::sched
