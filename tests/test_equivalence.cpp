// The equivalence suite: every scheduler, at every thread count, builds the
// bit-identical node array and permutation as the sequential reference.
#include "core/depth_first.h"
#include "core/scene.h"
#include "core/validate.h"
#include "schedulers/registry.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#if CANOPY_HAVE_TBB
#include <tbb/parallel_for.h>
#endif
#if CANOPY_HAVE_OPENMP
#include <omp.h>
#endif

namespace {

using namespace canopy;

using canopy::test_util::small_tuning;

// True when `name` is one of the comma-separated names in `list`.
bool listed(const char* list, const char* name) {
    const std::string_view l(list), n(name);
    size_t start = 0;
    while (start <= l.size()) {
        const size_t comma = std::min(l.find(',', start), l.size());
        if (l.substr(start, comma - start) == n) return true;
        start = comma + 1;
    }
    return false;
}

// The schedulers under test: all compiled in, or those named in the
// environment variable CANOPY_TEST_SCHEDULERS ("tbb,sequential"), which the
// ThreadSanitizer run uses.
std::vector<SchedulerEntry> tested_schedulers() {
    const char* env = std::getenv("CANOPY_TEST_SCHEDULERS");
    std::vector<SchedulerEntry> out;
    for (const SchedulerEntry& s : schedulers())
        if (!env || listed(env, s.name))
            out.push_back(s);
    return out;
}

void expect_same(const Bvh& ref, const Bvh& got, const std::string& what) {
    ASSERT_EQ(ref.nodes.size(), got.nodes.size()) << what;
    ASSERT_EQ(ref.permutation.size(), got.permutation.size()) << what;
    if (ref.nodes.empty() && ref.permutation.empty()) return;  // memcmp of null pointers is undefined
    EXPECT_EQ(0, std::memcmp(ref.nodes.data(), got.nodes.data(), ref.nodes.size() * sizeof(Node))) << what;
    EXPECT_EQ(0, std::memcmp(ref.permutation.data(), got.permutation.data(),
                             ref.permutation.size() * sizeof(uint32_t)))
        << what;
}

TriangleMesh scaled(TriangleMesh m, float s) {
    for (auto& v : m.vertices) v *= s;
    return m;
}

struct NamedMesh {
    std::string name;
    TriangleMesh mesh;
};

const std::vector<NamedMesh>& matrix_scenes() {
    static const std::vector<NamedMesh> scenes = [] {
        std::vector<NamedMesh> s;
        s.push_back({"sphere", generate("sphere", 20000, 1)});
        s.push_back({"random", generate("random", 20000, 7)});
        s.push_back({"stadium", generate("stadium", 30000, 1)});
        s.push_back({"plane", generate("plane", 10000, 1)});
        s.push_back({"coincident", generate("coincident", 3000, 1)});
        s.push_back({"tiny", scaled(generate("random", 8000, 3), 1e-30f)});
        s.push_back({"few", generate("random", 100, 5)});
        s.push_back({"room", generate("room", 20000, 1)});  // size splits, one at the root
        return s;
    }();
    return scenes;
}

TEST(Equivalence, FullMatrixOnGeneratedScenes) {
    for (const NamedMesh& scene : matrix_scenes()) {
        const TriangleView view = scene.mesh.view();
        for (uint32_t bins : {2u, 8u, 16u, 64u}) {
            const BuildOptions seq_opt = small_tuning(bins, 1);
            BuildStats seq_stats;
            const Bvh ref = build<Sequential>(view, seq_opt, &seq_stats);
            const ValidationReport rep = validate(ref, view, seq_opt);
            ASSERT_TRUE(rep.ok()) << scene.name << " bins " << bins << ": " << rep.summary();
            // The room exercises the size split, also at the team-parallel root.
            if (scene.name == "room") {
                EXPECT_GT(seq_stats.skipped.size_splits, 0u) << "bins " << bins;
            }
            // The stadium's big sparse box is where rotations pay.
            if (scene.name == "stadium") {
                EXPECT_GT(seq_stats.skipped.rotations, 0u) << "bins " << bins;
            }
            for (const SchedulerEntry& s : tested_schedulers()) {
                for (uint32_t threads : {1u, 2u, 3u, 4u, 8u}) {
                    const BuildOptions opt = small_tuning(bins, threads);
                    const int repeats = threads == 1 ? 1 : 2;
                    for (int r = 0; r < repeats; ++r) {
                        BuildStats stats;
                        const Bvh got = s.build_triangles(view, opt, &stats);
                        const std::string what = scene.name + " bins " + std::to_string(bins) + " " + s.name +
                                                 " threads " + std::to_string(threads) + " run " +
                                                 std::to_string(r);
                        expect_same(ref, got, what);
                        EXPECT_LE(stats.threads_used, threads) << what;
                        if (::testing::Test::HasFailure()) return;
                    }
                }
            }
        }
    }
}

// A one-off parallel build keeps its records in the final node array's
// storage (BuildState::allocate_records_in_tree(): 1.1 slots per record and
// a few), writes each inline subtree's nodes over its own records (those it
// has more than records in the overflow area at its range, or, a few, in
// the worker's chunks), and moves them to the front of that storage when
// the tree fits there; a tree of more nodes gets an array of its own, into
// which the blocks are copied while the storage is given back
// (place_beside_records()). Every way gives the sequential tree: the
// sphere's tree fits (0.98 nodes per primitive), the sphere with random
// triangles added fits too with blocks that outgrow their records (1.05
// nodes per primitive, chunks of 24 nodes: the rest crosses chunks), and
// random triangles' trees (1.85 per primitive) do not.
TEST(Equivalence, FinalArrayInTheRecordsStorageOrItsOwn) {
    struct Case {
        const char* name;
        TriangleMesh mesh;
        bool in_place;
        bool more_nodes_than_primitives;  // so some block outgrows its records
    };
    TriangleMesh mixed = generate("sphere", 20000, 1);
    const TriangleMesh extra = generate("random", 1500, 3);
    const uint32_t shift = static_cast<uint32_t>(mixed.vertices.size());
    mixed.vertices.insert(mixed.vertices.end(), extra.vertices.begin(), extra.vertices.end());
    for (uint32_t i : extra.indices) mixed.indices.push_back(i + shift);
    const Case cases[] = {{"sphere", generate("sphere", 20000, 1), true, false},
                          {"sphere and random", std::move(mixed), true, true},
                          {"random", generate("random", 20000, 7), false, true}};
    for (const Case& c : cases) {
        const TriangleView view = c.mesh.view();
        const size_t n = view.triangle_count();
        const size_t storage = canopy::NodesBeforeRecords::initial_capacity(static_cast<uint32_t>(n));
        const Bvh ref = build<Sequential>(view, small_tuning(32, 1));
        ASSERT_EQ(ref.nodes.size() <= storage, c.in_place) << c.name << ": " << ref.nodes.size() << " nodes";
        ASSERT_EQ(ref.nodes.size() > n, c.more_nodes_than_primitives) << c.name << ": " << ref.nodes.size();
        for (const SchedulerEntry& s : tested_schedulers()) {
            if (std::string_view(s.name) == "sequential") continue;
            BuildStats stats;
            const Bvh got = s.build_triangles(view, small_tuning(32, 2), &stats);
            const std::string what = std::string(c.name) + " " + s.name;
            ASSERT_EQ(stats.threads_used, 2u) << what;
            expect_same(ref, got, what);
            if (c.in_place) {
                EXPECT_EQ(got.nodes.capacity(), storage) << what;
            } else {
                // Its own array, a mapping (whole pages) where the system has them.
                EXPECT_GE(got.nodes.capacity(), got.nodes.size()) << what;
                EXPECT_LT(got.nodes.capacity() - got.nodes.size(), 4096 / sizeof(canopy::Node)) << what;
                EXPECT_EQ(got.nodes.mapped(), canopy::growable_mappings_available()) << what;
            }
        }
    }
}

// The default tuning on a scene big enough for team-parallel nodes near the
// root (stadium: one dense object) and for task cutoffs.
TEST(Equivalence, DefaultTuningOnLargerScenes) {
    for (const char* spec : {"gen:stadium:200000", "gen:sphere:150000"}) {
        const Scene scene = load_scene(spec);
        const TriangleView view = scene.mesh.view();
        BuildOptions opt;
        opt.threads = 1;
        const Bvh ref = build<Sequential>(view, opt);
        ASSERT_TRUE(validate(ref, view, opt).ok()) << spec;
        for (const SchedulerEntry& s : tested_schedulers()) {
            for (uint32_t threads : {2u, 4u}) {
                opt.threads = threads;
                BuildStats stats;
                expect_same(ref, s.build_triangles(view, opt, &stats),
                            std::string(spec) + " " + s.name + " threads " + std::to_string(threads));
                if (std::string(s.name) != "sequential") {
                    EXPECT_GT(stats.skipped.parallel_nodes, 0u) << s.name;
                }
            }
        }
    }
}

// A warm builder (canopy::Builder, reached through the registry) builds the
// same trees as build<S>() over a sequence of scenes of different sizes and
// options, reusing its memory; on bad input it throws and leaves the
// caller's tree alone.
TEST(Equivalence, WarmBuildersMatchBuild) {
    const TriangleMesh big = generate("sphere", 20000, 1);
    const TriangleMesh small = generate("random", 500, 3);
    const TriangleMesh room = generate("room", 20000, 1);
    const TriangleMesh empty;
    TriangleMesh bad = generate("random", 300, 4);
    bad.vertices[100].y = std::numeric_limits<float>::quiet_NaN();
    struct Step {
        const TriangleMesh* mesh;
        uint32_t bins, leaf;
    };
    const Step steps[] = {{&big, 16, 4}, {&small, 16, 4}, {&room, 32, 4}, {&empty, 16, 4},
                          {&big, 8, 1},  {&big, 8, 1},    {&big, 8, 1},   {&small, 256, 7}};
    for (const SchedulerEntry& s : tested_schedulers()) {
        const std::unique_ptr<WarmBuilder> builder = s.make_warm_builder();
        Bvh out;
        const Node* seen[8] = {};
        for (size_t k = 0; k < std::size(steps); ++k) {
            BuildOptions opt = small_tuning(steps[k].bins, 2);
            opt.max_leaf = steps[k].leaf;
            BuildStats warm_stats, stats;
            builder->build(steps[k].mesh->view(), out, opt, &warm_stats);
            const Bvh ref = s.build_triangles(steps[k].mesh->view(), opt, &stats);
            expect_same(ref, out, std::string(s.name) + " step " + std::to_string(k));
            EXPECT_EQ(warm_stats.skipped.bound_leaves, stats.skipped.bound_leaves) << s.name << " step " << k;
            EXPECT_EQ(warm_stats.skipped.size_splits, stats.skipped.size_splits) << s.name << " step " << k;
            seen[k] = out.nodes.data();
            if (::testing::Test::HasFailure()) return;
        }
        // Steps 4 to 6 build the same scene: the builder and the caller
        // swap two node arrays, so step 6 reuses step 4's.
        EXPECT_EQ(seen[6], seen[4]) << s.name;

        const Bvh before = out;
        EXPECT_THROW(builder->build(bad.view(), out, small_tuning(16, 2), nullptr), InputError) << s.name;
        EXPECT_TRUE(out == before) << s.name << ": a failed build changed the caller's tree";
        builder->build(big.view(), out, small_tuning(16, 2), nullptr);
        expect_same(s.build_triangles(big.view(), small_tuning(16, 2)), out, std::string(s.name) + " after an error");
    }

    // Boxes, on the library's Builder directly.
    std::vector<Box> boxes(small.triangle_count());
    for (size_t t = 0; t < boxes.size(); ++t)
        for (int k = 0; k < 3; ++k) boxes[t].extend(small.vertex(t, k));
    Builder<Sequential> b;
    Bvh out;
    b.build(big.view(), out, small_tuning(16, 1));
    b.build(std::span<const Box>(boxes), out, small_tuning(16, 1));
    expect_same(build<Sequential>(std::span<const Box>(boxes), small_tuning(16, 1)), out, "boxes");
}

TEST(Equivalence, BoxInputMatchesToo) {
    const TriangleMesh m = generate("random", 5000, 11);
    std::vector<Box> boxes(m.triangle_count());
    for (size_t t = 0; t < boxes.size(); ++t)
        for (int k = 0; k < 3; ++k) boxes[t].extend(m.vertex(t, k));
    const BuildOptions seq = small_tuning(16, 1);
    const Bvh ref = build<Sequential>(std::span<const Box>(boxes), seq);
    ASSERT_TRUE(validate(ref, std::span<const Box>(boxes), seq).ok());
    // Same boxes as the triangles' boxes: the same tree.
    expect_same(ref, build<Sequential>(m.view(), seq), "boxes vs triangles");
    for (const SchedulerEntry& s : tested_schedulers())
        expect_same(ref, s.build_boxes(boxes, small_tuning(16, 3), nullptr), s.name);
}

TEST(Equivalence, ConcurrentBuildsFromUserThreads) {
    const TriangleMesh m = generate("sphere", 30000, 1);
    const Bvh ref = build<Sequential>(m.view(), small_tuning(16, 1));
    for (const SchedulerEntry& s : tested_schedulers()) {
        std::atomic<int> mismatches{0};
        std::vector<std::thread> users;
        for (int u = 0; u < 3; ++u)
            users.emplace_back([&] {
                for (int r = 0; r < 2; ++r)
                    if (!(s.build_triangles(m.view(), small_tuning(16, 2), nullptr) == ref)) ++mismatches;
            });
        for (auto& t : users) t.join();
        EXPECT_EQ(mismatches.load(), 0) << s.name;
    }
}

#if CANOPY_HAVE_TBB
TEST(Equivalence, InsideAUsersTbbParallelRegion) {
    const TriangleMesh m = generate("sphere", 20000, 1);
    const Bvh ref = build<Sequential>(m.view(), small_tuning(16, 1));
    for (const SchedulerEntry& s : tested_schedulers()) {
        std::atomic<int> mismatches{0};
        tbb::parallel_for(0, 4, [&](int) {
            if (!(s.build_triangles(m.view(), small_tuning(16, 2), nullptr) == ref)) ++mismatches;
        });
        EXPECT_EQ(mismatches.load(), 0) << s.name;
    }
}
#endif

#if CANOPY_HAVE_OPENMP
TEST(Equivalence, InsideAUsersOpenMPParallelRegion) {
    const TriangleMesh m = generate("sphere", 20000, 1);
    const Bvh ref = build<Sequential>(m.view(), small_tuning(16, 1));
    for (const SchedulerEntry& s : tested_schedulers()) {
        int mismatches = 0;
#pragma omp parallel num_threads(2) reduction(+ : mismatches)
        {
            if (!(s.build_triangles(m.view(), small_tuning(16, 2), nullptr) == ref)) ++mismatches;
        }
        EXPECT_EQ(mismatches, 0) << s.name;
    }
}
#endif

// The meshes of ../shared/scenes when present (slow suite).
TEST(EquivalenceSlow, SharedScenes) {
    const std::filesystem::path dir = CANOPY_SCENES_DIR;
    if (!std::filesystem::exists(dir / "cow.obj")) GTEST_SKIP() << "shared scenes not found at " << dir;
    for (const char* f : {"cow.obj", "CBcoil.obj", "bunny.obj", "dragon_vrip_res3.obj", "sibenik.obj",
                          "dragon_vrip_res2.obj"}) {
        const Scene scene = load_scene((dir / f).string());
        const TriangleView view = scene.mesh.view();
        BuildOptions opt;
        opt.threads = 1;
        const Bvh ref = build<Sequential>(view, opt);
        const ValidationReport rep = validate(ref, view, opt);
        ASSERT_TRUE(rep.ok()) << f << ": " << rep.summary();
        for (const SchedulerEntry& s : tested_schedulers())
            for (uint32_t threads : {1u, 2u}) {
                opt.threads = threads;
                expect_same(ref, s.build_triangles(view, opt, nullptr),
                            std::string(f) + " " + s.name + " threads " + std::to_string(threads));
            }
    }
}

// Nodes of 2^19 records and more (four times the bins), and team-parallel
// nodes of more than 32 chunks of ParallelNode::kChunk records (the sphere's
// root: longer chunks, each bin set accumulating several of them), at two
// threads (partitioned by halves) and at four (marked and swapped by
// chunks, see ParallelNode::kTeamPartitionMin).
TEST(EquivalenceSlow, MillionTriangleScenes) {
    for (const char* spec : {"gen:sphere:1200000", "gen:stadium:1000000"}) {
        const Scene scene = load_scene(spec);
        const TriangleView view = scene.mesh.view();
        BuildOptions opt;
        opt.threads = 1;
        const Bvh ref = build<Sequential>(view, opt);
        ASSERT_TRUE(validate(ref, view, opt).ok()) << spec;
        for (const SchedulerEntry& s : tested_schedulers())
            for (const uint32_t threads : {2u, 4u}) {
                opt.threads = threads;
                expect_same(ref, s.build_triangles(view, opt, nullptr),
                            std::string(spec) + " " + s.name + " threads " + std::to_string(threads));
            }
    }
}

}  // namespace

