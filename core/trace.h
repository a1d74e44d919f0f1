// canopy: an optional trace of what every worker did during a build, written
// in the Chrome Trace Event Format (opens in Perfetto and chrome://tracing).
//
// A span is a node task as the scheduler ran it: a node processed on its own
// ("task"), a whole subtree run inline below the task cutoff ("inline"), or
// a big node processed by the whole team ("parallel", with a span for each
// of its phases: start, bin, evaluate, mark and swap or, for a middle split,
// count, and finish). Two spans cover the build's own phases around the
// node tasks, on the calling thread's track: "prepare" (the primitive
// records, bounds and centroids) and, for the parallel drivers, "place" (the
// final node array from the workers' blocks). Tracing is off unless a
// TraceLog is passed to the build; when off, the only cost is one pointer
// test per scheduled task, outside every per-primitive loop.
#pragma once

#include "layout.h"

#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace canopy {

struct TraceSpan {
    // How the node ran; the kinds from Start to Finish are the phases of a
    // team-parallel node (see run_parallel_node), Prepare and Place the
    // build's phases before and after the node tasks (their node is the root).
    enum Kind : uint8_t {
        Task, Inline, Parallel, Start, Bin, Evaluate, Count, Mark, Swap, Partition, Finish, Prepare, Place
    };
    static constexpr const char* kKindNames[] = {"task",  "inline", "parallel",  "start",  "bin",     "evaluate", "count",
                                                 "mark",  "swap",   "partition", "finish", "prepare", "place"};
    bool node_phase() const { return kind >= Start && kind <= Finish; }
    bool build_phase() const { return kind >= Prepare; }
    uint64_t start_ns, end_ns;  // since the log's start
    uint32_t worker;
    uint32_t node;              // canonical node index (filled in after placement)
    uint32_t begin, count;      // the node's range of the permutation
    uint32_t parent_begin;
    uint8_t depth, rights, is_right;
    Kind kind;
};

class TraceLog {
public:
    TraceLog() : start_(std::chrono::steady_clock::now()) {}

    uint64_t now_ns() const {
        return static_cast<uint64_t>(
            std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start_)
                .count());
    }
    // Thread-safe.
    void add(const TraceSpan& s) {
        std::lock_guard<std::mutex> lock(mutex_);
        spans_.push_back(s);
    }
    std::vector<TraceSpan>& spans() { return spans_; }
    const std::vector<TraceSpan>& spans() const { return spans_; }

    // Gives every span its canonical node index (the arithmetic that
    // place_nodes() uses for task nodes, over the finished tree's leaves).
    // Called by the build.
    void resolve(const NodeArray& nodes, uint32_t primitive_count) {
        LeafRank rank(primitive_count);
        for (const Node& n : nodes)
            if (n.is_leaf()) rank.mark(n.index);
        rank.finish();
        for (TraceSpan& s : spans_) {
            NodeRecord r{};
            r.begin = s.begin;
            r.parent_begin = s.parent_begin;
            r.depth = s.depth;
            r.rights = s.rights;
            r.is_right = s.is_right;
            s.node = canonical_slot(r, rank);
        }
    }

private:
    std::chrono::steady_clock::time_point start_;
    std::mutex mutex_;
    std::vector<TraceSpan> spans_;
};

// Starts a span at construction and adds it at destruction, when `log` is
// not null. Building with -DCANOPY_TRACE=0 (Meson: -Dtrace=false) compiles
// tracing out entirely, to measure what the disabled branch costs.
#ifndef CANOPY_TRACE
#define CANOPY_TRACE 1
#endif
class TraceScope {
public:
    TraceScope(TraceLog* log, const NodeTask& t, uint32_t worker, TraceSpan::Kind kind)
        : log_(CANOPY_TRACE ? log : nullptr) {
        if (!log_) return;
        span_ = TraceSpan{log_->now_ns(), 0, worker, 0, t.begin, t.size(), t.parent_begin,
                          static_cast<uint8_t>(t.depth), t.rights, static_cast<uint8_t>(t.is_right), kind};
    }
    // Untraced (the common case) it is one test, inlined; GCC had kept the
    // whole destructor out of line, a call per node.
    ~TraceScope() {
        if (log_) close();
    }
    // A build phase (Prepare, Place) over all `n` primitives, on `worker`.
    TraceScope(TraceLog* log, uint32_t n, uint32_t worker, TraceSpan::Kind kind)
        : log_(CANOPY_TRACE ? log : nullptr) {
        if (!log_) return;
        span_ = TraceSpan{log_->now_ns(), 0, worker, 0, 0, n, 0, 0, 0, 0, kind};
    }
    TraceScope(const TraceScope&) = delete;
    TraceScope& operator=(const TraceScope&) = delete;

private:
    [[gnu::noinline]] void close() {
        span_.end_ns = log_->now_ns();
        log_->add(span_);
    }
    TraceLog* log_;
    TraceSpan span_;  // set when log_ is (not zeroed per node otherwise)
};

// Writes the Chrome trace JSON. Throws canopy::Error when the file cannot
// be written.
void write_chrome_trace(const TraceLog& log, const std::string& path, const std::string& scheduler,
                        uint32_t threads);

}  // namespace canopy
