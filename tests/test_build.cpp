// Tests of canopy::build<Sequential> (core/build.h, schedulers/sequential.h):
// determinism, options, input errors, the tree's shape, the records
// prepare writes, and the schedulers' claims on the top of the tree.
#include "core/build.h"
#include "core/bvh.h"
#include "core/error.h"
#include "core/kernel.h"
#include "core/layout.h"
#include "core/memory.h"
#include "core/mesh.h"
#include "core/options.h"
#include "core/primitives.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/validate.h"
#include "schedulers/common.h"
#include "schedulers/sequential.h"
#include "test_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <random>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include <sys/resource.h>

using canopy::BuildOptions;
using canopy::BuildStats;
using canopy::Bvh;
using canopy::Box;
using canopy::Node;
using canopy::Sequential;
using canopy::TriangleMesh;
using canopy::Vec3;

namespace {

using canopy::test_util::coincident_mesh;
using canopy::test_util::geometric_mesh;
using canopy::test_util::grid_mesh;
using canopy::test_util::random_mesh;
using canopy::test_util::uniform;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

std::vector<Box> random_boxes(uint32_t n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::vector<Box> boxes(n);
    for (Box& b : boxes) {
        b.lo = Vec3(uniform(rng, -100, 100), uniform(rng, -100, 100), uniform(rng, -100, 100));
        b.hi = b.lo + Vec3(uniform(rng, 0, 5), uniform(rng, 0, 5), uniform(rng, 0, 5));
    }
    return boxes;
}

Bvh build(const TriangleMesh& m, const BuildOptions& opt = {}, BuildStats* stats = nullptr) {
    return canopy::build<Sequential>(m.view(), opt, stats);
}
Bvh build(const std::vector<Box>& boxes, const BuildOptions& opt = {}) {
    return canopy::build<Sequential>(std::span<const Box>(boxes), opt);
}

bool bit_equal(const Bvh& a, const Bvh& b) {
    return a.nodes.size() == b.nodes.size() && a.permutation.size() == b.permutation.size() &&
           std::memcmp(a.nodes.data(), b.nodes.data(), a.nodes.size() * sizeof(Node)) == 0 &&
           std::memcmp(a.permutation.data(), b.permutation.data(), a.permutation.size() * sizeof(uint32_t)) == 0;
}

// Runs `fn` and checks that it throws exactly E with every `parts` in the message.
template <class E, class Fn>
::testing::AssertionResult throws_with(Fn&& fn, std::initializer_list<std::string> parts) {
    try {
        fn();
    } catch (const E& e) {
        const std::string msg = e.what();
        for (const std::string& p : parts)
            if (msg.find(p) == std::string::npos)
                return ::testing::AssertionFailure() << "message \"" << msg << "\" lacks \"" << p << "\"";
        return ::testing::AssertionSuccess();
    } catch (const std::exception& e) {
        return ::testing::AssertionFailure() << "threw another exception: " << e.what();
    }
    return ::testing::AssertionFailure() << "did not throw";
}

// Runs in a death-test child: a build over kMaxPrimitives (fake) boxes with
// a max_depth far too small; exits 0 on OptionError, 3 on bad_alloc.
[[noreturn]] void build_near_max_primitives_and_exit() {
    const rlim_t limit = rlim_t(2) << 30;
    const rlimit lim{limit, limit};
    setrlimit(RLIMIT_AS, &lim);
    static const Box one{Vec3(0.0f), Vec3(1.0f)};
    const std::span<const Box> boxes(&one, size_t(canopy::kMaxPrimitives));  // never read
    BuildOptions opt;
    opt.max_leaf = 255;
    opt.max_depth = 20;  // needs ceil(log2(ceil(0xFFFFFFFE / 255))) = 25
    try {
        (void)canopy::build<Sequential>(boxes, opt);
        std::_Exit(2);
    } catch (const canopy::OptionError&) {
        std::_Exit(0);
    } catch (const std::bad_alloc&) {
        std::_Exit(3);
    } catch (...) {
        std::_Exit(4);
    }
}

}  // namespace

// ---------------------------------------------------------------- determinism

