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
        st.finish_prepare(st.prepare_range(0, st.n));
        build_subtree(st);
    }

private:
    static void build_subtree(BuildState& st) {
        std::vector<Node>& nodes = st.bvh.nodes;
        nodes.clear();
        // Typical trees have 0.9 to 1.1 nodes per primitive (leaves of up to
        // 4); a tree that needs more grows the array once.
        reserve_on_huge_pages(nodes, size_t(st.n) + st.n / 8 + 64);
        auto bins = std::make_unique<BinSet>();
        build_depth_first(st.context(), st.root, nodes, *bins, st.stats.skipped, 0);
    }
};

}  // namespace canopy
