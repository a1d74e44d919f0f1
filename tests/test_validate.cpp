// Tests of core/validate.h (and core/sah.h): valid trees pass, and each kind
// of corruption of a valid tree is reported with its own message.
#include "core/bvh.h"
#include "core/mesh.h"
#include "core/options.h"
#include "core/sah.h"
#include "core/validate.h"
#include "schedulers/sequential.h"
#include "test_util.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <span>
#include <string>
#include <vector>

using canopy::BuildOptions;
using canopy::Bvh;
using canopy::Box;
using canopy::Node;
using canopy::TriangleMesh;
using canopy::ValidationReport;
using canopy::Vec3;

namespace {

using canopy::test_util::coincident_mesh;
using canopy::test_util::grid_mesh;
using canopy::test_util::random_mesh;
using canopy::test_util::uniform;

constexpr float kInf = std::numeric_limits<float>::infinity();

// `clusters` groups of `per` coincident triangles, far apart along x.
TriangleMesh clustered_mesh(uint32_t clusters, uint32_t per) {
    TriangleMesh m;
    for (uint32_t c = 0; c < clusters; ++c) {
        const uint32_t base = uint32_t(m.vertices.size());
        const float x = 100.0f * float(c);
        m.vertices.insert(m.vertices.end(), {Vec3(x, 0, 0), Vec3(x + 1, 0, 0), Vec3(x, 1, 1)});
        for (uint32_t k = 0; k < per; ++k) m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
    }
    return m;
}

Bvh build(const TriangleMesh& m, const BuildOptions& opt = {}) {
    return canopy::build<canopy::Sequential>(m.view(), opt);
}

bool mentions(const ValidationReport& r, const std::string& what) {
    for (const std::string& p : r.problems)
        if (p.find(what) != std::string::npos) return true;
    return false;
}

// The report is not ok and one of its problems contains `what`.
::testing::AssertionResult rejects(const ValidationReport& r, const std::string& what) {
    if (r.ok()) return ::testing::AssertionFailure() << "the tree was accepted (expected: " << what << ")";
    if (!mentions(r, what))
        return ::testing::AssertionFailure() << "no problem mentions \"" << what << "\": " << r.summary();
    return ::testing::AssertionSuccess();
}

// Box of triangle t as validate computes it.
Box triangle_box(const TriangleMesh& m, uint32_t t) {
    Box b;
    for (int k = 0; k < 3; ++k) b.extend(m.vertex(t, k));
    return b;
}

// Index of the first leaf / inner node, and the parent of a node.
uint32_t first_leaf(const Bvh& b) {
    for (uint32_t i = 0; i < b.nodes.size(); ++i)
        if (b.nodes[i].is_leaf()) return i;
    return ~0u;
}
uint32_t parent_of(const Bvh& b, uint32_t child) {
    for (uint32_t i = 0; i < b.nodes.size(); ++i)
        if (!b.nodes[i].is_leaf() && (b.nodes[i].index == child || b.nodes[i].index + 1 == child)) return i;
    return ~0u;
}

}  // namespace

// ---------------------------------------------------------------- valid trees

TEST(ValidateAccepts, SequentialTreesOnSmallMeshes) {
    const TriangleMesh meshes[] = {random_mesh(1, 1),    random_mesh(2, 2),       random_mesh(7, 3),
                                   random_mesh(500, 4),  grid_mesh(1),            grid_mesh(12),
                                   coincident_mesh(1),   coincident_mesh(3),      coincident_mesh(100),
                                   clustered_mesh(9, 7)};
    for (uint32_t max_leaf : {1u, 4u, 16u}) {
        BuildOptions opt;
        opt.max_leaf = max_leaf;
        for (const TriangleMesh& m : meshes) {
            const Bvh b = build(m, opt);
            const ValidationReport r = canopy::validate(b, m.view(), opt);
            EXPECT_TRUE(r.ok()) << "n=" << m.triangle_count() << " max_leaf=" << max_leaf << ": "
                                << r.summary();
            EXPECT_EQ(r.summary(), "valid");
            EXPECT_EQ(b.permutation.size(), m.triangle_count());
            EXPECT_FALSE(b.nodes.empty());
        }
    }
}