TEST(BuildDeterminism, TwoBuildsAreBitIdentical) {
    const TriangleMesh meshes[] = {random_mesh(1, 1), random_mesh(3000, 2), grid_mesh(20), coincident_mesh(50),
                                   geometric_mesh(60)};
    for (const TriangleMesh& m : meshes) {
        for (uint32_t max_leaf : {1u, 4u}) {
            BuildOptions opt;
            opt.max_leaf = max_leaf;
            const Bvh a = build(m, opt), b = build(m, opt);
            EXPECT_TRUE(a == b);
            EXPECT_TRUE(bit_equal(a, b));
            EXPECT_EQ(canopy::tree_hash(a), canopy::tree_hash(b));
            EXPECT_EQ(canopy::tree_hash_hex(a), canopy::tree_hash_hex(b));
            EXPECT_TRUE(canopy::validate(a, m.view(), opt).ok());
        }
    }
    const std::vector<Box> boxes = random_boxes(2000, 3);
    const Bvh a = build(boxes), b = build(boxes);
    EXPECT_TRUE(a == b);
    EXPECT_TRUE(bit_equal(a, b));
    EXPECT_EQ(canopy::tree_hash(a), canopy::tree_hash(b));
    EXPECT_TRUE(canopy::validate(a, std::span<const Box>(boxes)).ok());

    // Different options give a different tree (the hash sees the change).
    BuildOptions one;
    one.max_leaf = 1;
    EXPECT_NE(canopy::tree_hash(build(boxes, one)), canopy::tree_hash(a));
}

TEST(BuildDeterminism, TrianglesAndTheirBoxesGiveTheSameTree) {
    const TriangleMesh m = random_mesh(1500, 8);
    std::vector<Box> boxes(m.triangle_count());
    for (size_t t = 0; t < boxes.size(); ++t)
        for (int k = 0; k < 3; ++k) boxes[t].extend(m.vertex(t, k));
    EXPECT_TRUE(bit_equal(build(m), build(boxes)));
}

TEST(BuildDeterminism, StatsAreReported) {
    BuildStats stats;
    stats.threads_used = 99;
    const Bvh b = build(coincident_mesh(100), BuildOptions{}, &stats);
    EXPECT_EQ(stats.threads_used, 1u);
    EXPECT_GT(stats.skipped.coincident_nodes, 0u);
    EXPECT_GT(stats.skipped.single_leaves + stats.skipped.coincident_nodes, 0u);
    BuildStats empty_stats;
    empty_stats.skipped.coincident_nodes = 5;
    EXPECT_TRUE(build(TriangleMesh{}, BuildOptions{}, &empty_stats).empty());
    EXPECT_EQ(empty_stats.skipped.coincident_nodes, 0u);
}

// ---------------------------------------------------------------- options

TEST(BuildOptionsCheck, OutOfRangeFieldsThrowOptionError) {
    const TriangleMesh m = random_mesh(10, 4);
    auto bad = [&](auto mutate, const char* what) {
        BuildOptions opt;
        mutate(opt);
        EXPECT_TRUE(throws_with<canopy::OptionError>([&] { (void)build(m, opt); }, {what})) << what;
        EXPECT_THROW(opt.check(), canopy::OptionError) << what;
        // Also for an empty input: options are checked first.
        EXPECT_THROW((void)build(TriangleMesh{}, opt), canopy::OptionError) << what;
    };
    bad([](BuildOptions& o) { o.bins = 1; }, "bins");
    bad([](BuildOptions& o) { o.bins = 0; }, "bins");
    bad([](BuildOptions& o) { o.bins = 257; }, "bins");
    bad([](BuildOptions& o) { o.max_leaf = 0; }, "max_leaf");
    bad([](BuildOptions& o) { o.max_leaf = 256; }, "max_leaf");
    bad([](BuildOptions& o) { o.max_depth = 0; }, "max_depth");
    bad([](BuildOptions& o) { o.max_depth = 256; }, "max_depth");
    bad([](BuildOptions& o) { o.traversal_cost = -1.0f; }, "traversal_cost");
    bad([](BuildOptions& o) { o.traversal_cost = kNaN; }, "traversal_cost");
    bad([](BuildOptions& o) { o.traversal_cost = kInf; }, "traversal_cost");
    bad([](BuildOptions& o) { o.intersection_cost = -1.0f; }, "intersection_cost");
    bad([](BuildOptions& o) { o.intersection_cost = 0.0f; }, "intersection_cost");
    bad([](BuildOptions& o) { o.threads = 5000; }, "threads");
    bad([](BuildOptions& o) { o.rotate_min = 1; }, "rotate_min");
    bad([](BuildOptions& o) { o.rotate_min = canopy::kRotateMinPrims - 1; }, "rotate_min");

    // The limits themselves are accepted.
    for (uint32_t bins : {2u, 256u})
        for (uint32_t leaf : {1u, 255u}) {
            BuildOptions opt;
            opt.bins = bins;
            opt.max_leaf = leaf;
            opt.traversal_cost = 0.0f;
            EXPECT_NO_THROW(opt.check());
            EXPECT_TRUE(canopy::validate(build(m, opt), m.view(), opt).ok());
        }
}