// Regression test for a bug found by fuzz_build (2026-12-02): when a
// team-parallel node became a leaf, the OpenMP drivers freed it inside the
// `single` that follows run_parallel_node, while a thread of the team could
// still be reading it in run_parallel_node's `splits()` test (a single has
// no barrier on entry). The fuzz input (4 vertices, tuning 1/1/1) hit it in
// about a third of its runs under AddressSanitizer. Tiny scenes whose root is
// team-parallel (every size qualifies with this tuning) and a leaf, or splits
// once, built many times: the sanitizer builds of this suite see a
// use-after-free if the freeing comes back; every build must still give the
// sequential tree.
TEST(Equivalence, TeamParallelNodesThatEndAsLeaves) {
    BuildOptions opt;
    opt.threads = 2;
    opt.max_leaf = 8;
    opt.tuning.prims_per_thread = 1;
    opt.tuning.task_cutoff = 1;
    opt.tuning.parallel_node_min = 1;
    // Coincident triangles up to the leaf size end as a leaf (no split
    // pays; 5 and more, since nodes of at most kExactMaxPrims never run
    // team-parallel); random ones split once or twice.
    const TriangleMesh meshes[] = {generate("coincident", 5, 1), generate("coincident", 8, 1),
                                   generate("random", 2, 3), generate("random", 7, 3)};
    for (const TriangleMesh& m : meshes) {
        const size_t n = m.triangle_count();
        BuildOptions seq = opt;
        seq.threads = 1;
        const Bvh ref = build<Sequential>(m.view(), seq);
        for (const SchedulerEntry& s : tested_schedulers()) {
            int mismatches = 0;
            for (int r = 0; r < 100; ++r)
                if (!(s.build_triangles(m.view(), opt, nullptr) == ref)) ++mismatches;
            EXPECT_EQ(mismatches, 0) << s.name << " n=" << n;
        }
    }
}

// With every threshold at its lowest, the team would take nodes of any size,
// even those that run_node() costs exactly instead of binning (at most
// kExactMaxPrims primitives): they must not be team-parallel, or the tree
// would depend on the driver. Found by fuzz_build (omp_levels differed from
// the sequential tree on a node of 4 triangles).
TEST(Equivalence, SmallNodesAreNeverTeamParallel) {
    BuildOptions opt;
    opt.threads = 2;
    opt.tuning.prims_per_thread = 1;
    opt.tuning.task_cutoff = 1;
    opt.tuning.parallel_node_min = 1;
    for (uint32_t n = 2; n <= 12; ++n)
        for (uint32_t seed = 1; seed <= 20; ++seed) {
            const TriangleMesh m = generate(seed % 2 ? "random" : "sphere", n, seed);
            BuildOptions seq = opt;
            seq.threads = 1;
            const Bvh ref = build<Sequential>(m.view(), seq);
            for (const SchedulerEntry& s : tested_schedulers())
                expect_same(ref, s.build_triangles(m.view(), opt, nullptr),
                            std::string(s.name) + " n=" + std::to_string(n) + " seed " + std::to_string(seed));
        }
}
