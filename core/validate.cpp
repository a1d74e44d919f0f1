#include "validate.h"

#include <cstdint>
#include <sstream>
#include <vector>

namespace canopy {

namespace {

constexpr size_t kMaxProblems = 1000;

std::string box_str(const Box& b) {
    std::ostringstream os;
    os.precision(9);
    os << '(' << b.lo.x << ", " << b.lo.y << ", " << b.lo.z << ")-(" << b.hi.x << ", " << b.hi.y << ", "
       << b.hi.z << ')';
    return os.str();
}

// `prim_box(id, box)` returns false when primitive `id` has no valid box.
template <class PrimBox>
ValidationReport validate_impl(const Bvh& bvh, size_t n, const BuildOptions& opt, PrimBox&& prim_box) {
    ValidationReport rep;
    auto problem = [&](const std::string& s) {
        if (rep.problems.size() < kMaxProblems) rep.problems.push_back(s);
        else if (rep.problems.size() == kMaxProblems) rep.problems.push_back("... (more problems not listed)");
    };
    const auto& nodes = bvh.nodes;
    const auto& perm = bvh.permutation;
    if (perm.size() != n)
        problem("permutation has " + std::to_string(perm.size()) + " entries for " + std::to_string(n) +
                " primitives");
    if (n == 0 || nodes.empty()) {
        if (n != 0) problem("no nodes for " + std::to_string(n) + " primitives");
        if (!nodes.empty()) problem("an empty input must give no nodes, got " + std::to_string(nodes.size()));
        return rep;
    }
    // Every primitive referenced exactly once.
    std::vector<uint8_t> seen(n, 0);
    for (size_t i = 0; i < perm.size(); ++i) {
        const uint32_t id = perm[i];
        if (id >= n) {
            problem("permutation[" + std::to_string(i) + "] = " + std::to_string(id) + " is out of range");
            continue;
        }
        if (seen[id]++) problem("primitive " + std::to_string(id) + " is referenced more than once");
    }
    for (size_t id = 0; id < n; ++id)
        if (!seen[id]) problem("primitive " + std::to_string(id) + " is not referenced");

    // Walk in canonical order: depth-first, left first. Child pairs must be
    // allocated in that order, and leaves must tile the permutation in it.
    struct Item {
        uint32_t node;
        uint32_t depth;
    };
    std::vector<Item> stack{{0, 0}};
    std::vector<uint8_t> visited(nodes.size(), 0);
    uint64_t next_pair = 1;
    uint64_t next_leaf_begin = 0;
    uint32_t max_depth_seen = 0;
    while (!stack.empty()) {
        const Item it = stack.back();
        stack.pop_back();
        const std::string where = "node " + std::to_string(it.node);
        if (visited[it.node]++) {
            problem(where + " is reached twice");
            continue;
        }
        const Node& nd = nodes[it.node];
        const Box box = nd.box();
        if (it.depth > max_depth_seen) max_depth_seen = it.depth;
        if (it.depth > opt.max_depth)
            problem(where + " is at depth " + std::to_string(it.depth) + " beyond max_depth " +
                    std::to_string(opt.max_depth));
        if (nd.is_leaf()) {
            if (nd.count > opt.max_leaf)
                problem(where + ": leaf of " + std::to_string(nd.count) + " primitives exceeds max_leaf " +
                        std::to_string(opt.max_leaf));
            if (nd.index != next_leaf_begin)
                problem(where + ": leaf starts at permutation slot " + std::to_string(nd.index) +
                        ", the canonical layout needs " + std::to_string(next_leaf_begin));
            if (uint64_t(nd.index) + nd.count > perm.size()) {
                problem(where + ": leaf range [" + std::to_string(nd.index) + ", " +
                        std::to_string(uint64_t(nd.index) + nd.count) + ") is past the permutation");
                continue;
            }
            next_leaf_begin = uint64_t(nd.index) + nd.count;
            for (uint32_t k = nd.index; k < nd.index + nd.count; ++k) {
                const uint32_t id = perm[k];
                if (id >= n) continue;
                Box pb;
                if (!prim_box(id, pb)) {
                    problem("primitive " + std::to_string(id) + " has no valid box");
                    continue;
                }
                if (!box.contains(pb))
                    problem(where + " " + box_str(box) + " does not contain primitive " + std::to_string(id) +
                            " " + box_str(pb));
            }
            continue;
        }
        if (nd.index != next_pair)
            problem(where + ": first child at " + std::to_string(nd.index) + ", the canonical layout needs " +
                    std::to_string(next_pair));
        if (uint64_t(nd.index) + 1 >= nodes.size() || nd.index == 0) {
            problem(where + ": child index " + std::to_string(nd.index) + " is out of range");
            continue;
        }
        next_pair = uint64_t(nd.index) + 2;
        for (uint32_t k = 0; k < 2; ++k) {
            const Box cb = nodes[nd.index + k].box();
            if (!box.contains(cb))
                problem(where + " " + box_str(box) + " does not contain its child " +
                        std::to_string(nd.index + k) + " " + box_str(cb));
        }
        stack.push_back({nd.index + 1, it.depth + 1});
        stack.push_back({nd.index, it.depth + 1});
    }
    if (next_leaf_begin != perm.size())
        problem("leaves cover " + std::to_string(next_leaf_begin) + " of " + std::to_string(perm.size()) +
                " permutation slots");
    if (next_pair != nodes.size())
        problem("the tree uses " + std::to_string(next_pair) + " node slots but the array has " +
                std::to_string(nodes.size()));
    for (size_t i = 0; i < nodes.size(); ++i)
        if (!visited[i]) {
            problem("node " + std::to_string(i) + " is not reachable from the root");
            break;
        }
    return rep;
}

}  // namespace

std::string ValidationReport::summary(size_t max_lines) const {
    if (problems.empty()) return "valid";
    std::string s = std::to_string(problems.size()) + " problem(s):";
    for (size_t i = 0; i < problems.size() && i < max_lines; ++i) s += "\n  " + problems[i];
    if (problems.size() > max_lines) s += "\n  ...";
    return s;
}

ValidationReport validate(const Bvh& bvh, const TriangleView& mesh, const BuildOptions& options) {
    const size_t nv = mesh.vertices.size();
    return validate_impl(bvh, mesh.triangle_count(), options, [&](uint32_t id, Box& b) {
        b = Box{};
        for (int k = 0; k < 3; ++k) {
            const uint32_t vi = mesh.indices[3 * size_t(id) + k];
            if (vi >= nv) return false;
            b.extend(mesh.vertices[vi]);
        }
        return true;
    });
}

ValidationReport validate(const Bvh& bvh, std::span<const Box> boxes, const BuildOptions& options) {
    return validate_impl(bvh, boxes.size(), options, [&](uint32_t id, Box& b) {
        b = boxes[id];
        return !b.is_empty();
    });
}

}  // namespace canopy