// Tree rotations (core/kernel/rotate.h): where the build takes them, the
// tree is valid and its SAH strictly lower than without them, since every
// subtree keeps its records in order and splits as before, and only the
// rotated nodes' boxes change, each for a smaller one. Where it takes none,
// the splits it chose ahead and carried to the children's tasks give the
// same tree, bit for bit, as the build without rotations.
TEST(BuildRotations, LowerTheSahWhereTaken) {
    struct Case {
        const char* name;
        TriangleMesh mesh;
    };
    const Case cases[] = {{"stadium", canopy::generate("stadium", 30000, 1)},
                          {"sphere", canopy::generate("sphere", 20000, 1)},
                          {"room", canopy::generate("room", 20000, 1)}};
    for (const Case& c : cases) {
        for (uint32_t bins : {8u, 32u}) {
            BuildOptions plain;
            plain.bins = bins;
            plain.rotate_min = 0;
            BuildOptions rotating = plain;
            rotating.rotate_min = canopy::kRotateMinPrims;
            BuildStats none, some;
            const Bvh a = build(c.mesh, plain, &none), b = build(c.mesh, rotating, &some);
            const std::string what = std::string(c.name) + " bins " + std::to_string(bins);
            EXPECT_EQ(none.skipped.rotations, 0u) << what;
            EXPECT_GT(some.skipped.rotations, 0u) << what;
            const canopy::ValidationReport rep = canopy::validate(b, c.mesh.view(), rotating);
            EXPECT_TRUE(rep.ok()) << what << ": " << rep.summary();
            EXPECT_LT(canopy::sah_cost(b), canopy::sah_cost(a)) << what;
            EXPECT_EQ(a.nodes.size(), b.nodes.size()) << what << ": the same leaves, grouped otherwise";
        }
    }
}

TEST(BuildRotations, WithoutRotationsTheCarriedSplitsChangeNothing) {
    const TriangleMesh m = canopy::generate("random", 20000, 7);
    BuildOptions plain;
    plain.rotate_min = 0;
    BuildOptions rotating;
    rotating.rotate_min = canopy::kRotateMinPrims;
    BuildStats stats;
    const Bvh a = build(m, plain), b = build(m, rotating, &stats);
    ASSERT_EQ(stats.skipped.rotations, 0u) << "this scene was chosen for taking none";
    ASSERT_EQ(a.nodes.size(), b.nodes.size());
    EXPECT_EQ(0, std::memcmp(a.nodes.data(), b.nodes.data(), a.nodes.size() * sizeof(Node)));
    EXPECT_EQ(a.permutation, b.permutation);
}

// A rotation moves two subtrees one level down; near the depth cap none is
// taken, and the tree stays within it.
TEST(BuildRotations, RespectTheDepthCap) {
    const TriangleMesh m = canopy::generate("stadium", 30000, 1);
    for (uint32_t depth : {14u, 16u, 20u, 64u}) {
        BuildOptions opt;
        opt.max_depth = depth;
        opt.rotate_min = canopy::kRotateMinPrims;
        const Bvh b = build(m, opt);
        const canopy::ValidationReport rep = canopy::validate(b, m.view(), opt);
        EXPECT_TRUE(rep.ok()) << "max_depth " << depth << ": " << rep.summary();
    }
}

