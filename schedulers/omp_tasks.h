// canopy scheduler: OpenMP tasks.
//
// The big nodes near the root run with the whole team (omp_top_phase); then
// one thread turns the remaining node tasks into OpenMP tasks. A task that
// splits continues with its right child itself and, while fewer than
// threads - 1 tasks wait to be started, spawns a task for its left child;
// otherwise it runs the left child first, depth first, on its own thread.
// Below the task cutoff a subtree runs inline, depth first.
//
// The limit on waiting tasks: with a task spawned at every split, all of
// them in libgomp's one queue for the team, the node work took longer than
// under TBB, whose threads take their own last-spawned task (whose records
// are still in their caches) and steal only when they have none. With the
// limit a thread goes depth first through its own subtrees, and the task
// waiting for an idle thread is the one a busy thread spawned last.
// Traced builds of the 1M sphere at 2 threads (medians of 7): the node
// work after the root 46.2 ms with a task at every split, 43.3 with the
// limit (tbb's 45.0); whole builds at 2 threads, alternated against the
// task at every split (medians of 7 rounds' ratios, "AMD EPYC" host,
// 2026-12-06): 1M sphere 0.960x, 1M stadium 0.978x (5 rounds), 1M random
// 0.958x, dragon_vrip_res2 0.986x and 0.989x (9 rounds), 4M sphere 0.993x
// (3 rounds).
// Which thread builds a node never changes the tree (see common.h).
#pragma once

#include "omp_common.h"

#include <atomic>

namespace canopy {

struct OmpTasks {
    static constexpr const char* name = "omp_tasks";

    static void run(BuildState& st) {
        const uint32_t threads = sched::useful_threads(st);
        if (threads == 1) return Sequential::run(st);
        st.allocate_records_in_tree();  // before any context() is taken
        const KernelContext ctx = st.context(threads);
        sched::TopPhase top;
        sched::TaskClaims claims;
        const uint32_t n = st.n;
        Spawner spawn{{0}, static_cast<int>(threads) - 1};
        sched::omp_build(st, threads, [&](sched::Workers& workers, uint32_t team) {
            sched::omp_top_phase(ctx, st.n, team, top, workers, st.root);
#pragma omp single
            {
                // Each thread takes first the tasks over the records it
                // prepared (sched::TaskClaims), when they are few enough.
                const bool claimed = top.small.size() <= sched::TaskClaims::kMax;
                for (size_t i = 0; i < top.small.size(); ++i) {
#pragma omp task firstprivate(i) shared(workers, spawn, top, claims)
                    {
                        const size_t k = claimed ? claims.claim(top.small, sched::OmpTeam::slot(), n, team) : i;
                        task(ctx, top.small[k], workers, spawn);
                    }
                }
            }  // the barrier here waits for every task
        });
    }

private:
    // Tasks spawned by task() and not started yet, and how many may wait.
    struct Spawner {
        std::atomic<int> waiting;
        int limit;
    };

    static void task(const KernelContext& ctx, NodeTask t, sched::Workers& workers, Spawner& spawn) {
        while (true) {
            sched::Worker& wk = workers[static_cast<size_t>(omp_get_thread_num())];
            if (sched::below_cutoff(t, ctx.options->tuning)) {
                ++wk.skip.inline_tasks;
                sched::run_subtree(ctx, t, wk);
                return;
            }
            NodeTask children[2];
            if (!sched::run_recorded(ctx, t, children, wk)) return;
            const NodeTask left = children[0];
            if (spawn.waiting.load(std::memory_order_relaxed) < spawn.limit) {
                spawn.waiting.fetch_add(1, std::memory_order_relaxed);
#pragma omp task firstprivate(left) shared(workers, spawn)
                {
                    spawn.waiting.fetch_sub(1, std::memory_order_relaxed);
                    task(ctx, left, workers, spawn);
                }
            } else {
                task(ctx, left, workers, spawn);
            }
            t = children[1];
        }
    }
};

}  // namespace canopy
