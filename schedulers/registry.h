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

#include <span>
#include <string>
#include <string_view>

namespace canopy {

struct SchedulerEntry {
    const char* name;
    Bvh (*build_triangles)(const TriangleView&, const BuildOptions&, BuildStats*);
    Bvh (*build_boxes)(std::span<const Box>, const BuildOptions&, BuildStats*);
};

namespace detail {
template <Scheduler S>
constexpr SchedulerEntry entry() {
    return {S::name,
            [](const TriangleView& m, const BuildOptions& o, BuildStats* s) { return build<S>(m, o, s); },
            [](std::span<const Box> b, const BuildOptions& o, BuildStats* s) { return build<S>(b, o, s); }};
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