TEST(BuildOptionsCheck, MaxDepthTooSmallForTheCount) {
    // 100 primitives in leaves of 1 need ceil(log2(100)) = 7 levels.
    const TriangleMesh m = random_mesh(100, 5);
    BuildOptions opt;
    opt.max_leaf = 1;
    opt.max_depth = 6;
    EXPECT_TRUE(throws_with<canopy::OptionError>([&] { (void)build(m, opt); },
                                                 {"max_depth 6", "100 primitives", "needs 7"}));
    opt.max_depth = 7;
    const Bvh b = build(m, opt);
    EXPECT_TRUE(canopy::validate(b, m.view(), opt).ok());
    EXPECT_LE(canopy::tree_stats(b).depth, 7u);
    // In leaves of 4: 25 leaves, 5 levels.
    opt.max_leaf = 4;
    opt.max_depth = 4;
    EXPECT_THROW((void)build(m, opt), canopy::OptionError);
    opt.max_depth = 5;
    EXPECT_TRUE(canopy::validate(build(m, opt), m.view(), opt).ok());
}

// Regression test for a fixed bug: run_build() computes the leaves needed as
// (n + max_leaf - 1) / max_leaf in uint32_t. For n close to kMaxPrimitives
// (which the input checks accept) the sum wraps, leaves_needed becomes 0 and
// a max_depth that is far too small is accepted instead of throwing
// OptionError ("never a wrap", options.h). The build then goes on to
// allocate ~137 GB. The statement runs in a child process with a 2 GB
// address-space limit, so the wrap shows as std::bad_alloc (exit code 3)
// instead of OptionError (exit code 0); nothing reads the (fake) span.
TEST(BuildOptionsCheckDeathTest, MaxDepthCheckDoesNotWrapNearMaxPrimitives) {
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "address-space limits do not work under sanitizers";
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
    GTEST_SKIP() << "address-space limits do not work under sanitizers";
#endif
#endif
    GTEST_FLAG_SET(death_test_style, "threadsafe");
    EXPECT_EXIT(build_near_max_primitives_and_exit(), ::testing::ExitedWithCode(0), "");
}

// ---------------------------------------------------------------- input errors

TEST(BuildInput, IndexOutOfRange) {
    TriangleMesh m = random_mesh(5, 6);
    m.indices[3 * 2 + 1] = 15;  // the mesh has 15 vertices
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); },
                                                {"triangle 2", "vertex index 15", "out of range"}));
    m.indices[3 * 4] = 0xFFFFFFFFu;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); }, {"triangle 2"}));  // the lowest
}

TEST(BuildInput, InfVertexInEachCorner) {
    for (int corner = 0; corner < 3; ++corner)
        for (float v : {kInf, -kInf})
            for (int axis = 0; axis < 3; ++axis) {
                TriangleMesh m = random_mesh(6, 7);
                m.vertices[m.indices[3 * 3 + corner]][axis] = v;
                EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); },
                                                            {"triangle 3", "non-finite"}))
                    << "corner " << corner << " axis " << axis << " value " << v;
            }
}

TEST(BuildInput, NaNVertexInFirstCorner) {
    for (int axis = 0; axis < 3; ++axis) {
        TriangleMesh m = random_mesh(6, 7);
        m.vertices[m.indices[3 * 3 + 0]][axis] = kNaN;
        EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); }, {"triangle 3", "non-finite"}))
            << "axis " << axis;
    }
}

// Regression test for a fixed bug: prepare_triangles() finds the bounds with
// glm::min(a, glm::min(b, c)) / glm::max(...) and then tests the *bounds*
// for finiteness. glm::min(x, y) is (y < x) ? y : x, which drops a NaN in
// its second argument, so a NaN in the second or third vertex of a triangle
// vanishes from both lo and hi: the triangle is accepted (and built over a
// box that ignores the NaN coordinate) instead of throwing InputError.
TEST(BuildInput, NaNVertexInSecondAndThirdCorner) {
    for (int corner = 1; corner < 3; ++corner)
        for (int axis = 0; axis < 3; ++axis) {
            TriangleMesh m = random_mesh(6, 7);
            m.vertices[m.indices[3 * 3 + corner]][axis] = kNaN;
            EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); }, {"triangle 3", "non-finite"}))
                << "corner " << corner << " axis " << axis;
        }
}

TEST(BuildInput, IndexCountNotAMultipleOfThree) {
    TriangleMesh m = random_mesh(4, 8);
    m.indices.push_back(0);
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(m); }, {"13 entries", "multiple of 3"}));
    m.indices.push_back(1);
    EXPECT_THROW((void)build(m), canopy::InputError);
    m.indices.push_back(2);
    EXPECT_NO_THROW((void)build(m));
}