TEST(ValidateAccepts, EmptyInput) {
    const TriangleMesh m;
    const Bvh b = build(m);
    EXPECT_TRUE(b.empty());
    EXPECT_TRUE(b.nodes.empty());
    EXPECT_TRUE(b.permutation.empty());
    EXPECT_TRUE(canopy::validate(b, m.view()).ok());
    const std::vector<Box> none;
    EXPECT_TRUE(canopy::validate(b, std::span<const Box>(none)).ok());

    // An empty tree for a non-empty input is not valid, nor nodes for none.
    const TriangleMesh one = random_mesh(1, 9);
    EXPECT_TRUE(rejects(canopy::validate(b, one.view()), "no nodes"));
    const Bvh full = build(one);
    Bvh nodes_only = full;
    nodes_only.permutation.clear();
    EXPECT_TRUE(rejects(canopy::validate(nodes_only, m.view()), "an empty input must give no nodes"));
}

TEST(ValidateAccepts, BoxOverload) {
    std::mt19937 rng(42);
    std::vector<Box> boxes;
    for (int i = 0; i < 400; ++i) {
        Box b;
        b.lo = Vec3(uniform(rng, -50, 50), uniform(rng, -50, 50), uniform(rng, -50, 50));
        b.hi = b.lo + Vec3(uniform(rng, 0, 3), uniform(rng, 0, 3), uniform(rng, 0, 3));
        boxes.push_back(b);
    }
    boxes.push_back(Box{Vec3(-0.0f), Vec3(0.0f)});  // a point box with -0
    for (uint32_t max_leaf : {1u, 4u}) {
        BuildOptions opt;
        opt.max_leaf = max_leaf;
        const Bvh b = canopy::build<canopy::Sequential>(std::span<const Box>(boxes), opt);
        EXPECT_TRUE(canopy::validate(b, std::span<const Box>(boxes), opt).ok());
    }

    const Bvh b = canopy::build<canopy::Sequential>(std::span<const Box>(boxes));
    // A primitive box that no longer fits in its leaf.
    std::vector<Box> moved = boxes;
    moved[b.permutation[0]].hi.x += 1000.0f;
    EXPECT_TRUE(rejects(canopy::validate(b, std::span<const Box>(moved)), "does not contain primitive"));
    // A primitive without a valid box.
    std::vector<Box> inverted = boxes;
    std::swap(inverted[5].lo, inverted[5].hi);
    EXPECT_TRUE(rejects(canopy::validate(b, std::span<const Box>(inverted)), "primitive 5 has no valid box"));
    // One primitive too many / too few.
    std::vector<Box> more = boxes;
    more.push_back(boxes[0]);
    EXPECT_TRUE(rejects(canopy::validate(b, std::span<const Box>(more)), "permutation has"));
    EXPECT_TRUE(rejects(canopy::validate(b, std::span<const Box>(more)), "is not referenced"));
}

// ---------------------------------------------------------------- corruptions

class ValidateRejects : public ::testing::Test {
protected:
    void SetUp() override {
        mesh_ = random_mesh(300, 17);
        opt_.max_leaf = 4;
        tree_ = build(mesh_, opt_);
        ASSERT_TRUE(canopy::validate(tree_, mesh_.view(), opt_).ok());
        ASSERT_GT(tree_.nodes.size(), 7u);
    }
    ValidationReport check(const Bvh& b) const { return canopy::validate(b, mesh_.view(), opt_); }

    TriangleMesh mesh_;
    BuildOptions opt_;
    Bvh tree_;
};

TEST_F(ValidateRejects, PrimitiveReferencedTwice) {
    Bvh b = tree_;
    const uint32_t lost = b.permutation[1];
    b.permutation[1] = b.permutation[0];
    const ValidationReport r = check(b);
    EXPECT_TRUE(rejects(r, "primitive " + std::to_string(b.permutation[0]) + " is referenced more than once"));
    EXPECT_TRUE(rejects(r, "primitive " + std::to_string(lost) + " is not referenced"));
}

TEST_F(ValidateRejects, IdOutOfRange) {
    Bvh b = tree_;
    b.permutation[10] = 300;
    EXPECT_TRUE(rejects(check(b), "permutation[10] = 300 is out of range"));
    b.permutation[10] = 0xFFFFFFFFu;
    EXPECT_TRUE(rejects(check(b), "is out of range"));
}

