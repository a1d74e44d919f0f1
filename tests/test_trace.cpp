// The scheduler trace: spans resolved to the canonical node they ran, the
// phases of team-parallel nodes, and a Chrome trace file that parses.
#include "core/scene.h"
#include "core/trace.h"
#include "schedulers/registry.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>

#include <unistd.h>

namespace {

using namespace canopy;

// Primitives under a node, counted through the tree.
uint32_t primitives_under(const Bvh& bvh, uint32_t node) {
    const Node& n = bvh.nodes[node];
    if (n.is_leaf()) return n.count;
    return primitives_under(bvh, n.index) + primitives_under(bvh, n.index + 1);
}

BuildOptions small_thresholds(uint32_t threads) {
    BuildOptions o;
    o.threads = threads;
    o.tuning.prims_per_thread = 256;
    o.tuning.task_cutoff = 512;
    o.tuning.parallel_node_min = 4096;
    return o;
}

TEST(Trace, SpansNameTheirCanonicalNodes) {
    if (!CANOPY_TRACE) GTEST_SKIP() << "tracing compiled out (-Dtrace=false)";
    const TriangleMesh mesh = generate("sphere", 60000, 3);
    const TriangleView view = mesh.view();
    for (const SchedulerEntry& s : schedulers()) {
        SCOPED_TRACE(s.name);
        const BuildOptions opt = small_thresholds(2);
        TraceLog log;
        const Bvh traced = s.build_triangles(view, opt, nullptr, &log);
        // Tracing never changes the tree.
        EXPECT_TRUE(traced == s.build_triangles(view, opt, nullptr));
        ASSERT_FALSE(log.spans().empty());
        std::map<TraceSpan::Kind, int> kinds;
        for (const TraceSpan& sp : log.spans()) {
            ++kinds[sp.kind];
            ASSERT_LT(sp.node, traced.nodes.size());
            EXPECT_EQ(primitives_under(traced, sp.node), sp.count) << "node " << sp.node;
            EXPECT_LE(sp.start_ns, sp.end_ns);
            EXPECT_LT(sp.worker, 2u);
        }
        // One span for the primitive records; the parallel drivers add one for
        // the final node array.
        EXPECT_EQ(kinds[TraceSpan::Prepare], 1);
        if (std::string(s.name) == "sequential") {
            EXPECT_EQ(kinds[TraceSpan::Place], 0);
            continue;
        }
        EXPECT_EQ(kinds[TraceSpan::Place], 1);
        // The root is big enough to run team-parallel, with its phases.
        EXPECT_GT(kinds[TraceSpan::Parallel], 0);
        for (const TraceSpan::Kind k : {TraceSpan::Start, TraceSpan::Bin, TraceSpan::Evaluate, TraceSpan::Finish})
            EXPECT_EQ(kinds[k], kinds[TraceSpan::Parallel]) << TraceSpan::kKindNames[k];
        // A SAH split marks sides and swaps, or with a team of fewer than
        // kTeamPartitionMin threads (two here) partitions by halves; a
        // middle split only counts its halves' bounds.
        EXPECT_EQ(kinds[TraceSpan::Mark], kinds[TraceSpan::Swap]);
        EXPECT_EQ(kinds[TraceSpan::Mark] + kinds[TraceSpan::Partition] + kinds[TraceSpan::Count],
                  kinds[TraceSpan::Parallel]);
        static_assert(2 < canopy::ParallelNode::kTeamPartitionMin);
        EXPECT_GT(kinds[TraceSpan::Partition], 0);
        EXPECT_EQ(kinds[TraceSpan::Mark], 0);
    }
}

TEST(Trace, ChromeTraceFileParses) {
    if (!CANOPY_TRACE) GTEST_SKIP() << "tracing compiled out (-Dtrace=false)";
    const TriangleMesh mesh = generate("sphere", 30000, 5);
    const SchedulerEntry* tbb = nullptr;
    for (const SchedulerEntry& s : schedulers())
        if (std::string(s.name) == "tbb" || (!tbb && std::string(s.name) != "sequential")) tbb = &s;
    if (!tbb) GTEST_SKIP() << "no parallel scheduler compiled in";
    TraceLog log;
    tbb->build_triangles(mesh.view(), small_thresholds(2), nullptr, &log);
    const std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("canopy_trace_" + std::to_string(::getpid()) + ".json");
    write_chrome_trace(log, path.string(), tbb->name, 2);
    std::ifstream in(path);
    const nlohmann::json j = nlohmann::json::parse(in);  // throws on malformed JSON
    std::filesystem::remove(path);
    EXPECT_EQ(j["otherData"]["scheduler"], tbb->name);
    size_t spans = 0;
    std::set<int> tracks_named, tracks_used;
    for (const auto& e : j["traceEvents"]) {
        if (e["ph"] == "M" && e["name"] == "thread_name") tracks_named.insert(e["tid"].get<int>());
        if (e["ph"] != "X") continue;
        ++spans;
        tracks_used.insert(e["tid"].get<int>());
        EXPECT_TRUE(e.contains("ts") && e.contains("dur"));
        EXPECT_TRUE(e["args"].contains("node") && e["args"].contains("primitives") && e["args"].contains("level"));
        const std::string mode = e["args"]["mode"];
        const std::string cat = e["cat"];
        if (cat == "phase")
            EXPECT_NE(e["name"].get<std::string>().find(": " + mode), std::string::npos) << e["name"];
        else if (cat == "build")
            EXPECT_TRUE(e["name"] == "build: " + mode && (mode == "prepare" || mode == "place")) << e["name"];
        else
            EXPECT_TRUE(cat == mode && (mode == "task" || mode == "inline" || mode == "parallel")) << mode;
    }
    EXPECT_EQ(spans, log.spans().size());
    EXPECT_EQ(tracks_named, tracks_used);  // every track used has a name
}

TEST(Trace, UnwritablePathIsAnError) {
    TraceLog log;
    EXPECT_THROW(write_chrome_trace(log, "/nonexistent-dir/t.json", "tbb", 2), Error);
}

}  // namespace
