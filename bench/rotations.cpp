// rotations: how much lower canopy's SAH would be after local tree
// rotations (Kensler's, "Tree rotations for improving bounding volume
// hierarchies", 2008) of the finished tree: the probe that led to the
// build's own rotations (core/kernel/rotate.h), kept to see what is left.
//
//   ./build/bench/rotations SCENE... [--min-prims 256,4096,65536] [--passes 2]
//                                    [--build-rotate-min 0]
//
// For each scene it builds the sequential tree (default options, but the
// build's own rotations off unless --build-rotate-min says), then for
// each order (post-order: children first, as Kensler; pre-order: the node
// first, then its new children, which is what a build could decide top
// down) and each threshold runs passes over the inner nodes of at least
// that many primitives. At a node with children A and B, the four
// rotations swap A with a child of B or B with a child of A; the one that
// shrinks the surface area of the child whose children changed the most is
// done (the SAH changes only by that area: every other node keeps its box
// and primitives). It prints the SAH (core/sah.h's formula) after each
// pass, the rotations done, the pass's time, and how many records a build
// would move to take them (the swapped subtrees' primitives).
//
// The rotated tree is a valid BVH (checked here: every box holds its
// children's, the leaves keep their primitives) but not in the canonical
// layout (README, "The BVH layout"): swapping two subtrees moves their
// nodes in pre-order. The build takes the decision before the subtrees
// exist, moving the records of the swapped ranges instead (see
// docs/performance-log.md, 2026-12-07 night and 2026-12-08).
#include "core/sah.h"
#include "core/scene.h"
#include "schedulers/registry.h"
#include "tools/cli.h"

#include <chrono>
#include <cstdio>
#include <utility>
#include <vector>

namespace {

using namespace canopy;

float half_area(const Box& b) {
    const Vec3 d = b.hi - b.lo;
    return d.x * d.y + d.y * d.z + d.z * d.x;
}

Box join(Box a, const Box& b) {
    a.extend(b);
    return a;
}

struct Rotator {
    NodeArray& nodes;
    std::vector<uint32_t> prims;  // primitives below each node
    uint32_t min_prims;
    bool pre_order;
    // Records a build would move to take the rotations. A node's children
    // hold their subtrees in record order here (the left child's records
    // first), as in a build. A rotation regroups three subtrees T0 T1 T2
    // (in record order): when the one left alone is T0 or T2 it is only a
    // regrouping ((T0 T1) T2 <-> T0 (T1 T2)) and moves nothing; when it is
    // T1, two adjacent ranges trade places, the cheaper pair.
    uint64_t moved = 0;

    uint32_t count(uint32_t i) {
        const Node& n = nodes[i];
        return prims[i] = n.is_leaf() ? n.count : count(n.index) + count(n.index + 1);
    }

    // The best rotation at inner node i, if one lowers the area: the child
    // at slot `a` trades places with the grandchild at slot `g`, whose
    // parent is the child at slot `p`.
    bool rotate(uint32_t i) {
        const uint32_t first = nodes[i].index;
        float best = 0.0f;
        uint32_t best_g = 0, best_p = 0;
        for (uint32_t side = 0; side < 2; ++side) {
            const uint32_t a = first + side, p = first + 1 - side;
            if (nodes[p].is_leaf()) continue;
            const float now = half_area(nodes[p].box());
            for (uint32_t k = 0; k < 2; ++k) {
                const uint32_t g = nodes[p].index + k, keep = nodes[p].index + 1 - k;
                const float gain = now - half_area(join(nodes[keep].box(), nodes[a].box()));
                if (gain > best) best = gain, best_g = g, best_p = p;
            }
        }
        if (best <= 0.0f) return false;
        // The three subtrees in record order, their slots, and which one
        // ends up alone (the grandchild).
        const uint32_t pair = nodes[best_p].index;
        const uint32_t slot[3] = {best_p == first ? pair : first, best_p == first ? pair + 1 : pair,
                                  best_p == first ? first + 1 : pair + 1};
        const Node inner = nodes[best_p];
        Node t[3];
        uint32_t n[3];
        for (int k = 0; k < 3; ++k) t[k] = nodes[slot[k]], n[k] = prims[slot[k]];
        const int alone = best_g == slot[0] ? 0 : best_g == slot[1] ? 1 : 2;
        int order[3] = {0, 1, 2};
        bool left_grouped = alone == 2;
        if (alone == 1) {
            if (n[1] + n[2] <= n[0] + n[1]) {  // T0 T2 T1: ((T0 T2) T1)
                order[1] = 2, order[2] = 1, left_grouped = true;
                moved += uint64_t(n[1]) + n[2];
            } else {  // T1 T0 T2: (T1 (T0 T2))
                order[0] = 1, order[1] = 0, left_grouped = false;
                moved += uint64_t(n[0]) + n[1];
            }
        }
        // The new inner node takes the old one's child-pair slots.
        const int x0 = left_grouped ? order[0] : order[1], x1 = left_grouped ? order[1] : order[2];
        const int single = left_grouped ? order[2] : order[0];
        Node x = inner;
        x.set_box(join(t[x0].box(), t[x1].box()));
        nodes[pair] = t[x0], prims[pair] = n[x0];
        nodes[pair + 1] = t[x1], prims[pair + 1] = n[x1];
        const uint32_t x_slot = left_grouped ? first : first + 1;
        nodes[x_slot] = x, prims[x_slot] = n[x0] + n[x1];
        nodes[left_grouped ? first + 1 : first] = t[single];
        prims[left_grouped ? first + 1 : first] = n[single];
        return true;
    }

