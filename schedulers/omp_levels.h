// canopy scheduler: level by level with OpenMP.
//
// All node tasks of one level run in one parallel loop; each writes its two
// children (if any) to its own pair of slots, and the next level is built
// from those slots in task order (a prefix over the children emitted), so
// the frontier order never depends on timing. Big nodes of a level run one
// after another with the whole team (parallel binning and partition). A
// task below the task cutoff runs its whole subtree inline, depth first, as
// in the other drivers: level by level to the leaves, every level streamed
// the whole record buffer through the cache again, and the 1M sphere built
// slower on two threads than on one.
#pragma once

#include "omp_common.h"

#include <algorithm>

namespace canopy {

struct OmpLevels {
    static constexpr const char* name = "omp_levels";

    static void run(BuildState& st) {
        const uint32_t threads = sched::useful_threads(st);
        if (threads == 1) return Sequential::run(st);
        st.allocate_records_in_tree();  // before any context() is taken
        const KernelContext ctx = st.context(threads);
        struct Level {
            std::vector<NodeTask> frontier, big, small, next, kids;
            std::vector<uint8_t> split;
            std::vector<size_t> block_start;  // per thread: first child pair of its block
            size_t base = 0;                  // where the small tasks' children start in next
            std::unique_ptr<ParallelNode> node;
            NodeTask big_kids[2];
        } lv;
        const uint32_t n = st.n;
        sched::omp_build(st, threads, [&](sched::Workers& workers, uint32_t team) {
            const sched::OmpTeam omp;
#pragma omp single
            lv.frontier.assign(1, st.root);  // the root exists once prepared
            while (true) {
#pragma omp single
                {
                    lv.big.clear();
                    lv.small.clear();
                    lv.next.clear();
                    const bool any_big = std::any_of(lv.frontier.begin(), lv.frontier.end(), [&](const NodeTask& t) {
                        return sched::team_parallel(t.size(), n, team, ctx.options->tuning);
                    });
                    if (any_big) {
                        for (const NodeTask& t : lv.frontier)
                            (sched::team_parallel(t.size(), n, team, ctx.options->tuning) ? lv.big : lv.small)
                                .push_back(t);
                    } else {
                        lv.small.swap(lv.frontier);  // the deep levels: no copy
                    }
                    lv.kids.resize(2 * lv.small.size());
                    lv.split.assign(lv.small.size(), 0);
                    lv.block_start.assign(size_t(omp_get_num_threads()) + 1, 0);
                }
                if (lv.big.empty() && lv.small.empty()) break;
                for (size_t i = 0; i < lv.big.size(); ++i) {
#pragma omp single
                    lv.node = std::make_unique<ParallelNode>(ctx, lv.big[i], team);
                    sched::Worker& wk = workers[static_cast<size_t>(omp_get_thread_num())];
                    const TraceScope trace(wk.id == 0 ? ctx.trace : nullptr, lv.big[i], wk.id,
                                           TraceSpan::Parallel);
                    run_parallel_node(
                        *lv.node, lv.big_kids, wk.skip, [&](uint32_t k, auto&& fn) { omp.for_each(k, fn); },
                        [&](auto&& fn) { omp.serial(fn); }, wk.id == 0 ? ctx.trace : nullptr, wk.id);
#pragma omp single
                    {
                        const bool split = lv.node->splits();
                        workers[static_cast<size_t>(omp_get_thread_num())].out.records.push_back(
                            NodeRecord::of(lv.big[i], !split));
                        if (split) {
                            lv.next.push_back(lv.big_kids[0]);
                            lv.next.push_back(lv.big_kids[1]);
                        }
                    }
                }
                // Its bins and marks are not held through the rest of the
                // build. Not in the single above: a thread can still be reading
                // the node in run_parallel_node's `splits()` test when another
                // enters that single (only its end is a barrier). lv.big is the
                // same for the whole team, so all or none meet this single.
                if (!lv.big.empty()) {
#pragma omp single
                    lv.node.reset();
                }
                const size_t count = lv.small.size();
                // Chunks of one node while a level has few nodes (they are
                // big: a chunk of 16 would hand a whole level of up to 16
                // big nodes to one thread); chunks of 16 once the level is
                // wide, where nodes are small and taking work costs.
                const int chunk = count >= 64 * size_t(team) ? 16 : 1;
#pragma omp for schedule(dynamic, chunk)
                for (size_t i = 0; i < count; ++i) {
                    sched::Worker& wk = workers[static_cast<size_t>(omp_get_thread_num())];
                    if (sched::below_cutoff(lv.small[i], ctx.options->tuning)) {
                        ++wk.skip.inline_tasks;
                        sched::run_subtree(ctx, lv.small[i], wk);
                        lv.split[i] = 0;  // its subtree is done: nothing for the next level
                    } else {
                        lv.split[i] = sched::run_recorded(ctx, lv.small[i], &lv.kids[2 * i], wk);
                    }
                }
                // The next level, in task order after the big nodes'
                // children: a parallel pack. Each thread counts the splits
                // of its own block of tasks, one thread turns the counts
                // into offsets, and each copies its block's children there.
                const size_t threads_now = size_t(omp_get_num_threads()), me = size_t(omp_get_thread_num());
                const size_t per = (count + threads_now - 1) / threads_now;
                const size_t b0 = std::min(count, per * me), b1 = std::min(count, b0 + per);
                size_t mine = 0;
                for (size_t i = b0; i < b1; ++i) mine += lv.split[i];
                lv.block_start[me + 1] = mine;
#pragma omp barrier
#pragma omp single
                {
                    for (size_t b = 0; b < threads_now; ++b) lv.block_start[b + 1] += lv.block_start[b];
                    lv.base = lv.next.size();
                    lv.next.resize(lv.base + 2 * lv.block_start[threads_now]);
                }
                NodeTask* out = lv.next.data() + lv.base + 2 * lv.block_start[me];
                for (size_t i = b0; i < b1; ++i)
                    if (lv.split[i]) {
                        *out++ = lv.kids[2 * i];
                        *out++ = lv.kids[2 * i + 1];
                    }
#pragma omp barrier
#pragma omp single
                lv.frontier.swap(lv.next);
            }
        });
    }
};

}  // namespace canopy
