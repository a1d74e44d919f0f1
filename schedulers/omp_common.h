// canopy: what the OpenMP schedulers share: the team's parallel loop and
// single, the parallel prepare and finish, and the top phase that runs the
// big nodes near the root with the whole team.
#pragma once

#include "common.h"

#include <omp.h>

#include <memory>
#include <vector>

namespace canopy::sched {

// Inside a parallel region, called by every thread of the team.
struct OmpTeam {
    template <class Fn>
    void for_each(uint32_t k, Fn&& fn) const {
#pragma omp for schedule(dynamic, 1)
        for (uint32_t i = 0; i < k; ++i) fn(i);
    }
    template <class Fn>
    void serial(Fn&& fn) const {
#pragma omp single
        fn();
    }
    // The calling thread's index in the team.
    static uint32_t slot() { return static_cast<uint32_t>(omp_get_thread_num()); }
};

// A standalone parallel loop (opens its own region): the prepare's blocks
// (equal, a multiple of the team) and the placement's runs (one per
// thread). Static, one iteration at a time in turn, so that each thread
// takes its own: with `dynamic` the placement of omp_tasks builds took
// about its one-thread time, as if the thread that opened the region took
// both runs before the other had woken (traced builds of the 1M sphere at
// 2 threads, medians of 9: 1.62 ms; 1.23 with `static`, tbb's 1.10, one
// thread's 1.7; whole builds 0.996x, 1M random 0.994x, dragon 0.991x, 7
// alternated rounds, "AMD EPYC" host, 2026-12-06).
struct OmpLoop {
    uint32_t threads;
    template <class Fn>
    void operator()(uint32_t k, Fn&& fn) const {
#pragma omp parallel for num_threads(threads) schedule(static, 1)
        for (uint32_t i = 0; i < k; ++i) fn(i);
    }
};

// Shared state of the top phase.
struct TopPhase {
    std::vector<NodeTask> frontier, big, next, small;
    std::unique_ptr<ParallelNode> node;
    NodeTask kids[2];
};

// Called by every thread of the team: runs every node that qualifies for
// team parallelism (sched::team_parallel), breadth first, and leaves the
// other tasks in top.small. Records go to the worker of the thread that ran
// the serial phase.
inline void omp_top_phase(const KernelContext& ctx, uint32_t n, uint32_t team, TopPhase& top,
                          Workers& workers, const NodeTask& root) {
    const OmpTeam omp;
#pragma omp single
    {
        top.frontier.assign(1, root);
        top.small.clear();
    }
    while (true) {
#pragma omp single
        {
            top.big.clear();
            top.next.clear();
            for (const NodeTask& t : top.frontier)
                (team_parallel(t.size(), n, team, ctx.options->tuning) ? top.big : top.small).push_back(t);
        }
        if (top.big.empty()) break;
        for (size_t i = 0; i < top.big.size(); ++i) {
#pragma omp single
            top.node = std::make_unique<ParallelNode>(ctx, top.big[i], team);
            Worker& wk = workers[static_cast<size_t>(omp_get_thread_num())];
            const TraceScope trace(wk.id == 0 ? ctx.trace : nullptr, top.big[i], wk.id, TraceSpan::Parallel);
            run_parallel_node(
                *top.node, top.kids, wk.skip, [&](uint32_t k, auto&& fn) { omp.for_each(k, fn); },
                [&](auto&& fn) { omp.serial(fn); }, wk.id == 0 ? ctx.trace : nullptr, wk.id);
#pragma omp single
            {
                const bool split = top.node->splits();
                workers[static_cast<size_t>(omp_get_thread_num())].out.records.push_back(
                    NodeRecord::of(top.big[i], !split));
                if (split) {
                    top.next.push_back(top.kids[0]);
                    top.next.push_back(top.kids[1]);
                }
            }
        }
#pragma omp single
        {
            // Its bins and marks are not held through the rest of the build.
            // Not in the single above: a thread can still be reading the node
            // in run_parallel_node's `splits()` test when another enters that
            // single (only its end is a barrier).
            top.node.reset();
            top.frontier.swap(top.next);
        }
    }
}

// Runs `body(workers, team)` in a parallel region of `threads` threads after
// preparing the primitives; then places the nodes. The team may be smaller
// than asked (e.g. inside a user's parallel region, where nesting is off).
template <class Body>
void omp_build(BuildState& st, uint32_t threads, Body&& body) {
    st.stats.threads_used = threads;
    prepare_parallel(st, threads, OmpLoop{threads}, OmpTeam::slot);
    Workers& workers = st.workers;
    start_workers(st, workers, threads);
#pragma omp parallel num_threads(threads)
    {
        body(workers, static_cast<uint32_t>(omp_get_num_threads()));
    }
    finish_parallel(st, workers, OmpLoop{threads});
}

}  // namespace canopy::sched