TEST_F(ValidateRejects, LeafBoxShrunkByOneUlp) {
    // Shrink one face of a leaf by one ulp where a primitive touches it.
    for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
            Bvh b = tree_;
            const uint32_t li = first_leaf(b);
            ASSERT_NE(li, ~0u);
            Node& leaf = b.nodes[li];
            // The leaf box is exactly the union of its primitives' boxes.
            Box u;
            for (uint32_t k = leaf.index; k < leaf.index + leaf.count; ++k)
                u.extend(triangle_box(mesh_, b.permutation[k]));
            ASSERT_EQ(leaf.box(), u);
            if (side == 0)
                leaf.min[axis] = std::nextafter(leaf.min[axis], kInf);
            else
                leaf.max[axis] = std::nextafter(leaf.max[axis], -kInf);
            const ValidationReport r = check(b);
            EXPECT_TRUE(rejects(r, "node " + std::to_string(li) + " ")) << axis << side;
            EXPECT_TRUE(rejects(r, "does not contain primitive")) << axis << side;
            EXPECT_FALSE(mentions(r, "does not contain its child")) << r.summary();
        }
}

TEST_F(ValidateRejects, ChildBoxSticksOutOfItsParent) {
    for (uint32_t child : {1u, 2u, uint32_t(tree_.nodes.size() - 1)}) {
        Bvh b = tree_;
        const uint32_t p = parent_of(b, child);
        ASSERT_NE(p, ~0u);
        // Grow the child by one ulp past the parent's face.
        b.nodes[child].max[1] = std::nextafter(b.nodes[p].max[1], kInf);
        const ValidationReport r = check(b);
        EXPECT_TRUE(rejects(r, "node " + std::to_string(p) + " ")) << child;
        EXPECT_TRUE(rejects(r, "does not contain its child " + std::to_string(child))) << child;
    }
}

TEST_F(ValidateRejects, LeafLargerThanMaxLeaf) {
    // Clusters of 6 coincident triangles: with max_leaf 8 each is a leaf of 6.
    const TriangleMesh m = clustered_mesh(10, 6);
    BuildOptions opt8;
    opt8.max_leaf = 8;
    const Bvh b = build(m, opt8);
    ASSERT_TRUE(canopy::validate(b, m.view(), opt8).ok());
    const canopy::TreeStats s = canopy::tree_stats(b);
    ASSERT_GT(s.leaf_size_histogram.size(), 6u);
    ASSERT_GT(s.leaf_size_histogram[6], 0u);
    BuildOptions opt4 = opt8;
    opt4.max_leaf = 4;
    EXPECT_TRUE(rejects(canopy::validate(b, m.view(), opt4), "exceeds max_leaf 4"));
    EXPECT_TRUE(rejects(canopy::validate(b, m.view(), opt4), "leaf of 6 primitives"));
}

TEST_F(ValidateRejects, DepthBeyondMaxDepth) {
    const canopy::TreeStats s = canopy::tree_stats(tree_);
    ASSERT_GE(s.depth, 2u);
    BuildOptions tight = opt_;
    tight.max_depth = s.depth - 1;
    EXPECT_TRUE(rejects(canopy::validate(tree_, mesh_.view(), tight),
                        "is at depth " + std::to_string(s.depth) + " beyond max_depth " +
                            std::to_string(s.depth - 1)));
    tight.max_depth = s.depth;
    EXPECT_TRUE(canopy::validate(tree_, mesh_.view(), tight).ok());
}

TEST_F(ValidateRejects, SwappedChildPairPlacement) {
    // Both children of the root must be inner nodes: the left one's pair is
    // at 3, the right one's pair at P > 3. Swap where the two pairs are
    // stored (fixing the two index fields): the tree still has the same
    // shape and boxes, but the placement is not the canonical pre-order.
    Bvh b = tree_;
    ASSERT_FALSE(b.nodes[0].is_leaf());
    ASSERT_EQ(b.nodes[0].index, 1u);
    ASSERT_FALSE(b.nodes[1].is_leaf());
    ASSERT_FALSE(b.nodes[2].is_leaf());
    const uint32_t l = b.nodes[1].index, r = b.nodes[2].index;
    ASSERT_EQ(l, 3u);
    ASSERT_GT(r, 3u);
    std::swap(b.nodes[l], b.nodes[r]);
    std::swap(b.nodes[l + 1], b.nodes[r + 1]);
    b.nodes[1].index = r;
    b.nodes[2].index = l;
    const ValidationReport rep = check(b);
    EXPECT_TRUE(rejects(rep, "node 1: first child at " + std::to_string(r) + ", the canonical layout needs 3"));
    // Nothing else is wrong with it.
    EXPECT_FALSE(mentions(rep, "does not contain"));
    EXPECT_FALSE(mentions(rep, "referenced"));
    EXPECT_FALSE(mentions(rep, "leaf starts"));

    // Swapping the two children of a pair breaks the leaf order.
    Bvh c = tree_;
    std::swap(c.nodes[1], c.nodes[2]);
    EXPECT_TRUE(rejects(check(c), "the canonical layout needs"));
}

