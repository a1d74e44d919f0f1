// canopy: what one build owns while it runs, shared by every scheduler.
#pragma once

#include "bvh.h"
#include "kernel.h"
#include "memory.h"
#include "mesh.h"
#include "options.h"
#include "primitives.h"
#include "trace.h"
#include "workers.h"

#include <cstdint>
#include <memory>
#include <span>

namespace canopy {

// Counters a build reports besides the tree.
struct BuildStats {
    SkipCounts skipped;
    uint32_t threads_used = 1;  // threads the scheduler actually ran on
};

// An array that is not zero-filled on allocation (every slot is written by
// the build before it is read), on huge pages where the system allows.
// allocate() keeps the memory it has when that is big enough (warm builds).
template <class T>
struct RawArray {
    std::unique_ptr<T[]> data;
    size_t capacity = 0;
    void allocate(size_t n) {
        if (n <= capacity && data) return;
        data.reset();  // the old array goes before the new one comes
        data.reset(new T[n]);
        capacity = n;
        advise_huge_pages(data.get(), n * sizeof(T));
    }
    T* get() const { return data.get(); }
    void release() {
        data.reset();
        capacity = 0;
    }
};

struct BuildState {
    BuildOptions options;
    uint32_t threads = 1;  // upper bound asked for (resolved, >= 1)
    uint32_t n = 0;

    const TriangleView* mesh = nullptr;  // one of mesh / boxes is the input
    std::span<const Box> boxes;

    RawArray<PrimRef> refs;     // the records, partitioned in place
    Workers workers;            // the parallel drivers' per-thread scratch
    bool keep_memory = false;   // a warm Builder's state: release nothing early
    Bvh bvh;
    NodeTask root;
    BuildStats stats;
    TraceLog* trace = nullptr;  // optional

    KernelContext context() { return {refs.get(), bvh.permutation.data(), &options, trace}; }

    // Frees the records once the tree no longer needs them, unless the state
    // is kept for further builds.
    void release_records() {
        if (keep_memory) return;
        refs.release();
    }

    // Computes refs[first, last) from primitives first..last-1.
    PrepareSummary prepare_range(size_t first, size_t last) {
        return mesh ? prepare_triangles(*mesh, first, last, refs.get())
                    : prepare_boxes(boxes, first, last, refs.get());
    }
    // Throws for the lowest rejected primitive; otherwise sets up the root.
    void finish_prepare(const PrepareSummary& s) {
        if (s.first_bad != PrepareSummary::kNone) {
            if (mesh) throw_bad_triangle(*mesh, s.first_bad);
            throw_bad_box(boxes, s.first_bad);
        }
        root = NodeTask{};
        root.begin = 0;
        root.end = n;
        root.bounds = s.bounds;
        root.cbounds = s.cbounds;
        root.max_area = s.max_area;
    }
};

}  // namespace canopy
