#include "sah.h"

#include <algorithm>
#include <vector>

namespace canopy {

double sah_cost(const Bvh& bvh) {
    if (bvh.nodes.empty()) return 0.0;
    double sum = 0.0;
    for (const Node& n : bvh.nodes) {
        const double a = n.box().half_area();
        sum += n.is_leaf() ? a * double(n.count) : a;
    }
    const double root = bvh.nodes[0].box().half_area();
    return root > 0.0 ? sum / root : sum;
}

TreeStats tree_stats(const Bvh& bvh) {
    TreeStats s;
    s.nodes = static_cast<uint32_t>(bvh.nodes.size());
    if (bvh.nodes.empty()) return s;
    struct Item {
        uint32_t node, depth;
    };
    std::vector<Item> stack{{0, 0}};
    while (!stack.empty()) {
        const Item it = stack.back();
        stack.pop_back();
        const Node& n = bvh.nodes[it.node];
        s.depth = std::max(s.depth, it.depth);
        if (n.is_leaf()) {
            ++s.leaves;
            if (s.leaf_size_histogram.size() <= n.count) s.leaf_size_histogram.resize(n.count + 1, 0);
            ++s.leaf_size_histogram[n.count];
        } else if (n.index + 1 < bvh.nodes.size()) {
            stack.push_back({n.index, it.depth + 1});
            stack.push_back({n.index + 1, it.depth + 1});
        }
    }
    return s;
}

}  // namespace canopy