TEST_F(ValidateRejects, UnreachableExtraNode) {
    Bvh b = tree_;
    b.nodes.push_back(b.nodes[1]);
    const ValidationReport r = check(b);
    EXPECT_TRUE(rejects(r, "node " + std::to_string(b.nodes.size() - 1) + " is not reachable from the root"));
    EXPECT_TRUE(rejects(r, "node slots but the array has " + std::to_string(b.nodes.size())));
}

TEST_F(ValidateRejects, OtherStructuralDamage) {
    // A child index out of range.
    Bvh b = tree_;
    b.nodes[0].index = uint32_t(b.nodes.size());
    EXPECT_TRUE(rejects(check(b), "child index"));
    // A cycle back to the root.
    Bvh c = tree_;
    const uint32_t inner = c.nodes[1].is_leaf() ? 2u : 1u;
    ASSERT_FALSE(c.nodes[inner].is_leaf());
    c.nodes[inner].index = 0;
    EXPECT_FALSE(check(c).ok());
    // A leaf range past the permutation.
    Bvh d = tree_;
    const uint32_t li = first_leaf(d);
    d.nodes[li].count = 1000;
    EXPECT_TRUE(rejects(check(d), "is past the permutation"));
    // A permutation that is one short.
    Bvh e = tree_;
    e.permutation.pop_back();
    EXPECT_TRUE(rejects(check(e), "permutation has 299 entries for 300 primitives"));
}

TEST_F(ValidateRejects, SummaryListsProblems) {
    Bvh b = tree_;
    b.permutation[1] = b.permutation[0];
    const ValidationReport r = check(b);
    ASSERT_FALSE(r.ok());
    const std::string s = r.summary();
    EXPECT_NE(s.find(std::to_string(r.problems.size()) + " problem(s):"), std::string::npos) << s;
    EXPECT_NE(s.find(r.problems[0]), std::string::npos);
}

// ---------------------------------------------------------------- sah_cost, tree_stats

namespace {

Node inner(Box b, uint32_t first_child) {
    Node n{};
    n.set_box(b);
    n.index = first_child;
    n.count = 0;
    return n;
}
Node leaf(Box b, uint32_t first, uint32_t count) {
    Node n{};
    n.set_box(b);
    n.index = first;
    n.count = count;
    return n;
}

}  // namespace

TEST(ValidateSah, ThreeNodeTreeHandValue) {
    // Root [0,2]x[0,1]x[0,1]: A = 2 + 1 + 2 = 5. Leaves: [0,1]^3 with 2
    // primitives (A = 3) and [1,2]x[0,1]^2 with 1 (A = 3).
    // (5 + 3 * 2 + 3 * 1) / 5 = 14 / 5.
    Bvh b;
    b.nodes = {inner(Box{Vec3(0, 0, 0), Vec3(2, 1, 1)}, 1), leaf(Box{Vec3(0, 0, 0), Vec3(1, 1, 1)}, 0, 2),
               leaf(Box{Vec3(1, 0, 0), Vec3(2, 1, 1)}, 2, 1)};
    b.permutation = {0, 1, 2};
    EXPECT_DOUBLE_EQ(canopy::sah_cost(b), 14.0 / 5.0);

    // The tree is valid for these primitive boxes.
    const std::vector<Box> boxes = {Box{Vec3(0, 0, 0), Vec3(1, 1, 0.5f)}, Box{Vec3(0.5f, 0, 0), Vec3(1, 1, 1)},
                                    Box{Vec3(1, 0, 0), Vec3(2, 1, 1)}};
    BuildOptions opt;
    EXPECT_TRUE(canopy::validate(b, std::span<const Box>(boxes), opt).ok())
        << canopy::validate(b, std::span<const Box>(boxes), opt).summary();

    const canopy::TreeStats s = canopy::tree_stats(b);
    EXPECT_EQ(s.nodes, 3u);
    EXPECT_EQ(s.leaves, 2u);
    EXPECT_EQ(s.depth, 1u);
    EXPECT_EQ(s.leaf_size_histogram, (std::vector<uint32_t>{0, 1, 1}));
}

