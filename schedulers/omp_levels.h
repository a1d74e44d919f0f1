// canopy scheduler: level by level with OpenMP.
//
// All node tasks of one level run in one parallel loop; each writes its two
// children (if any) to its own pair of slots, and the next level is built
// from those slots in task order (a prefix over the children emitted), so
// the frontier order never depends on timing. Big nodes of a level run one
// after another with the whole team (parallel binning and partition).
#pragma once

#include "omp_common.h"

namespace canopy {

struct OmpLevels {
    static constexpr const char* name = "omp_levels";

    static void run(BuildState& st) {
        const uint32_t threads = sched::useful_threads(st);
        if (threads == 1) return Sequential::run(st);
        const KernelContext ctx = st.context();
        struct Level {
            std::vector<NodeTask> frontier, big, small, next, kids;
            std::vector<uint8_t> split;
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
                    for (const NodeTask& t : lv.frontier)
                        (sched::team_parallel(t.size(), n, team, ctx.options->tuning) ? lv.big : lv.small).push_back(t);
                    lv.kids.resize(2 * lv.small.size());
                    lv.split.assign(lv.small.size(), 0);
                }
                if (lv.big.empty() && lv.small.empty()) break;
                for (size_t i = 0; i < lv.big.size(); ++i) {
#pragma omp single
                    lv.node = std::make_unique<ParallelNode>(ctx, lv.big[i]);
                    sched::Worker& wk = workers[static_cast<size_t>(omp_get_thread_num())];
                    const TraceScope trace(wk.id == 0 ? ctx.trace : nullptr, lv.big[i], wk.id,
                                           TraceSpan::Parallel);
                    run_parallel_node(
                        *lv.node, lv.big_kids, wk.skip, [&](uint32_t k, auto&& fn) { omp.for_each(k, fn); },
                        [&](auto&& fn) { omp.serial(fn); }, wk.id == 0 ? ctx.trace : nullptr, wk.id);
#pragma omp single
                    {
                        const bool split = lv.node->splits();
                        workers[static_cast<size_t>(omp_get_thread_num())].records.push_back(
                            NodeRecord::of(lv.big[i], !split));
                        if (split) {
                            lv.next.push_back(lv.big_kids[0]);
                            lv.next.push_back(lv.big_kids[1]);
                        }
                    }
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
                    lv.split[i] = sched::run_recorded(ctx, lv.small[i], &lv.kids[2 * i], wk);
                }
#pragma omp single
                {
                    for (size_t i = 0; i < count; ++i)
                        if (lv.split[i]) {
                            lv.next.push_back(lv.kids[2 * i]);
                            lv.next.push_back(lv.kids[2 * i + 1]);
                        }
                    lv.frontier.swap(lv.next);
                }
            }
        });
    }
};

}  // namespace canopy
