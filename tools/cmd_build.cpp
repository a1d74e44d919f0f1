// canopy build: build a BVH over a scene, validate it, print statistics.
#include "alloc_probe.h"
#include "cli.h"
#include "core/bvh.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/trace.h"
#include "core/validate.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <thread>

namespace canopy::cli {

namespace {

using Clock = std::chrono::steady_clock;

struct BuildArgs {
    std::string scene;
    std::string scheduler = default_scheduler();
    uint32_t threads = 0;
    uint32_t bins = BuildOptions{}.bins;
    uint32_t leaf = BuildOptions{}.max_leaf;
    uint32_t rotate_min = BuildOptions{}.rotate_min;
    uint32_t repeat = 1;
    bool json = false;
    bool warm = false;
    std::string save;
    std::string trace;
};

int run_build(const BuildArgs& a) {
    const SchedulerEntry* sched = &scheduler_or_throw(a.scheduler);
    Scene scene = a.scene.empty() ? default_scene() : load_scene(a.scene);
    BuildOptions opt;
    opt.bins = a.bins;
    opt.max_leaf = a.leaf;
    opt.rotate_min = a.rotate_min;
    opt.threads = a.threads;
    opt.check();
    const TriangleView view = scene.mesh.view();

    std::vector<double> times;
    Bvh bvh;
    BuildStats stats;
    size_t peak_bytes = 0;  // heap high-water mark of the first build, beyond what was held before it
    if (a.warm) {
        // One builder for every build. Untimed builds first fill its memory:
        // the first allocates its buffers, and it swaps trees with the
        // caller, so it holds a spare tree's arrays from the third on. The
        // timed builds then allocate almost nothing.
        const std::unique_ptr<WarmBuilder> builder = sched->make_warm_builder();
        alloc_probe::start();
        builder->build(view, bvh, opt, &stats);
        peak_bytes = alloc_probe::peak_since_start();
        Bvh fresh;
        for (int r = 0; r < 2; ++r) builder->build(view, fresh, opt, &stats);
        for (uint32_t r = 0; r < a.repeat; ++r) {
            const auto t0 = Clock::now();
            builder->build(view, fresh, opt, &stats);
            const auto t1 = Clock::now();
            times.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
            if (!(fresh == bvh)) {
                std::cerr << "canopy build: warm builds differ (scheduler " << sched->name << ")\n";
                return kInvalid;
            }
        }
        if (!(bvh == sched->build_triangles(view, opt))) {
            std::cerr << "canopy build: the warm builder's tree differs from build() (scheduler " << sched->name
                      << ")\n";
            return kInvalid;
        }
    }
    for (uint32_t r = 0; !a.warm && r < a.repeat; ++r) {
        Bvh fresh;  // the previous tree is freed outside the timed region
        if (r == 0) alloc_probe::start();
        const auto t0 = Clock::now();
        fresh = sched->build_triangles(view, opt, &stats);
        const auto t1 = Clock::now();
        if (r == 0) peak_bytes = alloc_probe::peak_since_start();
        times.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
        if (r > 0 && !(fresh == bvh)) {
            std::cerr << "canopy build: repeated builds differ (scheduler " << sched->name << ")\n";
            return kInvalid;
        }
        bvh = std::move(fresh);
    }
    if (!a.trace.empty() && !CANOPY_TRACE)
        throw UsageError("--trace: this canopy was built with tracing compiled out (-Dtrace=false)");
    if (!a.trace.empty()) {
        // One more build, traced, after the timed ones (so tracing never
        // shows in build_ms); it must give the same tree.
        TraceLog log;
        const Bvh traced = sched->build_triangles(view, opt, nullptr, &log);
        if (!(traced == bvh)) {
            std::cerr << "canopy build: the traced build differs from the untraced one\n";
            return kInvalid;
        }
        write_chrome_trace(log, a.trace, sched->name, opt.threads ? opt.threads : std::thread::hardware_concurrency());
    }
    const ValidationReport report = validate(bvh, view, opt);
    const TreeStats ts = tree_stats(bvh);
    const double sah = sah_cost(bvh);
    const double ms = median(times);
    const uint32_t threads = a.threads ? a.threads : std::max(1u, std::thread::hardware_concurrency());

    if (!a.save.empty()) save_bvh(bvh, a.save);

    if (a.json) {
        nlohmann::ordered_json j;
        j["scene"] = scene.name;
        j["triangles"] = view.triangle_count();
        j["nodes"] = ts.nodes;
        j["leaves"] = ts.leaves;
        j["depth"] = ts.depth;
        j["sah"] = sah;
        j["build_ms"] = ms;
        j["tree_hash"] = tree_hash_hex(bvh);
        j["valid"] = report.ok();
        j["scheduler"] = sched->name;
        j["threads"] = threads;
        j["threads_used"] = stats.threads_used;
        j["bins"] = opt.bins;
        j["max_leaf"] = opt.max_leaf;
        j["rotate_min"] = opt.rotate_min;
        j["repeat"] = a.repeat;
        j["warm"] = a.warm;
        j["peak_bytes"] = peak_bytes;
        j["peak_bytes_per_triangle"] = view.triangle_count() ? double(peak_bytes) / double(view.triangle_count()) : 0.0;
        nlohmann::ordered_json sk;
        sk["axes_not_binned"] = stats.skipped.axes_not_binned;
        sk["coincident_nodes"] = stats.skipped.coincident_nodes;
        sk["depth_cap_splits"] = stats.skipped.depth_cap_splits;
        sk["single_leaves"] = stats.skipped.single_leaves;
        sk["inline_tasks"] = stats.skipped.inline_tasks;
        sk["parallel_nodes"] = stats.skipped.parallel_nodes;
        sk["bound_leaves"] = stats.skipped.bound_leaves;
        sk["exact_nodes"] = stats.skipped.exact_nodes;
        sk["sampled_axes"] = stats.skipped.sampled_axes;
        sk["rotations"] = stats.skipped.rotations;
        j["skipped"] = sk;
        j["size_splits"] = stats.skipped.size_splits;
        std::cout << j.dump() << "\n";
    } else {
        std::printf("scene      %s (%s)\n", scene.name.c_str(), scene.format.c_str());
        std::printf("triangles  %zu\n", view.triangle_count());
        std::printf("scheduler  %s, threads %u (used %u)\n", sched->name, threads, stats.threads_used);
        std::printf("nodes      %u\nleaves     %u\ndepth      %u\n", ts.nodes, ts.leaves, ts.depth);
        std::printf("sah        %.4f\n", sah);
        std::printf("build      %.3f ms (median of %u%s)\n", ms, a.repeat, a.warm ? ", warm" : "");
        std::printf("memory     %.1f MB heap peak (%.1f bytes per triangle, the tree included)\n", double(peak_bytes) / 1e6,
                    view.triangle_count() ? double(peak_bytes) / double(view.triangle_count()) : 0.0);
        std::printf("tree hash  %s\n", tree_hash_hex(bvh).c_str());
        std::printf("valid      %s\n", report.ok() ? "yes" : "NO");
        std::fflush(stdout);
    }
    if (!report.ok()) {
        std::cerr << "canopy build: the tree failed validation: " << report.summary() << "\n";
        return kInvalid;
    }
    return kOk;
}

}  // namespace

Runner add_build(CLI::App& app) {
    auto a = std::make_shared<BuildArgs>();
    CLI::App* build = app.add_subcommand("build", "Build a BVH over a scene, validate it and print statistics");
    build->add_option("scene", a->scene, "Mesh file or gen:NAME:COUNT[:SEED] (default: gen:sphere:100000)");
    build->add_option("--scheduler", a->scheduler, "Scheduler: " + scheduler_names())->capture_default_str();
    build->add_option("--threads", a->threads, "Thread upper bound (0 = all hardware threads)")->capture_default_str();
    build->add_option("--bins", a->bins, "Bins per axis (2-256)")->capture_default_str();
    build->add_option("--leaf", a->leaf, "Largest leaf (1-255)")->capture_default_str();
    build->add_option("--rotate-min", a->rotate_min,
                      "Nodes of at least this many primitives may take a tree rotation (0 = none, else >= 256)")
        ->capture_default_str();
    build->add_option("--repeat", a->repeat, "Builds to time; build_ms is their median")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100000u));
    build->add_flag("--json", a->json, "One JSON object on stdout");
    build->add_flag("--warm", a->warm,
                    "Time warm builds: one builder keeps its memory (and the previous tree's) between builds, "
                    "after a first untimed build");
    build->add_option("--save", a->save, "Write the BVH to FILE (canopy binary format)");
    build->add_option("--trace", a->trace,
                      "Write a Chrome trace (JSON, for Perfetto / chrome://tracing) of one more build to FILE");
    return [a, build]() { return *build ? run_build(*a) : -1; };
}

}  // namespace canopy::cli