TEST(ValidateSah, EdgeCases) {
    EXPECT_EQ(canopy::sah_cost(Bvh{}), 0.0);
    const canopy::TreeStats e = canopy::tree_stats(Bvh{});
    EXPECT_EQ(e.nodes, 0u);
    EXPECT_EQ(e.leaves, 0u);
    EXPECT_EQ(e.depth, 0u);
    EXPECT_TRUE(e.leaf_size_histogram.empty());

    // A single leaf of 7: the cost is 7 (A * 7 / A).
    Bvh one;
    one.nodes = {leaf(Box{Vec3(0, 0, 0), Vec3(3, 1, 2)}, 0, 7)};
    one.permutation = {0, 1, 2, 3, 4, 5, 6};
    EXPECT_DOUBLE_EQ(canopy::sah_cost(one), 7.0);
    const canopy::TreeStats s = canopy::tree_stats(one);
    EXPECT_EQ(s.nodes, 1u);
    EXPECT_EQ(s.leaves, 1u);
    EXPECT_EQ(s.depth, 0u);
    ASSERT_EQ(s.leaf_size_histogram.size(), 8u);
    EXPECT_EQ(s.leaf_size_histogram[7], 1u);

    // A root of zero area (a segment): the unnormalised sum, here 0, not NaN.
    Bvh seg;
    seg.nodes = {inner(Box{Vec3(0, 0, 0), Vec3(4, 0, 0)}, 1), leaf(Box{Vec3(0, 0, 0), Vec3(1, 0, 0)}, 0, 1),
                 leaf(Box{Vec3(3, 0, 0), Vec3(4, 0, 0)}, 1, 1)};
    seg.permutation = {0, 1};
    EXPECT_EQ(canopy::sah_cost(seg), 0.0);
}

TEST(ValidateSah, FiveNodeTreeStats) {
    // Root -> (leaf of 3, inner -> (leaf of 1, leaf of 2)).
    const Box u{Vec3(0, 0, 0), Vec3(4, 4, 4)};
    const Box half{Vec3(0, 0, 0), Vec3(2, 2, 2)};  // A = 12
    Bvh b;
    b.nodes = {inner(u, 1), leaf(half, 0, 3), inner(half, 3), leaf(half, 3, 1), leaf(half, 4, 2)};
    b.permutation = {0, 1, 2, 3, 4, 5};
    const canopy::TreeStats s = canopy::tree_stats(b);
    EXPECT_EQ(s.nodes, 5u);
    EXPECT_EQ(s.leaves, 3u);
    EXPECT_EQ(s.depth, 2u);
    EXPECT_EQ(s.leaf_size_histogram, (std::vector<uint32_t>{0, 1, 1, 1}));
    // (48 + 12 + 12 * 3 + 12 * 1 + 12 * 2) / 48 = 132 / 48.
    EXPECT_DOUBLE_EQ(canopy::sah_cost(b), 132.0 / 48.0);
}

TEST(ValidateSah, StatsOfBuiltTrees) {
    for (uint32_t n : {1u, 2u, 50u, 1000u}) {
        const TriangleMesh m = random_mesh(n, n);
        const Bvh b = build(m);
        const canopy::TreeStats s = canopy::tree_stats(b);
        EXPECT_EQ(s.nodes, b.nodes.size());
        EXPECT_EQ(s.leaves, (s.nodes + 1) / 2);  // a full binary tree
        uint64_t prims = 0, leaves = 0;
        for (size_t k = 0; k < s.leaf_size_histogram.size(); ++k) {
            prims += k * s.leaf_size_histogram[k];
            leaves += s.leaf_size_histogram[k];
        }
        EXPECT_EQ(prims, n);
        EXPECT_EQ(leaves, s.leaves);
        EXPECT_LE(s.leaf_size_histogram.size(), 5u);  // max_leaf 4
        const double cost = canopy::sah_cost(b);
        EXPECT_TRUE(std::isfinite(cost));
        EXPECT_GE(cost, 1.0);  // the root alone contributes 1 (or it is a leaf of n >= 1)
    }
}
