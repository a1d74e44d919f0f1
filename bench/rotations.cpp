// rotations: how much lower canopy's SAH would be after local tree
// rotations (Kensler's, "Tree rotations for improving bounding volume
// hierarchies", 2008), a probe for a later kernel change, not part of the
// build.
//
//   ./build/bench/rotations SCENE... [--min-prims 256,4096,65536] [--passes 2]
//
// For each scene it builds the sequential tree (default options), then for
// each order (post-order: children first, as Kensler; pre-order: the node
// first, then its new children, which is what a build could decide top
// down) and each threshold runs passes over the inner nodes of at least
// that many primitives. At a node with children A and B, the four
// rotations swap A with a child of B or B with a child of A; the one that
// shrinks the surface area of the child whose children changed the most is
// done (the SAH changes only by that area: every other node keeps its box
// and primitives). It prints the SAH (core/sah.h's formula) after each
// pass, the rotations done and the pass's time.
//
// The rotated tree is a valid BVH (checked here: every box holds its
// children's, the leaves keep their primitives) but not in the canonical
// layout (README, "The BVH layout"): swapping two subtrees moves their
// nodes in pre-order. A build would take the decision before the subtrees
// exist, moving the records of the swapped ranges instead (see
// docs/performance-log.md, 2026-12-07 night).
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

    uint32_t count(uint32_t i) {
        const Node& n = nodes[i];
        return prims[i] = n.is_leaf() ? n.count : count(n.index) + count(n.index + 1);
    }

    // The best rotation at inner node i, if one lowers the area: swaps the
    // child at slot `a` with the grandchild at slot `g`, whose parent is the
    // child at slot `p`.
    bool rotate(uint32_t i) {
        const uint32_t first = nodes[i].index;
        float best = 0.0f;
        uint32_t best_a = 0, best_g = 0, best_p = 0;
        for (uint32_t side = 0; side < 2; ++side) {
            const uint32_t a = first + side, p = first + 1 - side;
            if (nodes[p].is_leaf()) continue;
            const float now = half_area(nodes[p].box());
            for (uint32_t k = 0; k < 2; ++k) {
                const uint32_t g = nodes[p].index + k, keep = nodes[p].index + 1 - k;
                const float gain = now - half_area(join(nodes[keep].box(), nodes[a].box()));
                if (gain > best) best = gain, best_a = a, best_g = g, best_p = p;
            }
        }
        if (best <= 0.0f) return false;
        std::swap(nodes[best_a], nodes[best_g]);
        std::swap(prims[best_a], prims[best_g]);
        Node& p = nodes[best_p];
        p.set_box(join(nodes[p.index].box(), nodes[p.index + 1].box()));
        prims[best_p] = prims[p.index] + prims[p.index + 1];
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
    app.add_option("scene", scenes, "Mesh files or gen:NAME:COUNT[:SEED]")->required();
    app.add_option("--min-prims", thresholds, "Rotate only at nodes of at least this many primitives (a list)")
        ->capture_default_str();
    app.add_option("--passes", passes, "Passes over the tree per order and threshold")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100u));
    CLI11_PARSE(app, argc, argv);
    try {
        const std::vector<uint32_t> mins = cli::parse_list(thresholds, "--min-prims");
        for (const std::string& spec : scenes) {
            const TriangleMesh mesh = load_scene(spec).mesh;
            const Bvh built = build<Sequential>(mesh.view(), BuildOptions{});
            const double sah = sah_cost(built);
            std::printf("%s: %zu triangles, %zu nodes, SAH %.4f\n", spec.c_str(), mesh.triangle_count(),
                        built.nodes.size(), sah);
            for (const bool pre_order : {false, true}) {
                for (const uint32_t min_prims : mins) {
                    Bvh bvh = built;
                    Rotator r{bvh.nodes, std::vector<uint32_t>(bvh.nodes.size()), min_prims, pre_order};
                    r.count(0);
                    for (unsigned p = 1; p <= passes; ++p) {
                        const auto t0 = std::chrono::steady_clock::now();
                        const size_t done = r.pass(0);
                        const double ms =
                            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
                        const double now = sah_cost(bvh);
                        std::printf("  %s, nodes of %u+ primitives, pass %u: %zu rotations (%.2f ms), SAH %.4f (%+.2f%%)\n",
                                    pre_order ? "pre-order" : "post-order", min_prims, p, done, ms, now,
                                    100.0 * (now / sah - 1.0));
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
