// canopy scheduler: oneTBB work stealing.
//
// The build runs in its own task_arena limited to the thread bound, so a
// build called from inside a user's TBB parallel region does not
// oversubscribe. Each split node above the task cutoff hands its two
// children to parallel_invoke; smaller subtrees run inline, depth-first.
// Big nodes near the root are binned and partitioned with parallel_for.
#pragma once

#include "common.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

namespace canopy {

struct Tbb {
    static constexpr const char* name = "tbb";

    // The calling thread's index in the arena (its slot in the team, and its
    // worker's index); public for the benchmarks that drive the same arena.
    static uint32_t slot() { return static_cast<uint32_t>(tbb::this_task_arena::current_thread_index()); }

    // The drivers' parallel loop: fn(i) for every i in [0, k), one index a
    // task, returning when all are done (prepare_parallel(),
    // run_parallel_node(), finish_parallel(); the benchmarks' too).
    struct ForEach {
        template <class Fn>
        void operator()(uint32_t k, Fn&& fn) const {
            tbb::parallel_for(tbb::blocked_range<uint32_t>(0, k, 1), [&](const tbb::blocked_range<uint32_t>& r) {
                for (uint32_t i = r.begin(); i != r.end(); ++i) fn(i);
            });
        }
    };

    static void run(BuildState& st) {
        // Never more threads than the calling context allows (inside a user's
        // arena, its concurrency), so nothing is oversubscribed.
        const uint32_t threads = std::min<uint32_t>(
            sched::useful_threads(st), static_cast<uint32_t>(tbb::this_task_arena::max_concurrency()));
        if (threads <= 1) return Sequential::run(st);
        st.allocate_records_in_tree();  // before any context() is taken
        st.stats.threads_used = threads;
        tbb::task_arena arena(static_cast<int>(threads));
        arena.execute([&] {
            sched::prepare_parallel(st, threads, ForEach{}, slot);
            // Slots are indexed by the arena's thread index, unique per thread.
            sched::Workers& workers = st.workers;
            sched::start_workers(st, workers, static_cast<uint32_t>(tbb::this_task_arena::max_concurrency()));
            Builder b{st.context(threads), st.n, threads, workers};
            b.task(st.root);
            sched::finish_parallel(st, workers, ForEach{});
        });
    }

private:
    struct Builder {
        KernelContext ctx;
        uint32_t n, threads;
        sched::Workers& workers;

        sched::Worker& me() { return workers[slot()]; }

        void task(const NodeTask& t) {
            if (sched::below_cutoff(t, ctx.options->tuning)) {
                ++me().skip.inline_tasks;
                sched::run_subtree(ctx, t, me());
                return;
            }
            NodeTask children[2];
            bool split;
            const bool team = sched::team_parallel(t.size(), n, threads, ctx.options->tuning);
            if (team) {
                const TraceScope trace(ctx.trace, t, me().id, TraceSpan::Parallel);
                ParallelNode pn(ctx, t, threads);
                split = run_parallel_node(pn, children, me().skip, ForEach{}, [](auto&& fn) { fn(); }, ctx.trace,
                                          me().id);
                me().out.records.push_back(NodeRecord::of(t, !split));
            } else {
                split = sched::run_recorded(ctx, t, children, me());
            }
            if (!split) return;
            if (team) {
                // The team's children: each thread takes first the one over
                // the records it prepared (sched::TaskClaims).
                sched::TaskClaims claims;
                const auto take = [&] { task(children[claims.claim(children, slot(), n, threads)]); };
                tbb::parallel_invoke(take, take);
                return;
            }
            tbb::parallel_invoke([&] { task(children[0]); }, [&] { task(children[1]); });
        }
    };
};

}  // namespace canopy
