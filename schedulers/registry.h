// canopy: the schedulers compiled into this build, selectable by name at run
// time (the compile-time choice is the template parameter of canopy::build).
#pragma once

#include "../core/build.h"
#include "sequential.h"
#if CANOPY_HAVE_OPENMP
#include "omp_levels.h"
#include "omp_queues.h"
#include "omp_tasks.h"
#endif
#if CANOPY_HAVE_TBB
#include "tbb.h"
#endif

#include <memory>
#include <span>
#include <string>
#include <string_view>

namespace canopy {

// A Builder<S> (core/build.h) behind an interface, for tools that pick the
// scheduler at run time.
struct WarmBuilder {
    virtual ~WarmBuilder() = default;
    virtual void build(const TriangleView& mesh, Bvh& out, const BuildOptions& options, BuildStats* stats) = 0;
};

template <Scheduler S>
struct WarmBuilderOf final : WarmBuilder {
    Builder<S> builder;
    void build(const TriangleView& mesh, Bvh& out, const BuildOptions& options, BuildStats* stats) override {
        builder.build(mesh, out, options, stats);
    }
};

struct SchedulerEntry {
    const char* name;
    Bvh (*triangles_fn)(const TriangleView&, const BuildOptions&, BuildStats*, TraceLog*);
    Bvh (*boxes_fn)(std::span<const Box>, const BuildOptions&, BuildStats*, TraceLog*);
    std::unique_ptr<WarmBuilder> (*warm_fn)();

    // A Builder<S> that keeps its memory between builds.
    std::unique_ptr<WarmBuilder> make_warm_builder() const { return warm_fn(); }

    // canopy::build<S> for this entry's S.
    Bvh build_triangles(const TriangleView& mesh, const BuildOptions& options = {}, BuildStats* stats = nullptr,
                        TraceLog* trace = nullptr) const {
        return triangles_fn(mesh, options, stats, trace);
    }
    Bvh build_boxes(std::span<const Box> boxes, const BuildOptions& options = {}, BuildStats* stats = nullptr,
                    TraceLog* trace = nullptr) const {
        return boxes_fn(boxes, options, stats, trace);
    }
};

namespace detail {
template <Scheduler S>
constexpr SchedulerEntry entry() {
    return {S::name,
            [](const TriangleView& m, const BuildOptions& o, BuildStats* s, TraceLog* t) {
                return build<S>(m, o, s, t);
            },
            [](std::span<const Box> b, const BuildOptions& o, BuildStats* s, TraceLog* t) {
                return build<S>(b, o, s, t);
            },
            []() -> std::unique_ptr<WarmBuilder> { return std::make_unique<WarmBuilderOf<S>>(); }};
}
inline constexpr SchedulerEntry kSchedulers[] = {
    entry<Sequential>(),
#if CANOPY_HAVE_OPENMP
    entry<OmpLevels>(),
    entry<OmpQueues>(),
    entry<OmpTasks>(),
#endif
#if CANOPY_HAVE_TBB
    entry<Tbb>(),
#endif
};
}  // namespace detail

// Every scheduler compiled in, sequential first.
inline std::span<const SchedulerEntry> schedulers() { return detail::kSchedulers; }

// nullptr when `name` is not compiled in.
inline const SchedulerEntry* find_scheduler(std::string_view name) {
    for (const auto& e : schedulers())
        if (name == e.name) return &e;
    return nullptr;
}

}  // namespace canopy
