// Tests of canopy::build<Sequential> (core/build.h, schedulers/sequential.h)
// and of the arithmetic node placement of core/layout.h against it.
#include "core/build.h"
#include "core/depth_first.h"
#include "core/bvh.h"
#include "core/error.h"
#include "core/kernel.h"
#include "core/layout.h"
#include "core/memory.h"
#include "core/mesh.h"
#include "core/options.h"
#include "core/overflow_area.h"
#include "core/primitives.h"
#include "core/scene.h"
#include "core/sah.h"
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

#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/utsname.h>

using canopy::BuildOptions;
using canopy::BuildStats;
using canopy::Bvh;
using canopy::Box;
using canopy::Node;
using canopy::NodeRecord;
using canopy::Sequential;
using canopy::TriangleMesh;
using canopy::Vec3;

namespace {

using canopy::test_util::coincident_mesh;
using canopy::test_util::grid_mesh;
using canopy::test_util::random_mesh;
using canopy::test_util::uniform;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

// Triangles in the planes x = 2^-k, k = 0..kmax: with bins over [2^-kmax, 1]
// nearly everything falls in bin 0, so every SAH split peels off only the
// few largest: without a depth cap the tree is about as deep as it has
// triangles.
TriangleMesh geometric_mesh(int kmax) {
    TriangleMesh m;
    for (int k = 0; k <= kmax; ++k) {
        const float x = std::ldexp(1.0f, -k);
        const uint32_t base = uint32_t(m.vertices.size());
        m.vertices.insert(m.vertices.end(), {Vec3(x, 0, 0), Vec3(x, 1, 0), Vec3(x, 0, 1)});
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
    }
    return m;
}

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

// ---------------------------------------------------------------- memory

// allocate_huge(): from kHugeAllocMin bytes on the memory starts on a 2 MiB
// boundary; below, it is ordinary memory; every byte is usable and the
// release matches (ASan checks the pairing). A NodeChunk of whole huge
// pages is aligned too.
TEST(HugeAllocation, BigArraysStartOnHugePageBoundaries) {
    constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
    for (size_t bytes : {size_t(1000), canopy::kHugeAllocMin - 1, canopy::kHugeAllocMin, canopy::kHugeAllocMin + 4096,
                         size_t(5) << 20}) {
        SCOPED_TRACE(bytes);
        auto* p = static_cast<unsigned char*>(canopy::allocate_huge(bytes));
        ASSERT_NE(p, nullptr);
        if (bytes >= canopy::kHugeAllocMin) {
            EXPECT_EQ(reinterpret_cast<std::uintptr_t>(p) % kHuge, 0u);
        }
        std::memset(p, 0xAB, bytes);
        EXPECT_EQ(p[bytes - 1], 0xAB);
        canopy::release_huge(p, bytes);
    }
    canopy::NodeChunk chunk;
    canopy::reserve_on_huge_pages(chunk, size_t(1) << 16);  // 2 MiB of nodes
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(chunk.data()) % kHuge, 0u);
    chunk.resize(3);
    chunk[2].index = 7;
    EXPECT_EQ(chunk[2].index, 7u);
}

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

// NodeArray (core/node_array.h), the Bvh's node array: std::vector's
// behaviour where it has one; expand() keeps the whole storage (a one-off
// build's records live past size()); a mapped array grows without holding
// its old and new pages at once.
namespace {
canopy::Node tagged(uint32_t i) {
    canopy::Node n{};
    n.min[0] = float(i);
    n.index = i;
    n.count = i + 1;
    return n;
}
bool has_tag(const canopy::Node& n, uint32_t i) { return n.min[0] == float(i) && n.index == i && n.count == i + 1; }
// Tags every slot of v's capacity with its index.
void tag_all(canopy::NodeArray& v) {
    for (size_t i = 0; i < v.capacity(); ++i) v.data()[i] = tagged(uint32_t(i));
}
// 1 MiB of tagged slots, mapped or on the heap.
canopy::NodeArray tagged_mib(bool map) {
    canopy::NodeArray v = map ? canopy::NodeArray(canopy::NodeArray::MapFrom{0}) : canopy::NodeArray();
    v.reserve(size_t(1) << 15);
    tag_all(v);
    return v;
}
// The bytes of the whole 4 KiB pages inside [begin, end).
size_t whole_page_bytes(const void* begin, const void* end) {
    const size_t first = (reinterpret_cast<std::uintptr_t>(begin) + 4095) / 4096,
                 last = reinterpret_cast<std::uintptr_t>(end) / 4096;
    return last > first ? (last - first) * 4096 : 0;
}

// Mapped bytes as the observer of core/memory.h sees them.
std::atomic<long long> g_mapped{0}, g_mapped_peak{0};
void observe_mapped(std::ptrdiff_t delta) {
    const long long now = g_mapped += delta;
    long long peak = g_mapped_peak.load();
    while (now > peak && !g_mapped_peak.compare_exchange_weak(peak, now)) {
    }
}
}  // namespace

TEST(BuildMemory, NodeArrayBehavesLikeAVector) {
    for (const bool map : {false, true}) {
        canopy::NodeArray v = map ? canopy::NodeArray(canopy::NodeArray::MapFrom{0}) : canopy::NodeArray();
        EXPECT_TRUE(v.empty());
        for (uint32_t i = 0; i < 5000; ++i) v.push_back(tagged(i));  // grows many times
        ASSERT_EQ(v.size(), 5000u);
        EXPECT_GE(v.capacity(), 5000u);
        EXPECT_EQ(v.mapped(), map);
        for (uint32_t i = 0; i < 5000; ++i) ASSERT_TRUE(has_tag(v[i], i)) << i;
        const canopy::NodeArray copy = v;  // a copy holds size() nodes, on the heap
        ASSERT_EQ(copy.size(), v.size());
        EXPECT_FALSE(copy.mapped());
        EXPECT_EQ(std::memcmp(copy.data(), v.data(), v.size() * sizeof(canopy::Node)), 0);
        canopy::NodeArray moved = std::move(v);
        EXPECT_TRUE(v.empty());
        EXPECT_EQ(moved.size(), 5000u);
        EXPECT_TRUE(has_tag(moved.back(), 4999));
        moved.resize(10);
        EXPECT_EQ(moved.size(), 10u);
        moved.reserve(moved.capacity() + 1);  // keeps the first size() nodes
        for (uint32_t i = 0; i < 10; ++i) ASSERT_TRUE(has_tag(moved[i], i));
        const canopy::Node more[] = {tagged(70), tagged(71)};
        moved.append(more, more + 2);
        EXPECT_TRUE(has_tag(moved[11], 71));
        moved.clear();
        EXPECT_TRUE(moved.empty());
    }
    canopy::NodeArray list = {tagged(1), tagged(2)};
    EXPECT_EQ(list.size(), 2u);
    EXPECT_TRUE(has_tag(list[1], 2));
    // Its own nodes, appended while it grows (ASan saw push_back read a
    // node the growth had freed).
    for (uint32_t i = 0; i < 10; ++i) list.push_back(list[i % 2]);
    list.append(list.begin(), list.end());
    ASSERT_EQ(list.size(), 24u);
    for (uint32_t i = 0; i < 24; ++i) EXPECT_TRUE(has_tag(list[i], 1 + i % 2)) << i;
}