TEST(BuildInput, BadBoxes) {
    std::vector<Box> boxes = random_boxes(10, 9);
    std::vector<Box> nan = boxes;
    nan[3].lo.y = kNaN;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(nan); }, {"primitive box 3", "non-finite"}));
    std::vector<Box> nan_hi = boxes;
    nan_hi[4].hi.z = kNaN;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(nan_hi); }, {"primitive box 4", "non-finite"}));
    std::vector<Box> inf = boxes;
    inf[6].hi.x = kInf;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(inf); }, {"primitive box 6", "non-finite"}));
    std::vector<Box> inverted = boxes;
    inverted[7].lo.x = inverted[7].hi.x + 1.0f;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(inverted); }, {"primitive box 7", "inverted"}));
    // The empty box is inverted too.
    std::vector<Box> empty = boxes;
    empty[2] = Box::empty();
    EXPECT_THROW((void)build(empty), canopy::InputError);
    // Several bad boxes: the lowest is named.
    std::vector<Box> many = inverted;
    many[8].lo.x = kNaN;
    many[5].lo.z = many[5].hi.z + 1.0f;
    EXPECT_TRUE(throws_with<canopy::InputError>([&] { (void)build(many); }, {"primitive box 5"}));
}

// ---------------------------------------------------------------- tree shape

TEST(BuildShape, LeafSizesRespectMaxLeaf) {
    const TriangleMesh m = random_mesh(3000, 10, 30.0f);  // large, overlapping triangles
    for (uint32_t max_leaf : {1u, 4u, 255u}) {
        BuildOptions opt;
        opt.max_leaf = max_leaf;
        // Make leaves attractive so that big ones actually occur.
        opt.traversal_cost = max_leaf == 255 ? 50.0f : 1.0f;
        const Bvh b = build(m, opt);
        EXPECT_TRUE(canopy::validate(b, m.view(), opt).ok()) << canopy::validate(b, m.view(), opt).summary();
        uint32_t largest = 0;
        uint64_t total = 0;
        for (const Node& n : b.nodes)
            if (n.is_leaf()) {
                EXPECT_LE(n.count, max_leaf);
                largest = std::max(largest, n.count);
                total += n.count;
            }
        EXPECT_EQ(total, m.triangle_count());
        if (max_leaf == 1) {
            EXPECT_EQ(largest, 1u);
        }
        if (max_leaf == 255) {
            EXPECT_GT(largest, 4u);
        }
    }
}

TEST(BuildShape, DepthCapOnAPathologicalInput) {
    const TriangleMesh m = geometric_mesh(120);
    ASSERT_EQ(m.triangle_count(), 121u);
    // Uncapped (well, capped at 255), the tree is deep.
    BuildOptions deep;
    deep.max_depth = 255;
    const Bvh d = build(m, deep);
    ASSERT_TRUE(canopy::validate(d, m.view(), deep).ok());
    const uint32_t natural = canopy::tree_stats(d).depth;
    EXPECT_GT(natural, 20u);  // deeper than every cap tried below

    for (uint32_t max_leaf : {1u, 4u})
        for (uint32_t max_depth = 10; max_depth <= 20; ++max_depth) {
            BuildOptions opt;
            opt.max_leaf = max_leaf;
            opt.max_depth = max_depth;
            BuildStats stats;
            const Bvh b = build(m, opt, &stats);
            const auto rep = canopy::validate(b, m.view(), opt);
            EXPECT_TRUE(rep.ok()) << "max_depth " << max_depth << ": " << rep.summary();
            const canopy::TreeStats s = canopy::tree_stats(b);
            EXPECT_LE(s.depth, max_depth);
            EXPECT_GT(stats.skipped.depth_cap_splits, 0u) << max_depth;
            for (size_t k = max_leaf + 1; k < s.leaf_size_histogram.size(); ++k)
                EXPECT_EQ(s.leaf_size_histogram[k], 0u);
        }
}

