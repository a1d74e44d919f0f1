// canopy scheduler: per-thread queues with locks, as in the original
// project, done with persistent workers.
//
// The big nodes near the root run with the whole team (omp_top_phase). The
// remaining tasks are dealt to the workers' queues in turn. Every worker
// owns a queue and an OpenMP lock, pops from the back of its own queue, and
// pushes each child it emits onto queue (its own id + k) mod workers, k
// counting the children it has emitted (interleaved assignment). A worker
// whose queue is empty takes from the front of the others'; when all are
// empty it yields and then sleeps briefly instead of spinning. The build
// ends when an atomic count of outstanding tasks reaches zero. Small tasks
// (below the task cutoff) run their whole subtree inline.
#pragma once

#include "omp_common.h"

#include <atomic>
#include <chrono>
#include <deque>
#include <thread>

namespace canopy {

struct OmpQueues {
    static constexpr const char* name = "omp_queues";

    static void run(BuildState& st) {
        const uint32_t threads = sched::useful_threads(st);
        if (threads == 1) return Sequential::run(st);
        st.allocate_records_in_tree();  // before any context() is taken
        const KernelContext ctx = st.context(threads);
        sched::TopPhase top;
        std::vector<Queue> queues;
        std::atomic<int64_t> outstanding{0};
        sched::omp_build(st, threads, [&](sched::Workers& workers, uint32_t team) {
            sched::omp_top_phase(ctx, st.n, team, top, workers, st.root);
#pragma omp single
            {
                queues = std::vector<Queue>(team);
                for (size_t i = 0; i < top.small.size(); ++i) queues[i % team].tasks.push_back(top.small[i]);
                outstanding.store(static_cast<int64_t>(top.small.size()));
            }
            const uint32_t me = static_cast<uint32_t>(omp_get_thread_num());
            worker(ctx, me, team, queues, outstanding, workers[me]);
#pragma omp barrier
#pragma omp single
            queues.clear();  // destroys the locks after every worker left
        });
    }

private:
    struct Queue {
        omp_lock_t lock;
        std::deque<NodeTask> tasks;
        Queue() { omp_init_lock(&lock); }
        ~Queue() { omp_destroy_lock(&lock); }
        Queue(const Queue&) = delete;
        Queue& operator=(const Queue&) = delete;
        Queue(Queue&& o) noexcept : tasks(std::move(o.tasks)) { omp_init_lock(&lock); }
        Queue& operator=(Queue&&) = delete;
    };

    static bool pop(std::vector<Queue>& queues, uint32_t me, NodeTask& t) {
        const uint32_t w = static_cast<uint32_t>(queues.size());
        for (uint32_t k = 0; k < w; ++k) {
            Queue& q = queues[(me + k) % w];
            omp_set_lock(&q.lock);
            const bool got = !q.tasks.empty();
            if (got) {
                if (k == 0) {
                    t = q.tasks.back();
                    q.tasks.pop_back();
                } else {
                    t = q.tasks.front();
                    q.tasks.pop_front();
                }
            }
            omp_unset_lock(&q.lock);
            if (got) return true;
        }
        return false;
    }

    static void push(std::vector<Queue>& queues, uint32_t target, const NodeTask& t) {
        Queue& q = queues[target];
        omp_set_lock(&q.lock);
        q.tasks.push_back(t);
        omp_unset_lock(&q.lock);
    }

    static void worker(const KernelContext& ctx, uint32_t me, uint32_t team, std::vector<Queue>& queues,
                       std::atomic<int64_t>& outstanding, sched::Worker& wk) {
        uint64_t emitted = 0;
        uint32_t idle = 0;
        NodeTask t, children[2];
        while (outstanding.load(std::memory_order_acquire) > 0) {
            if (!pop(queues, me, t)) {
                if (++idle < 64)
                    std::this_thread::yield();
                else
                    std::this_thread::sleep_for(std::chrono::microseconds(50));
                continue;
            }
            idle = 0;
            if (sched::below_cutoff(t, ctx.options->tuning)) {
                ++wk.skip.inline_tasks;
                sched::run_subtree(ctx, t, wk);
            } else if (sched::run_recorded(ctx, t, children, wk)) {
                outstanding.fetch_add(2, std::memory_order_acq_rel);
                for (int k = 0; k < 2; ++k) push(queues, static_cast<uint32_t>((me + emitted++) % team), children[k]);
            }
            outstanding.fetch_sub(1, std::memory_order_acq_rel);
        }
    }
};

}  // namespace canopy
