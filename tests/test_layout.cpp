// Tests of the canonical layout (core/layout.h) and of the memory a build
// places its nodes in (core/memory.h, core/node_array.h,
// core/overflow_area.h): the arithmetic node placement and subtree blocks
// against the sequential build's tree, placement over and beside the
// records, huge-page allocations, node arrays that grow in place or into
// mappings, and the page ledger.
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
using canopy::test_util::geometric_mesh;
using canopy::test_util::grid_mesh;
using canopy::test_util::random_mesh;

Bvh build(const TriangleMesh& m, const BuildOptions& opt = {}, BuildStats* stats = nullptr) {
    return canopy::build<Sequential>(m.view(), opt, stats);
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
