// canopy scheduler: sequential, the reference every other scheduler matches.
//
// A depth-first loop over an explicit stack. When a node splits, its child
// pair is appended to the node array and the left child is processed before
// the right one, which is the canonical layout by construction (no
// arithmetic placement: the parallel schedulers' placement is checked
// against this).
#pragma once

#include "../core/build.h"

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
        const KernelContext ctx = st.context();
        std::vector<Node>& nodes = st.bvh.nodes;
        nodes.clear();
        nodes.reserve(st.n);  // typical trees need fewer; it grows if not
        advise_huge_pages(nodes.data(), nodes.capacity() * sizeof(Node));
        nodes.emplace_back();
        auto bins = std::make_unique<BinSet>();
        struct Item {
            NodeTask task;
            uint32_t node;
        };
        // One pending right child per level at most.
        std::vector<Item> stack;
        stack.reserve(st.options.max_depth + 2);
        stack.push_back({st.root, 0});
        NodeTask children[2];
        while (!stack.empty()) {
            const Item it = stack.back();
            stack.pop_back();
            // Traced like the parallel schedulers' tasks: nodes above the cutoff.
            const TraceScope trace(it.task.size() < st.options.tuning.task_cutoff ? nullptr : ctx.trace, it.task, 0,
                                   TraceSpan::Task);
            const bool split = run_node(ctx, it.task, children, *bins, st.stats.skipped);
            Node& node = nodes[it.node];
            node.set_box(it.task.bounds);
            if (!split) {
                node.index = it.task.begin;
                node.count = it.task.size();
                continue;
            }
            const uint32_t c = static_cast<uint32_t>(nodes.size());
            node.index = c;
            node.count = 0;
            nodes.emplace_back();  // `node` is not used past this point
            nodes.emplace_back();
            stack.push_back({children[1], c + 1});
            stack.push_back({children[0], c});
        }
    }
};

}  // namespace canopy
