// canopy scheduler: sequential, the reference every other scheduler matches.
//
// A depth-first loop over an explicit stack (core/depth_first.h). When a
// node splits, its child pair is appended to the node array and the left
// child is processed before the right one, which is the canonical layout by
// construction (no placement pass: the parallel schedulers' placement is
// checked against this).
#pragma once

#include "../core/build.h"
#include "../core/depth_first.h"

#include <vector>

namespace canopy {

struct Sequential {
    static constexpr const char* name = "sequential";

    static void run(BuildState& st) {
        st.stats.threads_used = 1;
        st.allocate_records();
        {
            const TraceScope trace(st.trace, st.n, 0, TraceSpan::Prepare);
            st.finish_prepare(st.prepare_range(0, st.n));
        }
        build_subtree(st);
    }

private:
    static void build_subtree(BuildState& st) {
        std::vector<Node>& nodes = st.bvh.nodes;
        nodes.clear();
        // Trees of meshes have 0.97 to 1.09 nodes per primitive with leaves
        // of up to 4 (the shared scenes, the generated sphere and stadium);
        // a tree that needs more than 1.1 grows the array once (1M random
        // small triangles: 1.86). 1.1 keeps a build's peak below 72 bytes
        // per primitive: records 32, permutation 4, nodes 35.2.
        reserve_on_huge_pages(nodes, size_t(st.n) + st.n / 10 + 64);
        auto bins = std::make_unique<BinSet>();
        build_depth_first(st.context(), st.root, nodes, *bins, st.stats.skipped, 0);
    }
};

}  // namespace canopy
