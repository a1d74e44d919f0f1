// canopy: what one build owns while it runs, shared by every scheduler.
#pragma once

#include "bvh.h"
#include "depth_first.h"
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

    RawArray<PrimRef> refs;     // the records' own array (see allocate_records())
    PrimRef* records = nullptr; // the records, partitioned in place
    Workers workers;            // the parallel drivers' per-thread scratch
    bool keep_memory = false;   // a warm Builder's state: release nothing early
    Bvh bvh;
    NodeTask root;
    BuildStats stats;
    TraceLog* trace = nullptr;  // optional
    CarriedSplits carried;      // splits chosen for tasks not yet run (kernel/rotate.h)

    // `threads`: how many work on the records (KernelContext::shared).
    KernelContext context(uint32_t threads = 1) {
        return {records, bvh.permutation.data(), &options, trace, threads > 1, &carried};
    }

    // The records in an array of their own: the sequential layout, whose
    // nodes are written while the records are in use.
    void allocate_records() {
        refs.allocate(n);
        records = refs.get();
    }
    // The sequential layout's records at the end of the node array's storage
    // (`capacity` nodes), which the nodes fill from the front as the build
    // consumes the records (NodesBeforeRecords in core/depth_first.h).
    void allocate_records_after_nodes(size_t capacity) {
        // bvh.nodes is empty (build_into()); NodeArray advises huge pages itself.
        bvh.nodes.reserve(capacity);
        records = NodesBeforeRecords::records_at_end(bvh.nodes.data(), bvh.nodes.capacity(), n);
    }
    // The parallel drivers' records, in the storage of the final node array
    // (bvh.nodes' capacity: NodesBeforeRecords::initial_capacity(), 1.1
    // nodes per record and a few, the records at its end): each inline
    // subtree's nodes are written over its own records once it is built,
    // and the placement moves them to the front of the same storage
    // (sched::run_subtree_over_records(), place_over_records() in
    // core/layout.h), so that a one-off build holds its tree once, in memory
    // the records had already brought in. (Until 2026-12-05 the subtrees'
    // nodes went to per-worker chunks and were copied into the final array:
    // the tree was held twice, and fresh memory, slow to hand out on
    // virtual machines, was written twice.) A warm Builder keeps the
    // records' own array, since its tree is swapped out.
    void allocate_records_in_tree() {
        if (!records_in_tree()) return allocate_records();
        allocate_records_after_nodes(NodesBeforeRecords::initial_capacity(n));
    }

    // Whether allocate_records_in_tree() puts the records in bvh.nodes'
    // storage (a one-off build) rather than in an array of their own.
    bool records_in_tree() const { return !keep_memory; }

    // Computes records[first, last) from primitives first..last-1.
    PrepareSummary prepare_range(size_t first, size_t last) {
        return mesh ? prepare_triangles(*mesh, first, last, records)
                    : prepare_boxes(boxes, first, last, records);
    }
    // Throws for the lowest rejected primitive; otherwise sets up the root.
    void finish_prepare(const PrepareSummary& s) {
        if (s.first_bad != PrepareSummary::kNone) {
            if (mesh) throw_bad_triangle(*mesh, s.first_bad);
            throw_bad_box(boxes, s.first_bad);
        }
        carried.clear();
        root = NodeTask{};
        root.begin = 0;
        root.end = n;
        root.bounds = s.bounds;
        root.cbounds = s.cbounds;
        root.max_area = s.max_area;
    }
};

}  // namespace canopy