    size_t pass(uint32_t i) {
        if (nodes[i].is_leaf() || prims[i] < min_prims) return 0;
        size_t done = 0;
        if (!pre_order) done += pass(nodes[i].index) + pass(nodes[i].index + 1);
        done += rotate(i);
        if (pre_order) done += pass(nodes[i].index) + pass(nodes[i].index + 1);
        return done;
    }
};

// Every box holds its children's and every primitive is in exactly one
// leaf of the permutation's slots.
bool still_valid(const Bvh& bvh) {
    std::vector<uint8_t> seen(bvh.permutation.size(), 0);
    std::vector<uint32_t> stack{0};
    while (!stack.empty()) {
        const Node& n = bvh.nodes[stack.back()];
        stack.pop_back();
        if (n.is_leaf()) {
            for (uint32_t s = n.index; s < n.index + n.count; ++s)
                if (seen[s]++) return false;
            continue;
        }
        for (uint32_t c = n.index; c < n.index + 2; ++c) {
            const Box inner = bvh.nodes[c].box(), outer = n.box();
            for (int a = 0; a < 3; ++a)
                if (inner.lo[a] < outer.lo[a] || inner.hi[a] > outer.hi[a]) return false;
            stack.push_back(c);
        }
    }
    for (uint8_t s : seen)
        if (s != 1) return false;
    return true;
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"SAH after local tree rotations of canopy's tree (a probe)"};
    std::vector<std::string> scenes;
    std::string thresholds = "256,4096,65536";
    unsigned passes = 2;
    uint32_t build_rotate_min = 0;
    app.add_option("scene", scenes, "Mesh files or gen:NAME:COUNT[:SEED]")->required();
    app.add_option("--min-prims", thresholds, "Rotate only at nodes of at least this many primitives (a list)")
        ->capture_default_str();
    app.add_option("--passes", passes, "Passes over the tree per order and threshold")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100u));
    app.add_option("--build-rotate-min", build_rotate_min,
                   "The build's own rotations (BuildOptions::rotate_min; 0 = none)")
        ->capture_default_str();
    CLI11_PARSE(app, argc, argv);
    try {
        const std::vector<uint32_t> mins = cli::parse_list(thresholds, "--min-prims");
        for (const std::string& spec : scenes) {
            const TriangleMesh mesh = load_scene(spec).mesh;
            BuildOptions opt;
            opt.rotate_min = build_rotate_min;
            const Bvh built = build<Sequential>(mesh.view(), opt);
            const double sah = sah_cost(built);
            std::printf("%s: %zu triangles, %zu nodes, SAH %.4f\n", spec.c_str(), mesh.triangle_count(),
                        built.nodes.size(), sah);
            for (const bool pre_order : {false, true}) {
                for (const uint32_t min_prims : mins) {
                    Bvh bvh = built;
                    Rotator r{bvh.nodes, std::vector<uint32_t>(bvh.nodes.size()), min_prims, pre_order, 0};
                    r.count(0);
                    for (unsigned p = 1; p <= passes; ++p) {
                        const auto t0 = std::chrono::steady_clock::now();
                        const size_t done = r.pass(0);
                        const double ms =
                            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
                        const double now = sah_cost(bvh);
                        std::printf(
                            "  %s, nodes of %u+ primitives, pass %u: %zu rotations (%.2f ms), SAH %.4f (%+.2f%%), "
                            "%.3f records moved per triangle so far\n",
                            pre_order ? "pre-order" : "post-order", min_prims, p, done, ms, now,
                            100.0 * (now / sah - 1.0), double(r.moved) / double(mesh.triangle_count()));
                    }
                    if (!still_valid(bvh)) {
                        std::fprintf(stderr, "rotations: the rotated tree of %s is not a valid BVH\n", spec.c_str());
                        return 1;
                    }
                }
            }
            std::fflush(stdout);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "rotations: %s\n", e.what());
        return 1;
    }
    return 0;
}