TEST(BuildShape, DepthCapAtTheMinimumAllowed) {
    // max_depth exactly ceil(log2(leaves needed)): the cap forces a
    // complete middle-split tree and still every leaf fits.
    for (uint32_t n : {2u, 3u, 100u, 1000u, 1025u})
        for (uint32_t max_leaf : {1u, 3u, 4u}) {
            const TriangleMesh m = random_mesh(n, n + max_leaf);
            BuildOptions opt;
            opt.max_leaf = max_leaf;
            opt.max_depth = std::max(1u, canopy::ceil_log2((n + max_leaf - 1) / max_leaf));
            const Bvh b = build(m, opt);
            const auto rep = canopy::validate(b, m.view(), opt);
            EXPECT_TRUE(rep.ok()) << n << " " << max_leaf << ": " << rep.summary();
        }
}

TEST(BuildShape, BinCountsTwoAnd256) {
    const TriangleMesh meshes[] = {random_mesh(2000, 11), grid_mesh(16), geometric_mesh(40)};
    for (const TriangleMesh& m : meshes)
        for (uint32_t bins : {2u, 256u}) {
            BuildOptions opt;
            opt.bins = bins;
            const Bvh b = build(m, opt);
            EXPECT_TRUE(canopy::validate(b, m.view(), opt).ok()) << bins;
            EXPECT_TRUE(b == build(m, opt));
        }
    // More bins cannot make the root split worse on a plain random mesh;
    // just check that both give sane costs.
    const TriangleMesh m = random_mesh(2000, 12);
    for (uint32_t bins : {2u, 256u}) {
        BuildOptions opt;
        opt.bins = bins;
        const double c = canopy::sah_cost(build(m, opt));
        EXPECT_TRUE(std::isfinite(c));
        EXPECT_GT(c, 1.0);
    }
}

TEST(BuildShape, TenThousandCoincidentTriangles) {
    const TriangleMesh m = coincident_mesh(10000);
    for (uint32_t max_leaf : {1u, 4u, 255u}) {
        BuildOptions opt;
        opt.max_leaf = max_leaf;
        BuildStats stats;
        const Bvh b = build(m, opt, &stats);
        EXPECT_TRUE(canopy::validate(b, m.view(), opt).ok());
        const canopy::TreeStats s = canopy::tree_stats(b);
        // Middle splits of coincident nodes: leaves hold between
        // (max_leaf + 1) / 2 and max_leaf primitives, and the tree is balanced.
        for (size_t k = 0; k < s.leaf_size_histogram.size(); ++k)
            if (s.leaf_size_histogram[k]) {
                EXPECT_LE(k, max_leaf);
                EXPECT_GE(k, std::max<size_t>(1, (max_leaf + 1) / 2));
            }
        EXPECT_LE(s.depth, canopy::ceil_log2(10000) + 1);
        EXPECT_GT(stats.skipped.coincident_nodes, 0u);
        // Every node has the triangle's box.
        for (const Node& n : b.nodes) EXPECT_EQ(n.box(), (Box{Vec3(1, 2, 3), Vec3(4, 6, 3)}));
        // Middle splits keep the input order: the permutation is the identity.
        for (uint32_t i = 0; i < b.permutation.size(); ++i) ASSERT_EQ(b.permutation[i], i);
    }
}

// A tree of more nodes than the sequential driver reserves (1.1 per
// primitive): leaves of one primitive need 2n - 1, so the node array grows
// during the build (the equivalence suite compares such trees across the
// schedulers).
TEST(BuildShape, TreeOutgrowsTheNodeReservation) {
    const canopy::TriangleMesh m = canopy::generate("random", 30000, 5);
    canopy::BuildOptions opt;
    opt.max_leaf = 1;
    const canopy::Bvh seq = canopy::build<canopy::Sequential>(m.view(), opt);
    EXPECT_EQ(seq.nodes.size(), 2 * m.triangle_count() - 1);
    EXPECT_TRUE(canopy::validate(seq, m.view(), opt).ok());
}

TEST(BuildShape, SingleAndTwoPrimitives) {
    const TriangleMesh one = random_mesh(1, 13);
    const Bvh b1 = build(one);
    ASSERT_EQ(b1.nodes.size(), 1u);
    EXPECT_EQ(b1.nodes[0].count, 1u);
    EXPECT_EQ(b1.nodes[0].index, 0u);
    EXPECT_EQ(b1.permutation, canopy::PrimitiveOrder{0});

    // Two far apart triangles with max_leaf 1 must split.
    BuildOptions opt;
    opt.max_leaf = 1;
    const TriangleMesh two = geometric_mesh(1);
    const Bvh b2 = build(two, opt);
    ASSERT_EQ(b2.nodes.size(), 3u);
    EXPECT_EQ(b2.nodes[0].index, 1u);
    EXPECT_EQ(b2.nodes[0].count, 0u);
    EXPECT_TRUE(canopy::validate(b2, two.view(), opt).ok());
}

