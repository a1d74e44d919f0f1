// canopy: the build entry points, with the scheduler a template parameter.
//
//   canopy::Bvh bvh = canopy::build<canopy::Tbb>(mesh.view(), options);
//
// Every scheduler produces the same bits (see bvh.h for the layout).
#pragma once

#include "build_state.h"
#include "error.h"

#include <concepts>
#include <thread>

namespace canopy {

// A scheduler is a type with a name and a static run(BuildState&) that
// prepares the primitives and builds the tree into state.bvh.
template <class S>
concept Scheduler = requires(BuildState& st) {
    { S::name } -> std::convertible_to<const char*>;
    S::run(st);
};

namespace detail {

// 0 asks for every hardware thread. The count is read once per process:
// std::thread::hardware_concurrency() opens, reads and closes a sysfs file
// on every call (glibc), which a build with default options did each time.
inline uint32_t resolve_threads(uint32_t asked) {
    if (asked) return asked;
    static const unsigned hw = std::thread::hardware_concurrency();
    return hw ? hw : 1;
}

// Builds into st.bvh (whose arrays' memory is reused).
template <Scheduler S>
void build_into(BuildState& st, size_t count, BuildStats* stats) {
    st.options.check();
    st.threads = resolve_threads(st.options.threads);
    st.n = static_cast<uint32_t>(count);
    st.stats = BuildStats{};
    st.root = NodeTask{};
    st.bvh.nodes.clear();
    st.bvh.permutation.clear();
    if (count == 0) {
        if (stats) *stats = BuildStats{};
        return;
    }
    const uint64_t leaves_needed = (uint64_t(st.n) + st.options.max_leaf - 1) / st.options.max_leaf;
    if (ceil_log2(static_cast<uint32_t>(leaves_needed)) > st.options.max_depth)
        throw OptionError("max_depth " + std::to_string(st.options.max_depth) + " is too small for " +
                          std::to_string(count) + " primitives in leaves of at most " +
                          std::to_string(st.options.max_leaf) + " (needs " +
                          std::to_string(ceil_log2(static_cast<uint32_t>(leaves_needed))) + ")");
    reserve_on_huge_pages(st.bvh.permutation, count);
    st.bvh.permutation.resize(count);
    S::run(st);
    assert(st.carried.size() == 0 && "every split chosen ahead was taken by its task");
    if (st.trace) st.trace->resolve(st.bvh.nodes, st.n);
    if (stats) *stats = st.stats;
}

template <Scheduler S>
Bvh run_build(BuildState& st, size_t count, BuildStats* stats) {
    build_into<S>(st, count, stats);
    return std::move(st.bvh);
}

}  // namespace detail

// Builds over an indexed triangle mesh. Throws InputError for bad triangles
// (index out of range, non-finite coordinate) naming the lowest such one,
// and OptionError for bad options.
// `trace`, when given, records what every worker did (see trace.h).
template <Scheduler S>
Bvh build(const TriangleView& mesh, const BuildOptions& options = {}, BuildStats* stats = nullptr,
          TraceLog* trace = nullptr) {
    check_triangle_input(mesh);
    BuildState st;
    st.options = options;
    st.mesh = &mesh;
    st.trace = trace;
    return detail::run_build<S>(st, mesh.triangle_count(), stats);
}

// Builds over caller-given primitive boxes (any primitive type); the
// permutation holds indices into `boxes`.
template <Scheduler S>
Bvh build(std::span<const Box> boxes, const BuildOptions& options = {}, BuildStats* stats = nullptr,
          TraceLog* trace = nullptr) {
    check_box_input(boxes);
    BuildState st;
    st.options = options;
    st.boxes = boxes;
    st.trace = trace;
    return detail::run_build<S>(st, boxes.size(), stats);
}

// A builder that keeps its memory between builds: the primitive records, the
// parallel drivers' per-thread bins and node chunks, and one tree's arrays. It builds the same trees as build<S>(); a
// build no bigger than an earlier one allocates almost nothing (a "warm"
// build: `canopy build --warm`). One build at a time per Builder.
//
//   canopy::Builder<canopy::Tbb> builder;
//   canopy::Bvh bvh;
//   for (const auto& frame : frames) builder.build(frame.view(), bvh, options);
//
// On success `out` holds the new tree, and the builder keeps the arrays `out`
// had, for the next build; on an exception (the same errors as build<S>())
// `out` is left as it was.
template <Scheduler S>
class Builder {
public:
    void build(const TriangleView& mesh, Bvh& out, const BuildOptions& options = {}, BuildStats* stats = nullptr,
               TraceLog* trace = nullptr) {
        check_triangle_input(mesh);
        start(options, trace);
        st_.mesh = &mesh;
        finish(mesh.triangle_count(), out, stats);
    }
    void build(std::span<const Box> boxes, Bvh& out, const BuildOptions& options = {}, BuildStats* stats = nullptr,
               TraceLog* trace = nullptr) {
        check_box_input(boxes);
        start(options, trace);
        st_.boxes = boxes;
        finish(boxes.size(), out, stats);
    }

private:
    void start(const BuildOptions& options, TraceLog* trace) {
        st_.options = options;
        st_.trace = trace;
        st_.mesh = nullptr;
        st_.boxes = {};
    }
    void finish(size_t count, Bvh& out, BuildStats* stats) {
        detail::build_into<S>(st_, count, stats);
        std::swap(out, st_.bvh);
        st_.mesh = nullptr;
        st_.trace = nullptr;
    }

    BuildState st_ = [] {
        BuildState st;
        st.keep_memory = true;
        return st;
    }();
};

}  // namespace canopy