TEST(BuildMemory, NodeArrayExpandKeepsTheWholeStorage) {
    for (const bool map : {false, true}) {
        canopy::NodeArray v = map ? canopy::NodeArray(canopy::NodeArray::MapFrom{0}) : canopy::NodeArray();
        v.reserve(3000);
        const size_t cap = v.capacity();
        v.resize(10);
        // Past size(): what a one-off build keeps there (its records).
        for (uint32_t i = 0; i < cap; ++i) v.data()[i] = tagged(i);
        v.expand(5 * cap);
        EXPECT_GE(v.capacity(), 5 * cap);
        EXPECT_EQ(v.size(), 10u);
        for (uint32_t i = 0; i < cap; ++i) ASSERT_TRUE(has_tag(v.data()[i], i)) << i << (map ? " mapped" : " heap");
    }
}

TEST(BuildMemory, MappedNodeArrayGrowsWithoutASecondCopy) {
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    canopy::set_mapped_bytes_observer(observe_mapped);
    {
        canopy::NodeArray v(canopy::NodeArray::MapFrom{0});
        v.reserve(size_t(1) << 16);  // 2 MiB, in a reservation of 4
        const long long small = g_mapped.load();
        EXPECT_GE(small, (1ll << 16) * 32);
        g_mapped_peak = small;
        // Every page written, so that a copy would have something to copy.
        tag_all(v);
        const canopy::Node* before = v.data();
        v.expand(size_t(3) << 15);  // 3 MiB: within the reservation, in place
        EXPECT_EQ(v.data(), before);
        for (const size_t nodes : {size_t(1) << 18, size_t(1) << 20}) {  // 8 and 32 MiB: moved, twice
            v.expand(nodes);
            const long long now = g_mapped.load();
            EXPECT_GE(now, (long long)(nodes * 32));
            // The high-water mark is the new size, not old + new.
            EXPECT_EQ(g_mapped_peak.load(), now) << nodes;
            EXPECT_EQ(reinterpret_cast<std::uintptr_t>(v.data()) % (size_t(2) << 20), 0u) << "on a 2 MiB boundary";
            for (size_t i = 0; i < (size_t(1) << 16); ++i) ASSERT_TRUE(has_tag(v.data()[i], uint32_t(i))) << i;
            v.data()[v.capacity() - 1] = tagged(5);  // the new part is writable
        }
    }
    EXPECT_EQ(g_mapped.load(), 0);  // unmapped when the array goes
    canopy::set_mapped_bytes_observer(nullptr);
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

// A one-off sequential build keeps its records at the end of the node
// array's storage and writes the nodes from the front (NodesBeforeRecords);
// a warm Builder keeps a records array of its own. Both give the same tree:
// the sphere's fits in the first reservation (1.1 nodes per primitive), the
// random triangles' (1.86) and leaves of one primitive (2n - 1) make the
// storage grow during the build.
TEST(BuildMemory, RecordsAtTheEndOfTheNodeArray) {
    struct Case {
        const char* name;
        TriangleMesh mesh;
        uint32_t max_leaf;
        bool grows;
    };
    const Case cases[] = {{"sphere", canopy::generate("sphere", 20000, 1), 4, false},
                          {"random", canopy::generate("random", 20000, 7), 4, true},
                          {"random, leaves of 1", canopy::generate("random", 5000, 3), 1, true}};
    for (const Case& c : cases) {
        BuildOptions opt;
        opt.max_leaf = c.max_leaf;
        const uint32_t n = uint32_t(c.mesh.triangle_count());
        const Bvh got = canopy::build<Sequential>(c.mesh.view(), opt);
        canopy::Builder<Sequential> warm;
        Bvh ref;
        warm.build(c.mesh.view(), ref, opt);
        EXPECT_TRUE(got == ref) << c.name;
        EXPECT_TRUE(canopy::validate(got, c.mesh.view(), opt).ok()) << c.name;
        const size_t first = canopy::NodesBeforeRecords::initial_capacity(n);
        if (c.grows)
            EXPECT_GT(got.nodes.capacity(), first) << c.name << ": " << got.nodes.size() << " nodes";
        else
            EXPECT_EQ(got.nodes.capacity(), first) << c.name << ": " << got.nodes.size() << " nodes";
    }
}

// NodesBeforeRecords on its own: pairs taken faster and faster against the
// records consumed (one pair for each of the first 100 records, up to ten
// for the last: each growth's estimate falls short) make it grow several
// times; every node written and every live record survive each move, and
// ctx.refs follows the records.
TEST(BuildMemory, NodesBeforeRecordsGrowsKeepingNodesAndLiveRecords) {
    const uint32_t n = 1000;
    canopy::NodeArray v;
    v.reserve(canopy::NodesBeforeRecords::initial_capacity(n));
    canopy::KernelContext ctx{canopy::NodesBeforeRecords::records_at_end(v.data(), v.capacity(), n), nullptr,
                              nullptr, nullptr};
    ASSERT_EQ(reinterpret_cast<std::uintptr_t>(ctx.refs) % 32, 0u);
    ASSERT_LE(reinterpret_cast<const char*>(ctx.refs + n), reinterpret_cast<const char*>(v.data() + v.capacity()));
    for (uint32_t r = 0; r < n; ++r) {
        ctx.refs[r] = canopy::PrimRef{};
        ctx.refs[r].id = r;
        ctx.refs[r].lo = Vec3(float(r), 0.0f, 0.0f);
    }
    canopy::NodesBeforeRecords out(v, ctx, n);
    const auto tag = [&](uint32_t slot) {
        Node& node = out.at(slot);
        node.index = slot;
        node.count = 7;
    };
    tag(out.root());
    int moves = 0;
    size_t pairs = 0;
    for (uint32_t live = 0; live < n; ++live) {
        const canopy::PrimRef* before = ctx.refs;
        for (uint32_t k = 0; k < 1 + live / 100; ++k, ++pairs) {
            const auto pair = out.pair(live);
            ASSERT_EQ(pair[1], pair[0] + 1);
            tag(pair[0]);
            tag(pair[1]);
        }
        moves += ctx.refs != before;
        for (uint32_t r = live; r < n; ++r) {
            ASSERT_EQ(ctx.refs[r].id, r) << "record " << r << " after record " << live;
            ASSERT_EQ(ctx.refs[r].lo.x, float(r));
        }
    }
    EXPECT_GE(moves, 3);
    ASSERT_EQ(v.size(), 1 + 2 * pairs);
    for (uint32_t s = 0; s < v.size(); ++s) {
        ASSERT_EQ(v[s].index, s);
        ASSERT_EQ(v[s].count, 7u);
    }
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

// ---------------------------------------------------------------- layout

namespace {

// The NodeRecords a parallel scheduler would produce for this tree,
// reconstructed by walking it: begin, count, depth, rights, is_right and
// parent_begin of every node.
std::vector<NodeRecord> records_of(const Bvh& b) {
    std::vector<NodeRecord> out;
    struct Item {
        uint32_t node, depth, rights, parent_begin;
        bool is_right;
    };
    // begin of a node = begin of its leftmost leaf.
    auto begin_of = [&](uint32_t i) {
        while (!b.nodes[i].is_leaf()) i = b.nodes[i].index;
        return b.nodes[i].index;
    };
    std::vector<Item> stack{{0, 0, 0, 0, false}};
    while (!stack.empty()) {
        const Item it = stack.back();
        stack.pop_back();
        const Node& n = b.nodes[it.node];
        NodeRecord r{};
        r.box = n.box();
        r.begin = begin_of(it.node);
        r.count = n.count;
        r.parent_begin = it.parent_begin;
        r.depth = uint8_t(it.depth);
        r.rights = uint8_t(it.rights);
        r.is_right = it.is_right;
        out.push_back(r);
        if (!n.is_leaf()) {
            stack.push_back({n.index + 1, it.depth + 1, it.rights + 1, r.begin, true});
            stack.push_back({n.index, it.depth + 1, it.rights, r.begin, false});
        }
    }
    return out;
}

std::vector<std::vector<NodeRecord>> scatter(std::vector<NodeRecord> records, uint32_t arenas, uint32_t seed) {
    std::mt19937 rng(seed);
    std::shuffle(records.begin(), records.end(), rng);
    std::vector<std::vector<NodeRecord>> out(arenas);
    for (const NodeRecord& r : records) out[rng() % arenas].push_back(r);
    return out;
}

// Runs fn(i) for i in [0, k) in reverse order (any order must do).
struct ReverseForEach {
    template <class Fn>
    void operator()(size_t k, Fn&& fn) const {
        for (size_t i = k; i-- > 0;) fn(i);
    }
};
struct ForwardForEach {
    template <class Fn>
    void operator()(size_t k, Fn&& fn) const {
        for (size_t i = 0; i < k; ++i) fn(i);
    }
};

// Places arenas that hold records only (every node run as a task).
canopy::NodeArray place(const std::vector<std::vector<NodeRecord>>& records) {
    std::vector<canopy::PlacementArena> arenas(records.size());
    std::vector<const canopy::PlacementArena*> views;
    for (size_t i = 0; i < records.size(); ++i) {
        arenas[i].records = records[i];
        views.push_back(&arenas[i]);
    }
    canopy::NodeArray nodes;
    canopy::place_nodes(std::span<const canopy::PlacementArena* const>(views), nullptr, nodes, ReverseForEach{});
    return nodes;
}

bool same_nodes(const canopy::NodeArray& a, const canopy::NodeArray& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(Node)) == 0;
}
// The first n nodes of a and b are the same.
bool same_nodes_prefix(const canopy::NodeArray& a, const canopy::NodeArray& b, size_t n) {
    return a.size() >= n && b.size() >= n && std::memcmp(a.data(), b.data(), n * sizeof(Node)) == 0;
}

}  // namespace

TEST(BuildLayout, PlaceRecordsReproducesTheSequentialTree) {
    struct Case {
        TriangleMesh mesh;
        BuildOptions opt;
    };
    std::vector<Case> cases;
    cases.push_back({random_mesh(1, 1), {}});
    cases.push_back({random_mesh(2000, 14), {}});
    cases.push_back({grid_mesh(15), {}});
    cases.push_back({coincident_mesh(1000), {}});
    cases.push_back({geometric_mesh(120), {}});
    BuildOptions leaf1;
    leaf1.max_leaf = 1;
    cases.push_back({random_mesh(777, 15), leaf1});
    BuildOptions capped;
    capped.max_depth = 12;
    cases.push_back({geometric_mesh(120), capped});
    for (const Case& c : cases) {
        const Bvh b = build(c.mesh, c.opt);
        const std::vector<NodeRecord> recs = records_of(b);
        ASSERT_EQ(recs.size(), b.nodes.size());
        for (uint32_t seed = 0; seed < 3; ++seed) {
            const auto arenas = scatter(recs, 3, seed);
            const canopy::NodeArray nodes = place(arenas);
            EXPECT_TRUE(same_nodes(nodes, b.nodes))
                << "n=" << c.mesh.triangle_count() << " seed " << seed;
        }
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

// The kernel's inputs for a whole mesh, as a scheduler sets them up: the
// records, an unwritten permutation, the root task, the context.
struct KernelInputs {
    BuildOptions opt;
    std::vector<canopy::PrimRef> refs;
    canopy::PrimitiveOrder perm;
    canopy::NodeTask root;
    explicit KernelInputs(const TriangleMesh& m) {
        const uint32_t n = uint32_t(m.triangle_count());
        refs.resize(n);
        const canopy::PrepareSummary s = canopy::prepare_triangles(m.view(), 0, n, refs.data());
        EXPECT_EQ(s.first_bad, canopy::PrepareSummary::kNone);
        root.begin = 0;
        root.end = n;
        root.bounds = s.bounds;
        root.cbounds = s.cbounds;
        perm.assign(n, ~0u);
    }
    canopy::KernelContext ctx() { return {refs.data(), perm.data(), &opt, nullptr}; }
};

TEST(BuildLayout, KernelTasksInRandomOrderPlaceLikeSequential) {
    // A toy parallel scheduler: pending node tasks are run in random order,
    // each one records NodeRecord::of(task) into one of 3 arenas; the
    // placement must give the sequential tree bit for bit.
    const TriangleMesh meshes[] = {random_mesh(3000, 16), grid_mesh(20), geometric_mesh(100), coincident_mesh(300)};
    for (const TriangleMesh& m : meshes) {
        KernelInputs in(m);
        const Bvh expected = build(m, in.opt);
        const uint32_t n = uint32_t(m.triangle_count());
        const canopy::NodeTask& root = in.root;
        const canopy::PrimitiveOrder& perm = in.perm;
        const canopy::KernelContext ctx = in.ctx();
        auto bins = std::make_unique<canopy::BinSet>();
        canopy::SkipCounts skip;
        std::mt19937 rng(n);
        std::vector<canopy::NodeTask> pending{root};
        std::vector<std::vector<NodeRecord>> arenas(3);
        while (!pending.empty()) {
            const size_t pick = rng() % pending.size();
            const canopy::NodeTask t = pending[pick];
            pending[pick] = pending.back();
            pending.pop_back();
            canopy::NodeTask children[2];
            const bool split = canopy::run_node(ctx, t, children, *bins, skip);
            arenas[rng() % 3].push_back(NodeRecord::of(t, !split));
            if (split) pending.insert(pending.end(), {children[0], children[1]});
        }
        const canopy::NodeArray nodes = place(arenas);
        EXPECT_TRUE(same_nodes(nodes, expected.nodes)) << "n=" << n;
        EXPECT_EQ(perm, expected.permutation) << "n=" << n;
    }
}

TEST(BuildLayout, SubtreeBlocksPlaceLikeSequential) {
    // What the parallel drivers leave: some subtrees as blocks in the
    // sequential layout (relative indices), the other nodes as records, all
    // scattered over arenas in random order. Blocks are cut from the
    // sequential tree itself: in the canonical layout a node's descendants
    // fill [first child, first child + descendants).
    const TriangleMesh meshes[] = {random_mesh(3000, 21), grid_mesh(18), coincident_mesh(500), random_mesh(1, 2)};
    for (const TriangleMesh& m : meshes) {
        const Bvh b = build(m, BuildOptions{});
        const std::vector<NodeRecord> recs = records_of(b);  // in depth-first pre-order of nodes
        // Node index of each record, in the same walk order.
        std::vector<uint32_t> index_of;
        {
            std::vector<uint32_t> stack{0};
            while (!stack.empty()) {
                const uint32_t i = stack.back();
                stack.pop_back();
                index_of.push_back(i);
                if (!b.nodes[i].is_leaf()) stack.insert(stack.end(), {b.nodes[i].index + 1, b.nodes[i].index});
            }
        }
        ASSERT_EQ(index_of.size(), recs.size());
        std::vector<uint32_t> subtree_size(b.nodes.size(), 1), leaves(b.nodes.size(), 0);
        for (size_t k = index_of.size(); k-- > 0;) {  // children before parents
            const Node& n = b.nodes[index_of[k]];
            if (n.is_leaf()) {
                leaves[index_of[k]] = 1;
            } else {
                subtree_size[index_of[k]] = 1 + subtree_size[n.index] + subtree_size[n.index + 1];
                leaves[index_of[k]] = leaves[n.index] + leaves[n.index + 1];
            }
        }
        uint32_t total_blocks = 0;
        for (uint32_t seed = 0; seed < 4; ++seed) {
            std::mt19937 rng(seed);
            std::vector<canopy::PlacementArena> arenas(3);
            std::vector<char> covered(b.nodes.size(), 0);
            uint32_t blocks = 0;
            for (size_t k = 0; k < recs.size(); ++k) {
                const uint32_t i = index_of[k];
                if (covered[i]) continue;
                canopy::PlacementArena& a = arenas[rng() % 3];
                if (rng() % 3 == 0) {  // this node's subtree becomes a block
                    canopy::SubtreeBlock blk;
                    blk.root = recs[k];
                    canopy::NodeChunk& chunk = a.open_chunk();
                    blk.chunk = uint32_t(a.chunks.size() - 1);
                    blk.first = uint32_t(chunk.size());
                    blk.size = subtree_size[i];
                    blk.leaves = leaves[i];
                    const Node& root = b.nodes[i];
                    const uint32_t c = root.is_leaf() ? 0 : root.index;
                    auto relative = [&](Node n) {
                        if (!n.is_leaf()) n.index = n.index - c + 1;
                        return n;
                    };
                    chunk.push_back(relative(root));
                    for (uint32_t j = 1; j < blk.size; ++j) chunk.push_back(relative(b.nodes[c + j - 1]));
                    a.blocks.push_back(blk);
                    ++blocks;
                    // Mark the subtree covered.
                    std::vector<uint32_t> st{i};
                    while (!st.empty()) {
                        const uint32_t u = st.back();
                        st.pop_back();
                        covered[u] = 1;
                        if (!b.nodes[u].is_leaf()) st.insert(st.end(), {b.nodes[u].index, b.nodes[u].index + 1});
                    }
                } else {
                    a.records.push_back(recs[k]);
                    covered[i] = 1;
                }
            }
            for (auto& a : arenas) std::shuffle(a.records.begin(), a.records.end(), rng);
            std::vector<const canopy::PlacementArena*> views{&arenas[0], &arenas[1], &arenas[2]};
            canopy::NodeArray nodes;
            canopy::place_nodes(std::span<const canopy::PlacementArena* const>(views), nullptr, nodes, ReverseForEach{});
            EXPECT_TRUE(same_nodes(nodes, b.nodes)) << "n=" << m.triangle_count() << " seed " << seed;
            total_blocks += blocks;
        }
        EXPECT_GT(total_blocks, 0u) << "n=" << m.triangle_count();  // the blocks were tested
    }
}

TEST(BuildLayout, BlocksGoOnInNewChunksWhenOneIsFull) {
    // Blocks built into chunks of a few nodes (ChunkedNodes): a block that
    // fills its chunk goes on at the start of a new one, every chunk but the
    // last ends full, node addresses stay valid, and the placement reads a
    // block across its chunks. The root runs as a record and its children's
    // subtrees as two blocks of one arena: the placement must give the
    // sequential tree bit for bit.
    const TriangleMesh meshes[] = {random_mesh(500, 5), grid_mesh(9), coincident_mesh(40)};
    for (const TriangleMesh& m : meshes) {
        for (const size_t chunk : {size_t(1), size_t(2), size_t(3), size_t(7), size_t(64)}) {
            KernelInputs in(m);
            const canopy::KernelContext ctx = in.ctx();
            const auto bins = std::make_unique<canopy::BinSet>();
            canopy::SkipCounts skip;
            canopy::PlacementArena arena;
            arena.chunk_nodes = chunk;
            canopy::NodeTask children[2];
            ASSERT_TRUE(canopy::run_node(ctx, in.root, children, *bins, skip));
            arena.records.push_back(NodeRecord::of(in.root, false));
            for (const canopy::NodeTask& c : children) {
                canopy::ChunkedNodes out(arena);
                canopy::SubtreeBlock b;
                b.leaves = canopy::build_depth_first(ctx, c, out, *bins, skip, 0);
                b.chunk = out.first_chunk();
                b.first = out.first();
                b.size = out.size();
                b.root = NodeRecord::of(c, arena.chunks[b.chunk][b.first].is_leaf());
                arena.blocks.push_back(b);
            }
            size_t held = 0;
            for (size_t k = 0; k < arena.chunks.size(); ++k) {
                EXPECT_LE(arena.chunks[k].size(), arena.chunks[k].capacity());
                if (k + 1 < arena.chunks.size()) {
                    EXPECT_EQ(arena.chunks[k].size(), arena.chunks[k].capacity());
                }
                held += arena.chunks[k].size();
            }
            const Bvh expected = build(m, in.opt);
            EXPECT_EQ(held, expected.nodes.size() - 1) << "every node but the root is in a block";
            if (chunk < 64) {
                EXPECT_GT(arena.chunks.size(), 2u) << "chunk " << chunk;
            }
            const canopy::PlacementArena* views[] = {&arena};
            canopy::NodeArray nodes;
            canopy::place_nodes(std::span<const canopy::PlacementArena* const>(views), nullptr, nodes, ReverseForEach{});
            EXPECT_TRUE(same_nodes(nodes, expected.nodes)) << "n=" << in.refs.size() << " chunk " << chunk;
            EXPECT_EQ(in.perm, expected.permutation) << "n=" << in.refs.size() << " chunk " << chunk;
        }
    }
}

// A one-off parallel build by hand: the records at the end of `nodes`'
// storage (reserved here as a build does), big nodes run as tasks, subtrees
// below `subtree` records built over their own records
// (run_subtree_over_records) by three workers in turn; then
// place_over_records() with `for_each`. Returns the storage's capacity
// before the placement. ByHand: the build options, the overflow area's
// `dense_min` (OverflowArea::reset()) and, if given, a count of the blocks
// whose nodes past their records lie partly in the area and partly in the
// chunks (`split`).
struct ByHand {
    BuildOptions opt;
    size_t dense_min = canopy::OverflowArea::kHugeAreaMin;
    size_t* split = nullptr;
};

template <class ForEach>
size_t build_by_hand(const TriangleMesh& m, canopy::NodeArray& nodes, canopy::PrimitiveOrder& perm,
                     ForEach&& for_each, uint32_t subtree = 600, canopy::BesideRecordsSizes sizes = {},
                     const ByHand& how = {}) {
    const BuildOptions& opt = how.opt;
    const uint32_t n = uint32_t(m.triangle_count());
    nodes.reserve(canopy::NodesBeforeRecords::initial_capacity(n));
    const size_t storage = nodes.capacity();
    canopy::PrimRef* refs = canopy::NodesBeforeRecords::records_at_end(nodes.data(), storage, n);
    const canopy::PrepareSummary s = canopy::prepare_triangles(m.view(), 0, n, refs);
    EXPECT_EQ(s.first_bad, canopy::PrepareSummary::kNone);
    canopy::NodeTask root;
    root.begin = 0;
    root.end = n;
    root.bounds = s.bounds;
    root.cbounds = s.cbounds;
    root.max_area = s.max_area;
    perm.assign(n, ~0u);
    const canopy::KernelContext ctx{refs, perm.data(), &opt, nullptr};
    canopy::Workers workers;
    workers.reset(3, n, opt.bins, 24, true, how.dense_min);
    std::vector<canopy::NodeTask> pending{root};
    uint32_t turn = 0, subtrees = 0;
    while (!pending.empty()) {
        const canopy::NodeTask t = pending.back();
        pending.pop_back();
        canopy::Worker& wk = workers[turn++ % 3];
        if (t.size() < subtree) {
            canopy::sched::run_subtree_over_records(ctx, t, wk);
            ++subtrees;
            continue;
        }
        canopy::NodeTask children[2];
        const bool split = canopy::run_node(ctx, t, children, *wk.bins, wk.skip);
        wk.out.records.push_back(NodeRecord::of(t, !split));
        if (split) pending.insert(pending.end(), {children[0], children[1]});
    }
    EXPECT_GT(subtrees, 15u);
    const canopy::PlacementArena* views[] = {&workers[0].out, &workers[1].out, &workers[2].out};
    if (how.split)
        for (const canopy::PlacementArena* a : views)
            for (const canopy::SubtreeBlock& b : a->blocks) *how.split += b.in_area > 0 && b.in_chunks() > 0;
    canopy::place_over_records(std::span<const canopy::PlacementArena* const>(views), refs, nodes, for_each, 0, sizes);
    return storage;
}

TEST(BuildLayout, InPlaceMovesSplitOverWorkersInAnyOrder) {
    // A one-off parallel build by hand (build_by_hand), placed in place with
    // the moves split into three runs, run last to first (ReverseForEach):
    // each run must copy aside the blocks whose slots lie over an earlier
    // run's records before it moves the rest, or it overwrites blocks that
    // have not moved. The sphere's blocks fit over their records; with the
    // random triangles some have more nodes than records and go on in the
    // overflow area or, a few, the workers' chunks. A tree of random
    // triangles alone does not fit (1.86 nodes per record): it goes into a
    // new array (a mapping, whatever the storage was), the runs copying
    // their blocks from the storage and the overflow area while they give
    // those back.
    TriangleMesh mixed = canopy::generate("sphere", 20000, 1);
    const TriangleMesh extra = canopy::generate("random", 1500, 3);
    const uint32_t shift = uint32_t(mixed.vertices.size());
    mixed.vertices.insert(mixed.vertices.end(), extra.vertices.begin(), extra.vertices.end());
    for (uint32_t i : extra.indices) mixed.indices.push_back(i + shift);
    struct Case {
        const char* name;
        TriangleMesh mesh;
        bool grows, mapped;
    };
    const Case cases[] = {{"sphere", canopy::generate("sphere", 20000, 1), false, false},
                          {"sphere + random", mixed, false, false},
                          {"random", canopy::generate("random", 20000, 7), true, false},
                          {"random, mapped", canopy::generate("random", 20000, 7), true, true}};
    for (const Case& c : cases)
        for (const bool forward : {false, true}) {
            const std::string what = std::string(c.name) + (forward ? ", runs first to last" : ", runs last to first");
            const Bvh expected = build(c.mesh, BuildOptions{});
            canopy::NodeArray nodes = c.mapped ? canopy::NodeArray(canopy::NodeArray::MapFrom{0}) : canopy::NodeArray();
            canopy::PrimitiveOrder perm;
            const size_t storage = forward ? build_by_hand(c.mesh, nodes, perm, ForwardForEach{})
                                           : build_by_hand(c.mesh, nodes, perm, ReverseForEach{});
            EXPECT_TRUE(same_nodes(nodes, expected.nodes)) << what;
            EXPECT_EQ(perm, expected.permutation) << what;
            if (c.grows) {
                EXPECT_GT(nodes.capacity(), storage) << what << ": an array of its own";
                EXPECT_EQ(nodes.mapped(), canopy::growable_mappings_available()) << what;
            } else {
                EXPECT_EQ(nodes.capacity(), storage) << what << ": placed in the records' storage";
                EXPECT_EQ(nodes.mapped(), c.mapped) << what;
            }
        }
}

// A for_each that notes the mapped bytes when it is first called (the start
// of a placement's runs) and restarts the high-water mark there.
struct MappedAtFirstRun {
    long long mapped = -1;
    template <class Fn>
    void operator()(size_t k, Fn&& fn) {
        if (mapped < 0) {
            mapped = g_mapped.load();
            g_mapped_peak = mapped;
        }
        for (size_t i = 0; i < k; ++i) fn(i);
    }
};

TEST(BuildMemory, PlacementBesideTheRecordsGivesThemBackAsItGoes) {
    // A tree that does not fit over its records goes into a new array
    // (place_beside_records()) while the runs give back the records' storage
    // and the overflow area they have consumed: the mapped bytes never rise
    // by more than a little over what they were before the placement
    // (before 2026-12-05 (this test's commit) the new array came on top of
    // both, 1.86 nodes per record; a placement that gave nothing back would
    // rise by the whole new array). Everything but the chunks is a mapping
    // here (the storage from MapFrom{0}, the overflow area, the new array),
    // so the observer sees all of it; subtrees of up to 2,500 records put
    // most of their nodes past their records in the area (the chunks take
    // fewer than PlacementArena::kSpillMax).
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    const TriangleMesh m = canopy::generate("random", 40000, 11);
    const Bvh expected = build(m, BuildOptions{});
    canopy::set_mapped_bytes_observer(observe_mapped);
    {
        canopy::NodeArray nodes(canopy::NodeArray::MapFrom{0});
        canopy::PrimitiveOrder perm;
        MappedAtFirstRun start;
        const long long before = g_mapped.load();
        build_by_hand(m, nodes, perm, start, 2500);  // blocks of up to 2,150 nodes past their records: in the area
        ASSERT_TRUE(same_nodes(nodes, expected.nodes));
        EXPECT_EQ(perm, expected.permutation);
        const long long tree = (long long)(nodes.capacity() * sizeof(canopy::Node));
        ASSERT_GT(start.mapped, before);
        // The new array (1.86 nodes per record) against the storage and the
        // area given back: a rise of a few steps at most, here a tenth of it.
        EXPECT_LT(g_mapped_peak.load() - start.mapped, tree / 10)
            << "peak " << g_mapped_peak.load() << " from " << start.mapped << ", tree " << tree;
        // Afterwards: the tree alone (the storage and the area are gone).
        EXPECT_EQ(g_mapped.load() - before, tree);
    }
    EXPECT_EQ(g_mapped.load(), 0);
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, OverflowAreaGivesTheStorageFrontBackOnceTheTreeCannotFit) {
    // The records' storage's front (before the records) goes back to the
    // system once the blocks counted have more nodes than the storage has
    // slots, once, and the placement then leaves it alone.
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    canopy::set_mapped_bytes_observer(observe_mapped);
    for (const bool map : {false, true}) {
        canopy::NodeArray storage = tagged_mib(map);
        const canopy::Node* records = storage.data() + 4000;  // a front of 125 KiB
        canopy::OverflowArea area;
        area.reset(1000);
        area.watch_front(storage, records);
        const long long start = g_mapped.load();
        area.count_block(storage.capacity() / 2);
        area.count_block(storage.capacity() / 2);  // as many nodes as slots: it may still fit
        EXPECT_FALSE(area.front_given()) << map;
        EXPECT_EQ(g_mapped.load(), start) << map;
        area.count_block(1);
        EXPECT_TRUE(area.front_given()) << map;
        const long long front = (long long)whole_page_bytes(storage.data(), records);
        EXPECT_EQ(g_mapped.load(), start - front) << map;
        area.count_block(5000);  // once only
        EXPECT_EQ(g_mapped.load(), start - front) << map;
        // The records and what follows them are kept.
        for (size_t i = 4000; i < storage.capacity(); ++i) ASSERT_TRUE(has_tag(storage.data()[i], uint32_t(i))) << i;
        // A new build's area watches nothing until told.
        area.reset(1000);
        EXPECT_FALSE(area.front_given()) << map;
    }
    EXPECT_EQ(g_mapped.load(), 0);
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, PlacementBesideTheRecordsMovesPagesIntoTheNewArray) {
    // With the new array on huge pages (from BesideRecordsSizes::huge_min;
    // 0 here) and the storage a mapping, the runs hand the storage's and the
    // overflow area's consumed 2 MiB to the new array instead of giving them
    // back, each into a huge page of its own slots before writing it: the
    // tree must come out the same whatever moved where, with one run or
    // three (runs_min), in either order, and the counts must balance (the
    // tree alone is counted afterwards). 200,000 random triangles: a storage
    // of 7 MB, a new array of 12 MB, several huge pages each.
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    const TriangleMesh m = canopy::generate("random", 200000, 13);
    const Bvh expected = build(m, BuildOptions{});
    canopy::set_mapped_bytes_observer(observe_mapped);
    for (const size_t runs_min : {size_t(0), ~size_t(0)})
        for (const bool forward : {false, true}) {
            const std::string what = std::string(runs_min ? "one run" : "three runs") + (forward ? ", forward" : ", reverse");
            const long long before = g_mapped.load();
            {
                canopy::NodeArray nodes(canopy::NodeArray::MapFrom{0});
                canopy::PrimitiveOrder perm;
                const canopy::BesideRecordsSizes sizes{0, runs_min};
                if (forward)
                    build_by_hand(m, nodes, perm, ForwardForEach{}, 4096, sizes);
                else
                    build_by_hand(m, nodes, perm, ReverseForEach{}, 4096, sizes);
                EXPECT_TRUE(same_nodes(nodes, expected.nodes)) << what;
                EXPECT_EQ(perm, expected.permutation) << what;
                EXPECT_TRUE(nodes.mapped()) << what;
                EXPECT_EQ(g_mapped.load() - before, (long long)(nodes.capacity() * sizeof(canopy::Node))) << what;
                // The array can still grow (a mapping of several areas
                // now: grow_pages() copies when it cannot move them).
                const size_t n = nodes.size();
                nodes.resize(4 * nodes.capacity());
                EXPECT_TRUE(same_nodes_prefix(nodes, expected.nodes, n)) << what;
            }
            EXPECT_EQ(g_mapped.load(), before) << what;
        }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, PlacementHandsEachConsumedHugePageOnAtOnce) {
    // Moving pages, the run's first huge pages of new array are the only
    // ones it must touch fresh: every whole 2 MiB of the storage and of the
    // overflow area it consumes is handed on to the next one it writes as
    // soon as it is consumed (not at the next step of given-back records),
    // and the records in the storage's huge page shared with its front go
    // back once consumed. At 1.86 nodes per record, two new huge pages are
    // written before the first 2 MiB of the area is consumed, and a third
    // before the first whole 2 MiB of the storage when the records start
    // early in a huge page (here: 6.2 MiB at the peak); until this test's
    // commit (2026-12-06) one or two more were touched fresh (7.6 MiB here;
    // the peak of 1M random triangles' 2-thread builds 70.7 bytes per
    // triangle, now 69.4). 200,000 random triangles, one run, the new array
    // on huge pages from the start (BesideRecordsSizes{0, ...}).
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    const TriangleMesh m = canopy::generate("random", 200000, 13);
    const Bvh expected = build(m, BuildOptions{});
    canopy::set_mapped_bytes_observer(observe_mapped);
    {
        canopy::NodeArray nodes(canopy::NodeArray::MapFrom{0});
        canopy::PrimitiveOrder perm;
        MappedAtFirstRun start;
        build_by_hand(m, nodes, perm, start, 4096, canopy::BesideRecordsSizes{0, ~size_t(0)});
        ASSERT_TRUE(same_nodes(nodes, expected.nodes));
        EXPECT_EQ(perm, expected.permutation);
        constexpr long long kHuge = 2 << 20;
        const long long rise = g_mapped_peak.load() - start.mapped;
        EXPECT_LE(rise, 3 * kHuge + kHuge / 4) << "the peak rose by " << rise << " bytes over the runs' start";
    }
    EXPECT_EQ(g_mapped.load(), 0);
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, DenseOverflowAreaBuildsTheSameTree) {
    // A dense overflow area (from OverflowArea::kHugeAreaMin bytes; 0 here)
    // gives a block of k records 7k/8 slots (OverflowArea::slot()), makes a
    // 2 MiB region that a dense block writes first a huge page, counted
    // whole, and puts the nodes past a block's slots in its worker's chunks.
    // 200,000 random triangles, with leaf size 4 (about 0.86 nodes past the
    // records per record, within the slots but for a few blocks) and leaf
    // size 1 (every block has k/8 more nodes than slots, split between the
    // area and the chunks): the sequential build's tree, whether the
    // placement moves pages (a mapped storage: the new array on huge pages,
    // one run or three) or not (the storage on the heap), in either order of
    // runs, and the counts balance.
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    const TriangleMesh m = canopy::generate("random", 200000, 13);
    canopy::set_mapped_bytes_observer(observe_mapped);
    for (const uint32_t leaf : {4u, 1u}) {
        ByHand how;
        how.opt.max_leaf = leaf;
        how.dense_min = 0;
        const Bvh expected = build(m, how.opt);
        for (const int variant : {0, 1, 2})
            for (const bool forward : {false, true}) {
                const std::string what = "leaf " + std::to_string(leaf) + ", " +
                                         (variant == 0 ? "heap storage" : variant == 1 ? "one run" : "three runs") +
                                         (forward ? ", forward" : ", reverse");
                const long long before = g_mapped.load();
                size_t split = 0;
                how.split = &split;
                {
                    canopy::NodeArray nodes = variant == 0 ? canopy::NodeArray() : canopy::NodeArray(canopy::NodeArray::MapFrom{0});
                    canopy::PrimitiveOrder perm;
                    const canopy::BesideRecordsSizes sizes{canopy::kHugeMin, variant == 2 ? size_t(0) : canopy::kRunsMin};
                    if (forward)
                        build_by_hand(m, nodes, perm, ForwardForEach{}, 4096, sizes, how);
                    else
                        build_by_hand(m, nodes, perm, ReverseForEach{}, 4096, sizes, how);
                    EXPECT_TRUE(same_nodes(nodes, expected.nodes)) << what;
                    EXPECT_EQ(perm, expected.permutation) << what;
                    const long long tree = nodes.mapped() ? (long long)(nodes.capacity() * sizeof(canopy::Node)) : 0;
                    EXPECT_EQ(g_mapped.load() - before, tree) << what;
                }
                EXPECT_EQ(g_mapped.load(), before) << what;
                if (leaf == 1) {
                    EXPECT_GT(split, 10u) << what;
                }
            }
    }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, DiscardedPagesAreCountedOnce) {
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    canopy::set_mapped_bytes_observer(observe_mapped);
    for (const bool map : {false, true}) {
        {
            canopy::NodeArray v = tagged_mib(map);
            const long long start = g_mapped.load();
            // Whole pages inside the range only.
            const size_t given = v.discard(v.data() + 100, v.data() + 20000);
            EXPECT_EQ(given, whole_page_bytes(v.data() + 100, v.data() + 20000)) << map;
            EXPECT_EQ(g_mapped.load(), start - (long long)given) << map;
            // The rest is kept.
            for (size_t i = 0; i < 100; ++i) ASSERT_TRUE(has_tag(v.data()[i], uint32_t(i))) << i;
            for (size_t i = 20000; i < v.capacity(); ++i) ASSERT_TRUE(has_tag(v.data()[i], uint32_t(i))) << i;
        }
        // Mapped: unmapped without the discarded pages; heap: the probe takes
        // the whole block off, so the discarded pages are reported again.
        EXPECT_EQ(g_mapped.load(), 0) << map;
    }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, BigHugeMappingsEndOnAHugePage) {
    // A mapping advised for huge pages, from kWholeHugeMin bytes, is a whole
    // number of huge pages, and stays one as it grows, so that its last
    // piece is not filled 4 KiB at a time; smaller ones and those advised
    // against huge pages keep to 4 KiB pages. Counted as they are made.
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    canopy::set_mapped_bytes_observer(observe_mapped);
    constexpr size_t kHuge = size_t(2) << 20, kMin = canopy::kWholeHugeMin;
    struct Case {
        size_t bytes;
        bool huge;
        size_t want;
    };
    const Case cases[] = {{kMin + 5000, true, kMin + kHuge},
                          {kMin - 5000, true, kMin - 4096},
                          {kMin + 5000, false, kMin + 8192},
                          {kMin + kHuge, true, kMin + kHuge}};
    for (const Case& c : cases) {
        canopy::PageMapping m = canopy::map_pages(c.bytes, 0, true, c.huge);
        EXPECT_EQ(m.bytes, c.want) << c.bytes << " " << c.huge;
        EXPECT_EQ(g_mapped.load(), (long long)c.want) << c.bytes << " " << c.huge;
        canopy::grow_pages(m, c.want + 100);
        const size_t grown = c.huge && c.want + 100 >= kMin ? c.want + kHuge : c.want + 4096;
        EXPECT_EQ(m.bytes, grown) << c.bytes << " " << c.huge;
        EXPECT_EQ(g_mapped.load(), (long long)grown) << c.bytes << " " << c.huge;
        canopy::unmap_pages(m);
        EXPECT_EQ(g_mapped.load(), 0);
    }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, PopulatedPagesKeepWhatIsWrittenAndAreBroughtIn) {
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    constexpr size_t kBytes = size_t(64) << 10;  // 16 pages
    canopy::PageMapping m = canopy::map_pages(kBytes, 0, false, false);
    unsigned char* const p = static_cast<unsigned char*>(m.p);
    // Pages 0 and 1 written (page 1 in part), the rest never touched.
    for (size_t i = 0; i < 4096 + 100; ++i) p[i] = static_cast<unsigned char>(i * 7 + 1);
    // From inside page 1 to inside page 12: pages 1 to 12.
    canopy::populate_pages(p + 4096 + 50, 11 * 4096);
    // Resident now: pages 0 to 12, and not the three after them (checked
    // before anything reads there). MADV_POPULATE_WRITE came with Linux 5.14.
    utsname u{};
    int major = 0, minor = 0;
    if (uname(&u) == 0 && std::sscanf(u.release, "%d.%d", &major, &minor) == 2 &&
        (major > 5 || (major == 5 && minor >= 14))) {
        std::vector<unsigned char> resident(kBytes / 4096);
        ASSERT_EQ(mincore(p, kBytes, resident.data()), 0);
        for (size_t k = 0; k < resident.size(); ++k) EXPECT_EQ(resident[k] & 1, k <= 12 ? 1 : 0) << "page " << k;
    }
    // What was written is kept, the rest reads as zeros.
    for (size_t i = 0; i < 4096 + 100; ++i) ASSERT_EQ(p[i], static_cast<unsigned char>(i * 7 + 1)) << i;
    for (size_t i = 4096 + 100; i < kBytes; ++i) ASSERT_EQ(p[i], 0) << i;
    m.discarded = m.bytes;  // uncounted: nothing to report
    canopy::unmap_pages(m);
}

TEST(BuildMemory, PageLedgerCountsEachUnitOnce) {
    canopy::set_mapped_bytes_observer(observe_mapped);
    {
        canopy::PageLedger ledger(10 * 4096 + 100, 4096, true);  // 11 units, the last of 100 bytes
        ledger.touch(10, 20);
        EXPECT_EQ(g_mapped.load(), 4096);
        ledger.touch(4000, 8200);  // units 0 to 2
        EXPECT_EQ(g_mapped.load(), 3 * 4096);
        // Releases the whole units inside only (1 and 2), and reports those counted (both).
        const auto [a, b] = ledger.release(100, 3 * 4096 + 5);
        EXPECT_EQ(a, 4096u);
        EXPECT_EQ(b, 3 * 4096u);
        EXPECT_EQ(g_mapped.load(), 4096);
        ledger.touch(4096, 4097);  // released: not counted again
        EXPECT_EQ(g_mapped.load(), 4096);
        ledger.count_untouched();  // units 3 to 10: 7 whole and 100 bytes
        EXPECT_EQ(g_mapped.load(), 4096 + 7 * 4096 + 100);
        ledger.release_counted();
        EXPECT_EQ(g_mapped.load(), 0);
    }
    {
        canopy::PageLedger off(1 << 20, 4096, false);  // heap memory: reports nothing
        off.touch(0, 1 << 20);
        off.count_untouched();
        EXPECT_EQ(g_mapped.load(), 0);
    }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildMemory, HeapNodeArrayExpandsIntoAMappingPieceByPiece) {
    // expand() of heap storage copies it into a mapping a piece at a time,
    // giving back each piece of the heap block once copied: the observer
    // sees the mapping counted as it is written and the heap's pages given
    // back, so its running count stays near zero until the mapping's part
    // past the copy is counted (then the heap block goes, and its pages
    // given back are reported again as the heap probe takes it off whole).
    // A copy into a new block before freeing the old would show the whole
    // new size first.
    if (!canopy::growable_mappings_available()) GTEST_SKIP() << "no growable mappings on this system";
    struct Log {
        static void note(std::ptrdiff_t d) { events().push_back(d); }
        static std::vector<std::ptrdiff_t>& events() {
            static std::vector<std::ptrdiff_t> e;
            return e;
        }
    };
    Log::events().reserve(1 << 12);
    Log::events().clear();
    canopy::set_mapped_bytes_observer(Log::note);
    for (const size_t old_nodes : {size_t(3) << 15, size_t(1) << 18}) {  // 3 MiB (4 KiB units) and 8 (2 MiB)
        Log::events().clear();
        {
            canopy::NodeArray v;  // heap below kMapMin
            v.reserve(old_nodes);
            ASSERT_FALSE(v.mapped());
            tag_all(v);
            const size_t old_cap = v.capacity();
            v.expand(2 * old_cap);
            EXPECT_TRUE(v.mapped());
            for (size_t i = 0; i < old_cap; ++i) ASSERT_TRUE(has_tag(v.data()[i], uint32_t(i))) << i;
            const std::vector<std::ptrdiff_t> e = Log::events();
            ASSERT_GE(e.size(), 3u);
            long long sum = 0, high = 0, total = 0;
            for (size_t i = 0; i + 1 < e.size(); ++i) {
                sum += e[i];
                high = std::max(high, sum);
            }
            for (const std::ptrdiff_t d : e) total += d;
            const long long grown = (long long)((v.capacity() - old_cap) * sizeof(canopy::Node));
            // Before the heap block goes: at most the part past the copy and
            // one unit in writing (2 MiB on huge pages) plus the pages at the
            // pieces' edges.
            EXPECT_LE(high, grown + (2 << 20) + 16 * 4096) << old_nodes;
            EXPECT_EQ(total, (long long)(v.capacity() * sizeof(canopy::Node))) << old_nodes;
        }
    }
    canopy::set_mapped_bytes_observer(nullptr);
}

TEST(BuildLayout, FirstChildSlotFormula) {
    // Hand-checked on a 7-node tree: root (leaves 0) -> 1; its left child
    // (depth 1, 0 leaves before, 0 rights) -> 3; its right child (depth 1,
    // 2 leaves before, 1 right) -> 1 + 2 * (1 + 2 - 1) = 5.
    EXPECT_EQ(canopy::first_child_slot(0, 0, 0), 1u);
    EXPECT_EQ(canopy::first_child_slot(1, 0, 0), 3u);
    EXPECT_EQ(canopy::first_child_slot(1, 2, 1), 5u);

    canopy::LeafRank rank(200);
    for (uint32_t b : {0u, 5u, 63u, 64u, 65u, 127u, 128u, 199u}) rank.mark(b);
    rank.finish();
    EXPECT_EQ(rank.rank(0), 0u);
    EXPECT_EQ(rank.rank(1), 1u);
    EXPECT_EQ(rank.rank(63), 2u);
    EXPECT_EQ(rank.rank(64), 3u);
    EXPECT_EQ(rank.rank(65), 4u);
    EXPECT_EQ(rank.rank(66), 5u);
    EXPECT_EQ(rank.rank(128), 6u);
    EXPECT_EQ(rank.rank(199), 7u);
    EXPECT_EQ(rank.rank(200), 8u);
}

TEST(BuildLayout, OverflowNodesSitOnWholePagesWithinTheirRange) {
    // A block's nodes past its records lie within its slots, from their
    // first page boundary (a left child) or up to their last one (a right
    // child), and where they do not fit so, from their start or up to their
    // end.
    constexpr uint32_t kPage = 4096 / sizeof(canopy::Node);  // 128 nodes
    for (const bool right : {false, true})
        for (uint32_t begin : {0u, 1u, 127u, 128u, 1000u, 0xFFFFFF00u - 4096u})
            for (uint32_t records : {1u, 100u, 200u, 300u, 1031u, 4095u})
                for (uint32_t past : {0u, 1u, 50u, 99u, 150u, 600u, 4000u}) {
                    if (past >= records) continue;  // at most 2 * records - 1 nodes in all
                    const uint64_t end = uint64_t(begin) + records;
                    const uint64_t at = canopy::area_start(begin, end, past, right);
                    ASSERT_GE(at, begin) << begin << " " << records << " " << past << " " << right;
                    ASSERT_LE(at + past, end) << begin << " " << records << " " << past << " " << right;
                    const uint64_t first_page = (uint64_t(begin) + kPage - 1) / kPage * kPage, last_page = end / kPage * kPage;
                    if (!right)
                        EXPECT_EQ(at, first_page + past <= end ? first_page : begin) << begin << " " << records;
                    else
                        EXPECT_EQ(at + past, last_page >= begin + past ? last_page : end) << begin << " " << records;
                }
    // Siblings: the left one's unused end and the right one's unused start meet.
    const uint64_t left = canopy::area_start(1000, 2000, 700, false), right = canopy::area_start(2000, 3000, 700, true);
    EXPECT_EQ(left, 1024u);
    EXPECT_EQ(right + 700, 2944u);
    EXPECT_GE(right, left + 700 + 2 * kPage);  // two whole pages between them untouched
}

TEST(BuildMemory, SmallScenesGetSmallTasksAndBinSets) {
    // A one-off build's task cutoff: the option's, or n / 32 when less
    // (from 512), so that the workers' scratch arrays stay small beside a
    // small scene; a bin set sized for the bins its root uses.
    EXPECT_EQ(canopy::sched::scratch_cutoff(1000000, 4096), 4096u);
    EXPECT_EQ(canopy::sched::scratch_cutoff(131072, 4096), 4096u);
    EXPECT_EQ(canopy::sched::scratch_cutoff(50000, 4096), 1562u);
    EXPECT_EQ(canopy::sched::scratch_cutoff(1000, 4096), 512u);
    EXPECT_EQ(canopy::sched::scratch_cutoff(50000, 64), 64u);  // the tests' low cutoffs stay
    canopy::Workers workers(2, 50000, 32);
    EXPECT_EQ(workers[0].bins->max_bins(), 32u);
    workers.reset(2, 1u << 19, 32);  // 4 * 32 from kWidestBinsMin primitives on
    EXPECT_EQ(workers[1].bins->max_bins(), 128u);
    workers.reset(2, 100, 2);
    EXPECT_EQ(workers[1].bins->max_bins(), 4u);  // a multiple of 4
    // The second set follows the first within the block, for the most bins.
    canopy::BinSet set(32);
    set.clear(32);
    canopy::BinArrays& odd = set.second(32);
    EXPECT_EQ(odd.base, set.base + 3 * 32);
    for (int a = 0; a < 3; ++a)
        for (uint32_t k = 0; k < 32; ++k) EXPECT_EQ(odd.count(a, k) + set.count(a, k), 0u);
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
