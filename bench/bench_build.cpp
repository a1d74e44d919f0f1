// canopy: Google Benchmark of the build, every scheduler compiled in x
// scenes x thread counts {1, 2} x bins {8, 16, 32, 64}: run time against
// error, as `canopy sweep` prints it.
//
// Scenes: gen:sphere, gen:random and gen:stadium at 100,000 triangles, and
// dragon_vrip_res2.obj from the scenes directory when it is there (the
// environment variable CANOPY_SCENES_DIR, else the directory compiled in).
// Each benchmark reports the build time (real time: the builds are
// multi-threaded), the counter Mtris/s (a rate), the SAH of the tree and
// error_% (its SAH excess over the exact full-sweep SAH tree of the scene,
// core/sweep_sah.h, built once per scene outside all timing).
// The tree is built and validated once before the timed loop; the timed
// builds are build_ms as `canopy build` defines it (freeing the tree is not
// timed).
#include "core/bvh.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/sweep_sah.h"
#include "core/validate.h"
#include "schedulers/registry.h"

#include <benchmark/benchmark.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#ifndef CANOPY_SCENES_DIR
#define CANOPY_SCENES_DIR ""
#endif

namespace {

constexpr const char* kGenerated[] = {"gen:sphere:100000", "gen:random:100000", "gen:stadium:100000"};
constexpr const char* kFileScenes[] = {"dragon_vrip_res2.obj"};
constexpr uint32_t kThreads[] = {1, 2};
constexpr uint32_t kBins[] = {8, 16, 32, 64};

struct SceneSpec {
    std::string label;  // in the benchmark name
    std::string spec;   // for canopy::load_scene
};

std::vector<SceneSpec> scene_specs() {
    std::vector<SceneSpec> out;
    for (const char* g : kGenerated) out.push_back({g, g});
    const char* env = std::getenv("CANOPY_SCENES_DIR");
    const std::filesystem::path dir = env && *env ? env : CANOPY_SCENES_DIR;
    if (!dir.empty()) {
        for (const char* f : kFileScenes) {
            const std::filesystem::path p = dir / f;
            std::error_code ec;
            if (std::filesystem::is_regular_file(p, ec))
                out.push_back({std::filesystem::path(f).stem().string(), p.string()});
        }
    }
    return out;
}

// Scenes load on first use (so a --benchmark_filter skips the others) and
// stay loaded; benchmarks run one after another on the main thread.
const canopy::Scene& scene(const std::string& spec) {
    static std::map<std::string, std::unique_ptr<canopy::Scene>> cache;
    auto& slot = cache[spec];
    if (!slot) slot = std::make_unique<canopy::Scene>(canopy::load_scene(spec));
    return *slot;
}

// The exact sweep tree's SAH for a scene (default options but the bins),
// computed once.
double exact_sah(const std::string& spec, const canopy::TriangleView& view) {
    static std::map<std::string, double> cache;
    const auto it = cache.find(spec);
    if (it != cache.end()) return it->second;
    return cache[spec] = canopy::sah_cost(canopy::build_sweep_sah(view, canopy::BuildOptions{}));
}

void bm_build(benchmark::State& state, const canopy::SchedulerEntry* sched, const std::string& spec,
              uint32_t threads, uint32_t bins) {
    const canopy::Scene* sc = nullptr;
    try {
        sc = &scene(spec);
    } catch (const std::exception& e) {
        state.SkipWithError(e.what());
        return;
    }
    const canopy::TriangleView view = sc->mesh.view();
    canopy::BuildOptions options;
    options.threads = threads;
    options.bins = bins;

    // Once, untimed: the tree must be valid; its SAH is reported.
    const canopy::Bvh reference = sched->build_triangles(view, options, nullptr);
    const canopy::ValidationReport report = canopy::validate(reference, view, options);
    if (!report.ok()) {
        const std::string msg = "invalid tree: " + report.summary(3);
        state.SkipWithError(msg.c_str());
        return;
    }

    for (auto _ : state) {
        canopy::Bvh bvh = sched->build_triangles(view, options, nullptr);
        benchmark::DoNotOptimize(bvh.nodes.data());
        state.PauseTiming();
        bvh = canopy::Bvh{};  // freed outside the timing
        state.ResumeTiming();
    }

    state.counters["Mtris/s"] = benchmark::Counter(double(view.triangle_count()) * 1e-6,
                                                   benchmark::Counter::kIsIterationInvariantRate);
    const double sah = canopy::sah_cost(reference);
    state.counters["SAH"] = sah;
    state.counters["error_%"] = 100.0 * (sah / exact_sah(spec, view) - 1.0);
}

}  // namespace

int main(int argc, char** argv) {
    benchmark::Initialize(&argc, argv);
    if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
    for (const SceneSpec& s : scene_specs())
        for (uint32_t t : kThreads)
            for (uint32_t b : kBins)
                for (const canopy::SchedulerEntry& e : canopy::schedulers()) {
                    const std::string name = std::string("build/") + e.name + "/" + s.label + "/threads:" +
                                             std::to_string(t) + "/bins:" + std::to_string(b);
                    benchmark::RegisterBenchmark(name.c_str(), bm_build, &e, s.spec, t, b)
                        ->Unit(benchmark::kMillisecond)
                        ->UseRealTime();
                }
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    return 0;
}
