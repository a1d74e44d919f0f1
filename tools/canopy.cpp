// canopy: the command-line tool.
//
// Exit status: 0 success; 1 bad input or a failed build (the first line on
// stderr says what and where); 2 usage error; 3 validation failed.
#include "core/bvh.h"
#include "core/error.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/validate.h"
#include "schedulers/registry.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <string>
#include <vector>

#ifndef CANOPY_DEFAULT_SCHEDULER
#define CANOPY_DEFAULT_SCHEDULER "sequential"
#endif

namespace {

using namespace canopy;
using Clock = std::chrono::steady_clock;

enum Exit { kOk = 0, kInput = 1, kUsage = 2, kInvalid = 3 };

std::string default_scheduler() {
    return find_scheduler(CANOPY_DEFAULT_SCHEDULER) ? CANOPY_DEFAULT_SCHEDULER : "sequential";
}

std::string scheduler_names() {
    std::string s;
    for (const auto& e : schedulers()) s += (s.empty() ? "" : ", ") + std::string(e.name);
    return s;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

struct BuildArgs {
    std::string scene;
    std::string scheduler = default_scheduler();
    uint32_t threads = 0;
    uint32_t bins = BuildOptions{}.bins;
    uint32_t leaf = BuildOptions{}.max_leaf;
    uint32_t repeat = 1;
    bool json = false;
    std::string save;
};

int run_build(const BuildArgs& a) {
    const SchedulerEntry* sched = find_scheduler(a.scheduler);
    if (!sched) {
        std::cerr << "canopy build: unknown scheduler '" << a.scheduler << "' (compiled in: " << scheduler_names()
                  << ")\n";
        return kUsage;
    }
    Scene scene = a.scene.empty() ? default_scene() : load_scene(a.scene);
    BuildOptions opt;
    opt.bins = a.bins;
    opt.max_leaf = a.leaf;
    opt.threads = a.threads;
    opt.check();
    const TriangleView view = scene.mesh.view();

    std::vector<double> times;
    Bvh bvh;
    BuildStats stats;
    for (uint32_t r = 0; r < a.repeat; ++r) {
        Bvh fresh;  // the previous tree is freed outside the timed region
        const auto t0 = Clock::now();
        fresh = sched->build_triangles(view, opt, &stats);
        const auto t1 = Clock::now();
        times.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
        if (r > 0 && !(fresh == bvh)) {
            std::cerr << "canopy build: repeated builds differ (scheduler " << sched->name << ")\n";
            return kInvalid;
        }
        bvh = std::move(fresh);
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
        j["repeat"] = a.repeat;
        nlohmann::ordered_json sk;
        sk["axes_not_binned"] = stats.skipped.axes_not_binned;
        sk["coincident_nodes"] = stats.skipped.coincident_nodes;
        sk["depth_cap_splits"] = stats.skipped.depth_cap_splits;
        sk["single_leaves"] = stats.skipped.single_leaves;
        sk["inline_tasks"] = stats.skipped.inline_tasks;
        sk["parallel_nodes"] = stats.skipped.parallel_nodes;
        j["skipped"] = sk;
        std::cout << j.dump() << "\n";
    } else {
        std::printf("scene      %s (%s)\n", scene.name.c_str(), scene.format.c_str());
        std::printf("triangles  %zu\n", view.triangle_count());
        std::printf("scheduler  %s, threads %u (used %u)\n", sched->name, threads, stats.threads_used);
        std::printf("nodes      %u\nleaves     %u\ndepth      %u\n", ts.nodes, ts.leaves, ts.depth);
        std::printf("sah        %.4f\n", sah);
        std::printf("build      %.3f ms (median of %u)\n", ms, a.repeat);
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

int run_info(const std::string& spec) {
    Scene scene = spec.empty() ? default_scene() : load_scene(spec);
    const TriangleMesh& m = scene.mesh;
    Box b;
    for (const Vec3& v : m.vertices) b.extend(v);
    size_t degenerate = 0;
    for (size_t t = 0; t < m.triangle_count(); ++t) {
        const Vec3 e1 = m.vertex(t, 1) - m.vertex(t, 0), e2 = m.vertex(t, 2) - m.vertex(t, 0);
        const double cx = double(e1.y) * e2.z - double(e1.z) * e2.y;
        const double cy = double(e1.z) * e2.x - double(e1.x) * e2.z;
        const double cz = double(e1.x) * e2.y - double(e1.y) * e2.x;
        degenerate += (cx == 0.0 && cy == 0.0 && cz == 0.0);
    }
    std::printf("scene      %s\nformat     %s\n", scene.name.c_str(), scene.format.c_str());
    std::printf("triangles  %zu\nvertices   %zu\n", m.triangle_count(), m.vertices.size());
    std::printf("bounds     (%g, %g, %g) - (%g, %g, %g)\n", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
    std::printf("zero-area  %zu\nnon-finite 0 (loading rejects them)\n", degenerate);
    return kOk;
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"canopy: parallel binned-SAH BVH builder"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "canopy 0.1.0");

    BuildArgs b;
    CLI::App* build = app.add_subcommand("build", "Build a BVH over a scene, validate it and print statistics");
    build->add_option("scene", b.scene, "Mesh file or gen:NAME:COUNT[:SEED] (default: gen:sphere:100000)");
    build->add_option("--scheduler", b.scheduler, "Scheduler: " + scheduler_names())->capture_default_str();
    build->add_option("--threads", b.threads, "Thread upper bound (0 = all hardware threads)")->capture_default_str();
    build->add_option("--bins", b.bins, "Bins per axis (2-256)")->capture_default_str();
    build->add_option("--leaf", b.leaf, "Largest leaf (1-255)")->capture_default_str();
    build->add_option("--repeat", b.repeat, "Builds to time; build_ms is their median")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100000u));
    build->add_flag("--json", b.json, "One JSON object on stdout");
    build->add_option("--save", b.save, "Write the BVH to FILE (canopy binary format)");

    std::string info_scene;
    CLI::App* info = app.add_subcommand("info", "Describe a scene: counts, bounds, degenerate triangles");
    info->add_option("scene", info_scene, "Mesh file or gen:NAME:COUNT[:SEED]");

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        std::cerr << "Run 'canopy --help' or 'canopy VERB --help'.\n";
        return kUsage;
    }
    try {
        if (*build) return run_build(b);
        if (*info) return run_info(info_scene);
    } catch (const canopy::OptionError& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        return kUsage;
    } catch (const canopy::Error& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        return kInput;
    } catch (const std::bad_alloc&) {
        std::cerr << "canopy: out of memory\n";
        return kInput;
    }
    return kUsage;
}
