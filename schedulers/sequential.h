// canopy scheduler: sequential, the reference every other scheduler matches.
//
// A depth-first loop over an explicit stack (core/depth_first.h). When a
// node splits, its child pair is appended to the node array and the left
// child is processed before the right one, which is the canonical layout by
// construction (no placement pass: the parallel schedulers' placement is
// checked against this). The records share the node array's storage: the
// nodes fill it from the front while the build consumes the records, which
// sit at its end.
#pragma once

#include "../core/build.h"
#include "../core/depth_first.h"

#include <vector>

namespace canopy {

struct Sequential {
    static constexpr const char* name = "sequential";

    static void run(BuildState& st) {
        st.stats.threads_used = 1;
        // One-off builds: the records at the end of the node array's storage,
        // the nodes filling it from the front (NodesBeforeRecords). A warm
        // Builder keeps a records array of its own (its tree is swapped out).
        const bool own_records = !st.records_in_tree();
        st.allocate_records_in_tree();
        {
            const TraceScope trace(st.trace, st.n, 0, TraceSpan::Prepare);
            st.finish_prepare(st.prepare_range(0, st.n));
        }
        auto bins = std::make_unique<BinSet>(bins_for(st.n, st.options.bins));  // as many as its root uses
        KernelContext ctx = st.context();
        if (own_records) {
            NodeArray& nodes = st.bvh.nodes;
            nodes.clear();
            // Trees of meshes have 0.97 to 1.09 nodes per primitive with
            // leaves of up to 4 (the shared scenes, the generated sphere and
            // stadium); a tree that needs more than 1.1 grows the array once
            // (1M random small triangles: 1.86).
            nodes.reserve(NodesBeforeRecords::initial_capacity(st.n));
            build_depth_first(ctx, st.root, nodes, *bins, st.stats.skipped, 0);
            return;
        }
        NodesBeforeRecords out(st.bvh.nodes, ctx, st.n);
        build_depth_first(ctx, st.root, out, *bins, st.stats.skipped, 0);
        st.records = nullptr;  // overwritten by nodes, or moved and freed by a growth
    }
};

}  // namespace canopy