TEST(BuildShape, NegativeZeroAndHugeCoordinates) {
    // -0 coordinates are canonicalised; +-FLT_MAX coordinates build fine.
    TriangleMesh m;
    const float big = std::numeric_limits<float>::max();
    m.vertices = {Vec3(-0.0f, -0.0f, -0.0f), Vec3(1, -0.0f, 0), Vec3(0, 1, -0.0f),
                  Vec3(-big, -big, -big),   Vec3(big, big, big), Vec3(0, big, -big),
                  Vec3(5, 5, 5),            Vec3(6, 5, 5),       Vec3(5, 6, 5)};
    m.indices = {0, 1, 2, 3, 4, 5, 6, 7, 8, 0, 1, 2};
    for (uint32_t max_leaf : {1u, 4u}) {
        BuildOptions opt;
        opt.max_leaf = max_leaf;
        const Bvh b = build(m, opt);
        EXPECT_TRUE(canopy::validate(b, m.view(), opt).ok());
        for (const Node& n : b.nodes)
            for (int a = 0; a < 3; ++a) {
                EXPECT_FALSE(n.min[a] == 0.0f && std::signbit(n.min[a]));
                EXPECT_FALSE(n.max[a] == 0.0f && std::signbit(n.max[a]));
            }
        EXPECT_TRUE(std::isfinite(canopy::sah_cost(b)));
    }
}

// prepare_triangles() and prepare_boxes() store prim_area() of each box, bit
// for bit: random boxes over 80 orders of magnitude of size and position,
// flat ones, points, and areas that underflow or saturate float. (A guard
// for a faster area in prepare: one in AVX2 vectors made no measurable
// difference and was not kept, see docs/performance-log.md.)
TEST(BuildPrepare, RecordAreasArePrimArea) {
    std::mt19937 rng(77);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
    std::uniform_int_distribution<int> exponent(-40, 40);
    TriangleMesh m;
    std::vector<canopy::Box> boxes;
    const auto add = [&](Vec3 a, Vec3 b, Vec3 c) {
        const uint32_t first = uint32_t(m.vertices.size());
        for (const Vec3& v : {a, b, c}) m.vertices.push_back(v);
        for (uint32_t k = 0; k < 3; ++k) m.indices.push_back(first + k);
        canopy::Box box;
        for (const Vec3& v : {a, b, c}) box.extend(v);
        boxes.push_back(box);
    };
    const float big = std::numeric_limits<float>::max();
    add(Vec3(-big), Vec3(big), Vec3(0));               // saturates
    add(Vec3(0), Vec3(1e-20f), Vec3(0));               // underflows to 0
    add(Vec3(0, 0, 5), Vec3(2, 3, 5), Vec3(1, 1, 5));  // flat
    add(Vec3(1, 2, 3), Vec3(1, 2, 3), Vec3(1, 2, 3));  // a point
    add(Vec3(-0.0f), Vec3(0.0f), Vec3(-0.0f));         // signed zeros
    for (int i = 0; i < 20000; ++i) {
        const float scale = std::ldexp(1.0f, exponent(rng)), offset = std::ldexp(unit(rng), exponent(rng));
        const auto point = [&] { return Vec3(unit(rng), unit(rng), unit(rng)) * scale + Vec3(offset); };
        add(point(), point(), point());
    }
    const size_t n = boxes.size();
    std::vector<canopy::PrimRef> from_triangles(n), from_boxes(n);
    EXPECT_EQ(canopy::prepare_triangles(m.view(), 0, n, from_triangles.data()).first_bad,
              canopy::PrepareSummary::kNone);
    EXPECT_EQ(canopy::prepare_boxes(boxes, 0, n, from_boxes.data()).first_bad, canopy::PrepareSummary::kNone);
    size_t positive = 0;
    for (size_t i = 0; i < n; ++i) {
        for (const canopy::PrimRef* r : {&from_triangles[i], &from_boxes[i]}) {
            const float expected = canopy::prim_area(r->lo, r->hi);
            ASSERT_EQ(std::bit_cast<uint32_t>(r->area), std::bit_cast<uint32_t>(expected))
                << "box " << i << ": " << r->area << " vs " << expected;
        }
        positive += from_triangles[i].area > 0.0f;
    }
    EXPECT_GT(positive, n / 2);  // not all underflowing
    EXPECT_EQ(from_triangles[0].area, big);
    EXPECT_EQ(from_triangles[1].area, 0.0f);
}

