// canopy scheduler: OpenMP tasks.
//
// The big nodes near the root run with the whole team (omp_top_phase); then
// one thread turns the remaining node tasks into OpenMP tasks. A task that
// splits spawns a task for its left child and continues with its right one
// itself; below the task cutoff a subtree runs inline, depth first.
#pragma once

#include "omp_common.h"

namespace canopy {

struct OmpTasks {
    static constexpr const char* name = "omp_tasks";

    static void run(BuildState& st) {
        const uint32_t threads = sched::useful_threads(st);
        if (threads == 1) return Sequential::run(st);
        st.allocate_records_in_tree();  // before any context() is taken
        const KernelContext ctx = st.context(threads);
        sched::TopPhase top;
        sched::omp_build(st, threads, [&](sched::Workers& workers, uint32_t team) {
            sched::omp_top_phase(ctx, st.n, team, top, workers, st.root);
#pragma omp single
            {
                for (size_t i = 0; i < top.small.size(); ++i) {
                    const NodeTask t = top.small[i];
#pragma omp task firstprivate(t) shared(workers)
                    task(ctx, t, workers);
                }
            }  // the barrier here waits for every task
        });
    }

private:
    static void task(const KernelContext& ctx, NodeTask t, sched::Workers& workers) {
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
#pragma omp task firstprivate(left) shared(workers)
            task(ctx, left, workers);
            t = children[1];
        }
    }
};

}  // namespace canopy
