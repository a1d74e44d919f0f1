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

    KernelContext context() { return {records, bvh.permutation.data(), &options, trace}; }

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
        // bvh.nodes is empty (build_into()).
        reserve_on_huge_pages(bvh.nodes, capacity);
        records = NodesBeforeRecords::records_at_end(bvh.nodes.data(), bvh.nodes.capacity(), n);
    }
    // The parallel drivers' records, in the storage of the final node array
    // (bvh.nodes' capacity, one 32-byte node per record): their nodes go
    // to per-worker chunks during the build and are copied into the final
    // array only once the records are no longer needed, and when the tree
    // has no more nodes than primitives (the meshes' trees: 0.97 to 1.09 per
    // triangle) that copy then writes memory the records had already
    // brought in, instead of fresh memory (finish_parallel() allocates anew
    // when the tree needs more). Fresh memory is slow to hand out on virtual
    // machines, and slower still at times: the placement of the 4M sphere's
    // tree at 2 threads (tbb, timed inside the build, 18 builds of each
    // version alternated, Intel host, 2026-12-04) took 9.98 to 13.7 ms this
    // way, against 19.6 to 387 ms (median 101) into fresh memory. A warm
    // Builder keeps the records' own array, since its tree is swapped out.
    void allocate_records_in_tree() {
        if (keep_memory) return allocate_records();
        // One node more than records: the vector's storage is 16-byte
        // aligned, the records want 32.
        allocate_records_after_nodes(size_t(n) + 1);
    }

    // Frees the records once the tree no longer needs them, unless the state
    // is kept for further builds. (Records kept in the final node array's
    // storage are overwritten by the placement.)
    void release_records() {
        if (keep_memory) return;
        refs.release();
        records = nullptr;
    }

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
        root = NodeTask{};
        root.begin = 0;
        root.end = n;
        root.bounds = s.bounds;
        root.cbounds = s.cbounds;
        root.max_area = s.max_area;
    }
};

}  // namespace canopy