// prepare_parallel()'s blocks: each block once, whatever the slots and the
// timing; a caller takes the next block of its own run while one is left,
// then the next of the runs after its own.
TEST(BuildSchedulers, BlockClaimsHandEachBlockOnceOwnRunFirst) {
    canopy::sched::BlockClaims c(3, 4);  // runs {0..3}, {4..7}, {8..11}
    EXPECT_EQ(c.claim(1), 4u);
    EXPECT_EQ(c.claim(1), 5u);
    EXPECT_EQ(c.claim(4), 6u);  // slot 4 is run 4 mod 3 = 1
    EXPECT_EQ(c.claim(1), 7u);
    EXPECT_EQ(c.claim(1), 8u);  // run 1 used up: the next run's next block
    EXPECT_EQ(c.claim(0), 0u);
    std::vector<int> seen(12, 0);
    for (uint32_t b : {4u, 5u, 6u, 7u, 8u, 0u}) ++seen[b];
    for (int k = 0; k < 6; ++k) ++seen[c.claim(2)];  // 9, 10, 11, then run 0's 1, 2, 3
    for (int s : seen) EXPECT_EQ(s, 1);

    // Four threads racing over 4 runs of 500 blocks, as many claims as blocks.
    canopy::sched::BlockClaims race(4, 500);
    std::vector<std::atomic<int>> got(2000);
    std::atomic<int> calls{2000};
    std::vector<std::thread> team;
    for (uint32_t slot = 0; slot < 4; ++slot)
        team.emplace_back([&, slot] {
            while (calls.fetch_sub(1) > 0) got[race.claim(slot)].fetch_add(1);
        });
    for (auto& t : team) t.join();
    for (const auto& g : got) EXPECT_EQ(g.load(), 1);
}

// The tasks the top of the tree hands out: each once, the caller's own
// (the one whose middle lies in the part of the records its slot prepared)
// first, else the first left.
TEST(BuildSchedulers, TaskClaimsTakeTheTaskOverTheCallersPartFirst) {
    canopy::NodeTask left, right;
    left.begin = 0;
    left.end = 600;
    right.begin = 600;
    right.end = 1000;
    const canopy::NodeTask two[2] = {left, right};
    EXPECT_EQ(canopy::sched::home_slot(left, 1000, 2), 0u);
    EXPECT_EQ(canopy::sched::home_slot(right, 1000, 2), 1u);
    {
        canopy::sched::TaskClaims c;
        EXPECT_EQ(c.claim(two, 1, 1000, 2), 1u);
        EXPECT_EQ(c.claim(two, 1, 1000, 2), 0u);  // its own is taken: the other
    }
    {
        canopy::sched::TaskClaims c;
        EXPECT_EQ(c.claim(two, 0, 1000, 2), 0u);
        EXPECT_EQ(c.claim(two, 0, 1000, 2), 1u);
    }
    // Eight tasks tiling [0, 8000), two threads racing: each task once.
    std::vector<canopy::NodeTask> eight(8);
    for (uint32_t i = 0; i < 8; ++i) {
        eight[i].begin = 1000 * i;
        eight[i].end = 1000 * (i + 1);
    }
    canopy::sched::TaskClaims c;
    std::vector<std::atomic<int>> got(8);
    std::atomic<int> calls{8};
    std::thread a([&] {
        while (calls.fetch_sub(1) > 0) got[c.claim(eight, 0, 8000, 2)].fetch_add(1);
    });
    std::thread b([&] {
        while (calls.fetch_sub(1) > 0) got[c.claim(eight, 1, 8000, 2)].fetch_add(1);
    });
    a.join();
    b.join();
    for (const auto& g : got) EXPECT_EQ(g.load(), 1);
}
