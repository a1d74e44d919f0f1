// canopy bench: every scheduler compiled in, and Embree 3 when it is, on the
// same scenes and thread counts, alternated (every builder once per round,
// in a seeded shuffle); one table per scene.
#include "cli.h"
#include "core_check.h"
#include "core/bvh.h"
#include "core/build_state.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/validate.h"
#if CANOPY_HAVE_EMBREE
#include "embree_compare.h"
#endif


#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <numeric>
#include <random>
#include <thread>
#include <vector>

namespace canopy::cli {

namespace {

using Clock = std::chrono::steady_clock;

struct BenchArgs {
    std::vector<std::string> scenes;
    std::string threads;
    uint32_t repeat = 7;
    uint32_t gap_ms = 50;
    uint32_t prefault = 192;  // bytes per triangle touched and freed before each timed build
    std::optional<uint64_t> shuffle;  // seed: every scene's triangles in a random order
    std::string csv;
    uint32_t bins = BuildOptions{}.bins;
    uint32_t leaf = BuildOptions{}.max_leaf;
    uint32_t rotate_min = BuildOptions{}.rotate_min;
    bool core_check = true;
};

enum class Kind { kCanopy, kEmbreeScene, kEmbreeBuilder };

struct Builder {
    std::string name;
    Kind kind;
    const SchedulerEntry* sched = nullptr;  // kCanopy
};

// One builder at one thread count.
struct Measure {
    std::vector<double> ms;
    std::optional<double> sah;
    double median = 0.0;
    double min = 0.0;
};

std::string default_threads() {
    const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
    return hw > 1 ? "1," + std::to_string(hw) : "1";
}

std::string csv_field(const std::string& s) {
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
}

// The median over rounds of a[r] / b[r]: both measured in the same round,
// seconds apart, so a slow spell of the machine (they last minutes on
// shared virtual machines) scales both alike and mostly cancels, where it
// moves one median more than the other.
std::optional<double> median_of_ratios(const std::vector<double>& a, const std::vector<double>& b) {
    std::vector<double> r;
    for (size_t i = 0; i < std::min(a.size(), b.size()); ++i)
        if (b[i] > 0.0) r.push_back(a[i] / b[i]);
    if (r.empty()) return std::nullopt;
    return median(std::move(r));
}

// Touches `bytes` of fresh memory (on huge pages where granted) and frees it.
// Run right before a timed build, it leaves that much memory in the
// system's free pool as pages the guest has just used: on virtual machines
// that hand idle free memory back to the host (virtio-balloon free page
// reporting, about 2 s after it is freed here), a first touch of memory
// handed back costs about ten times a touch of memory the guest holds, so
// without this a build's time depended on how long ago the machine last
// used the memory it gets (README, "Performance"). The build still
// allocates, faults and zeroes all its memory afresh.
void warm_page_pool(size_t bytes) {
    if (bytes == 0) return;
    RawArray<char> p;  // fresh, not zero-filled, advised for huge pages
    p.allocate(bytes);
    volatile char* v = p.get();
    for (size_t i = 0; i < bytes; i += 4096) v[i] = 1;
}

class Bench {
public:
    explicit Bench(const BenchArgs& a) : a_(a) {
        for (const auto& e : schedulers()) builders_.push_back({e.name, Kind::kCanopy, &e});
#if CANOPY_HAVE_EMBREE
        builders_.push_back({"embree_scene", Kind::kEmbreeScene});
        if (a.leaf <= embree::kMaxBuilderLeaf)
            builders_.push_back({"embree_builder", Kind::kEmbreeBuilder});
        else
            std::cerr << "canopy bench: --leaf " << a.leaf << " exceeds what rtcBuildBVH allows ("
                      << embree::kMaxBuilderLeaf << "): embree_builder left out\n";
#endif
        const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
        for (uint32_t t : parse_list(a.threads, "--threads")) threads_.push_back(t ? t : hw);
        std::sort(threads_.begin(), threads_.end());
        threads_.erase(std::unique(threads_.begin(), threads_.end()), threads_.end());
        options_.bins = a.bins;
        options_.max_leaf = a.leaf;
        options_.rotate_min = a.rotate_min;
        options_.check();
        if (a.core_check) cores_.emplace();
    }

    int run() {
        std::ofstream csv;
        if (!a_.csv.empty()) {
            csv.open(a_.csv);
            if (!csv) throw Error("cannot write '" + a_.csv + "'");
            csv << "scene,triangles,threads,builder,median_ms,min_ms,sah,ratio_vs_embree_scene,speedup_vs_T1,"
                   "ratio_vs_embree_scene_per_round,speedup_vs_T1_per_round,speedup_over_ideal_per_round\n";
        }
        std::vector<std::string> specs = a_.scenes;
        if (specs.empty()) specs.push_back("");
        for (const std::string& spec : specs) {
            int status = kOk;
            try {
                status = run_scene(spec, csv);
            } catch (...) {
                progress_.clear();  // main() prints the error on a clean line
                throw;
            }
            if (status != kOk) return status;
        }
        if (csv.is_open()) {
            csv.flush();
            if (!csv) throw Error("cannot write '" + a_.csv + "'");
        }
        return kOk;
    }

private:
    void print_header() const {
        std::printf("canopy bench: build times in ms, medians of %u alternated runs (each round: the thread counts in a "
                    "seeded shuffle, the builders in a seeded shuffle within each; after one warm-up round, %u bytes "
                    "per triangle touched and freed, then %u ms idle, before each run); bins %u, leaf %u, rotate_min %u\n",
                    a_.repeat, a_.prefault, a_.gap_ms, a_.bins, a_.leaf, a_.rotate_min);
#if CANOPY_HAVE_EMBREE
        std::printf("  vs_embree: median / median of Embree %s's scene build (rtcCommitScene) at the same "
                    "threads (< 1: faster than Embree)\n",
                    embree::version().c_str());
        std::printf("  embree_builder: Embree's rtcBuildBVH, binary, same leaf cap, triangle boxes given "
                    "(not timed); embree_scene has its own wide BVH: no SAH\n");
#else
        std::printf("  Embree not compiled in: no Embree rows, no vs_embree ratios\n");
#endif
        std::printf("  speedup: median at %u thread(s) / median at this thread count, per builder; "
                    "SAH: canopy's cost (half areas, costs 1)\n",
                    threads_.front());
        std::printf("  per_round: the same ratios taken within each round (seconds apart), median over the rounds: "
                    "less moved by the machine's slow spells than the ratio of medians\n");
        std::fflush(stdout);
    }

    // The warm-up build of a builder (untimed): validates canopy's trees and
    // keeps them to compare the timed ones with; gives the SAH.
    void warm_up(const Builder& b, Measure& m, const TriangleView& view, Bvh& reference) {
        switch (b.kind) {
            case Kind::kCanopy: {
                reference = b.sched->build_triangles(view, options_, nullptr);
                const ValidationReport report = validate(reference, view, options_);
                if (!report.ok())
                    throw Invalid("scheduler " + b.name + " at " + std::to_string(options_.threads) +
                                  " threads built an invalid tree: " + report.summary());
                m.sah = sah_cost(reference);
                break;
            }
#if CANOPY_HAVE_EMBREE
            case Kind::kEmbreeScene: embree::scene_build_ms(*device_, *input_); break;
            case Kind::kEmbreeBuilder: {
                Bvh tree;
                embree::builder_ms(*device_, *input_, options_.max_leaf, options_.max_depth, &tree);
                const ValidationReport report = validate(tree, view, options_);
                if (!report.ok())
                    throw Invalid("Embree's rtcBuildBVH tree (converted) is not valid: " + report.summary());
                m.sah = sah_cost(tree);
                break;
            }
#else
            default: break;
#endif
        }
    }

    double timed(const Builder& b, const TriangleView& view, const Bvh& reference) {
        switch (b.kind) {
            case Kind::kCanopy: {
                Bvh fresh;  // freed after the timing
                const auto t0 = Clock::now();
                fresh = b.sched->build_triangles(view, options_, nullptr);
                const auto t1 = Clock::now();
                if (!(fresh == reference))
                    throw Invalid("scheduler " + b.name + " at " + std::to_string(options_.threads) +
                                  " threads: repeated builds differ");
                return std::chrono::duration<double, std::milli>(t1 - t0).count();
            }
#if CANOPY_HAVE_EMBREE
            case Kind::kEmbreeScene: return embree::scene_build_ms(*device_, *input_);
            case Kind::kEmbreeBuilder:
                return embree::builder_ms(*device_, *input_, options_.max_leaf, options_.max_depth, nullptr);
#endif
            default: return 0.0;
        }
    }

    struct Invalid : Error {
        explicit Invalid(const std::string& w) : Error(w) {}
    };

    // The thread count of the next builds: canopy's option, and an Embree
    // device made for it (one device at a time: its thread limit is
    // process-wide). Making one is not timed, and is followed by a longer
    // idle (kDeviceSettleMs) so that the threads it starts are asleep before
    // the next timed build.
    [[maybe_unused]] static constexpr int kDeviceSettleMs = 250;  // used with Embree only
    void use_threads(uint32_t T) {
        options_.threads = T;
#if CANOPY_HAVE_EMBREE
        if (device_ && device_threads_ == T) return;
        device_.reset();
        device_ = std::make_unique<embree::Device>(T);
        device_threads_ = T;
        std::this_thread::sleep_for(std::chrono::milliseconds(kDeviceSettleMs));
#endif
    }

    int run_scene(const std::string& spec, std::ofstream& csv) {
        progress_.show("loading " + (spec.empty() ? std::string("the default scene") : spec));
        Scene scene = spec.empty() ? default_scene() : load_scene(spec);
        if (a_.shuffle) {
            shuffle_triangles(scene.mesh, *a_.shuffle);
            scene.name += " shuffled:" + std::to_string(*a_.shuffle);
        }
        const TriangleView view = scene.mesh.view();
        const size_t n = view.triangle_count();
        if (n == 0) {
            progress_.clear();
            if (!header_printed_) print_header();
            header_printed_ = true;
            std::printf("\nscene %s: no triangles, skipped\n", scene.name.c_str());
            return kOk;
        }
#if CANOPY_HAVE_EMBREE
        input_ = std::make_unique<embree::Input>(view);
#endif
        const size_t nb = builders_.size();
        const size_t prefault_bytes = n * size_t(a_.prefault);
        // results[t][b]
        std::vector<std::vector<Measure>> results(threads_.size(), std::vector<Measure>(nb));
        Bvh canonical;  // the first canopy tree of this scene
        try {
            for (size_t ti = 0; ti < threads_.size(); ++ti) {
                const uint32_t T = threads_[ti];
                use_threads(T);
                for (size_t b = 0; b < nb; ++b) {
                    progress_.show(scene.name + ", " + std::to_string(T) + " threads, warm-up " + builders_[b].name);
                    Bvh tree;
                    warm_up(builders_[b], results[ti][b], view, tree);
                    // Every scheduler at every thread count builds the same tree.
                    if (builders_[b].kind != Kind::kCanopy) continue;
                    if (canonical.nodes.empty() && canonical.permutation.empty())
                        canonical = std::move(tree);
                    else if (!(tree == canonical))
                        throw Invalid("scheduler " + builders_[b].name + " at " + std::to_string(T) +
                                      " threads built a different tree than the first canopy build");
                }
            }
            if (cores_) cores_->clear();
            for (uint32_t r = 0; r < a_.repeat; ++r) {
                progress_.show(scene.name + ", round " + std::to_string(r + 1) + "/" + std::to_string(a_.repeat));
                // Each CPU's speed this round (see core_check.h).
                if (cores_) cores_->probe();
                // Every thread count once per round, and within it every
                // builder once, each in a seeded shuffle drawn afresh each
                // round: no builder always follows the same one (a
                // round-robin that only moved its start kept the cyclic
                // order, and `sequential`, always right after Embree's
                // builder, measured up to 15% slower than the same code as
                // `omp_tasks` at 1 thread), and a slow spell of the machine
                // (they last minutes here) falls on every thread count
                // alike instead of on the whole of one, which made the
                // speedups swing.
                std::vector<size_t> thread_order(threads_.size());
                std::iota(thread_order.begin(), thread_order.end(), size_t(0));
                std::mt19937 trng(0x85EBCA6Bu + r);
                std::shuffle(thread_order.begin(), thread_order.end(), trng);
                for (const size_t ti : thread_order) {
                    use_threads(threads_[ti]);
                    std::vector<size_t> order(nb);
                    std::iota(order.begin(), order.end(), size_t(0));
                    std::mt19937 rng(0x9E3779B9u + 131u * r + uint32_t(ti));
                    std::shuffle(order.begin(), order.end(), rng);
                    for (const size_t b : order) {
                        // Memory the machine holds for the build (see
                        // warm_page_pool()), then idle, so that threads the
                        // previous builder left spinning (libgomp's team
                        // after a parallel region, TBB's workers) are asleep
                        // and do not take this builder's cores.
                        warm_page_pool(prefault_bytes);
                        if (a_.gap_ms) std::this_thread::sleep_for(std::chrono::milliseconds(a_.gap_ms));
                        // Every canopy tree equals `canonical` (checked in
                        // the warm-up), so one tree serves every check.
                        results[ti][b].ms.push_back(timed(builders_[b], view, canonical));
                        if (cores_ && threads_[ti] == 1 && builders_[b].kind == Kind::kCanopy)
                            cores_->note_calling_cpu();
                    }
                }
            }
            for (auto& row : results)
                for (Measure& m : row) {
                    m.median = median(m.ms);
                    m.min = *std::min_element(m.ms.begin(), m.ms.end());
                }
        } catch (const Invalid& e) {
            progress_.clear();
            std::cerr << "canopy bench: " << scene.name << ": " << e.what() << "\n";
            return kInvalid;
        }
#if CANOPY_HAVE_EMBREE
        device_.reset();
        input_.reset();
#endif
        progress_.clear();
        print_scene(scene.name, n, results, csv);
        return kOk;
    }

    void print_scene(const std::string& name, size_t n, const std::vector<std::vector<Measure>>& results,
                     std::ofstream& csv) {
        if (!header_printed_) print_header();
        header_printed_ = true;
        std::optional<size_t> embree_scene;
        for (size_t b = 0; b < builders_.size(); ++b)
            if (builders_[b].kind == Kind::kEmbreeScene) embree_scene = b;
        size_t width = 7;
        for (const Builder& b : builders_) width = std::max(width, b.name.size());

        // The core check's ideal speedup of each round, read once for the scene.
        const std::vector<double> ideal = ideal_threads_index() ? cores_->ideal_speedups() : std::vector<double>{};
        std::printf("\nscene %s: %zu triangles\n", name.c_str(), n);
        std::printf("%7s  %-*s %10s %10s %9s %10s %9s %8s %9s\n", "threads", int(width), "builder", "median_ms",
                    "min_ms", "SAH", "vs_embree", "per_round", "speedup", "per_round");
        for (size_t ti = 0; ti < threads_.size(); ++ti) {
            for (size_t b = 0; b < builders_.size(); ++b) {
                const Measure& m = results[ti][b];
                std::optional<double> ratio, speedup, ratio_rounds, speedup_rounds;
                if (embree_scene && results[ti][*embree_scene].median > 0.0) {
                    ratio = m.median / results[ti][*embree_scene].median;
                    ratio_rounds = median_of_ratios(m.ms, results[ti][*embree_scene].ms);
                }
                if (m.median > 0.0) {
                    speedup = results[0][b].median / m.median;
                    speedup_rounds = median_of_ratios(results[0][b].ms, m.ms);
                }
                const auto x = [](const std::optional<double>& v) { return v ? fmt("%.2fx", *v) : std::string("-"); };
                const auto c = [](const std::optional<double>& v) { return v ? fmt("%.4f", *v) : std::string(); };
                std::printf("%7u  %-*s %10.3f %10.3f %9s %10s %9s %8s %9s\n", threads_[ti], int(width),
                            builders_[b].name.c_str(), m.median, m.min,
                            m.sah ? fmt("%.4f", *m.sah).c_str() : "-", x(ratio).c_str(), x(ratio_rounds).c_str(),
                            x(speedup).c_str(), x(speedup_rounds).c_str());
                if (csv.is_open()) {
                    csv << csv_field(name) << ',' << n << ',' << threads_[ti] << ',' << builders_[b].name << ','
                        << fmt("%.4f", m.median) << ',' << fmt("%.4f", m.min) << ','
                        << (m.sah ? fmt("%.6f", *m.sah) : "") << ',' << c(ratio) << ',' << c(speedup) << ','
                        << c(ratio_rounds) << ',' << c(speedup_rounds) << ',' << c(over_ideal(results, ti, b, ideal))
                        << '\n';
                }
            }
        }
        if (cores_) print_scaling(results, ideal);
        std::fflush(stdout);
    }

    // The thread count whose speedups the core check's ideal applies to:
    // every CPU the process may use, with 1 thread measured first.
    std::optional<size_t> ideal_threads_index() const {
        if (!cores_ || cores_->cpus() < 2 || threads_.front() != 1) return std::nullopt;
        const auto all = std::find(threads_.begin(), threads_.end(), uint32_t(cores_->cpus()));
        if (all == threads_.end()) return std::nullopt;
        return size_t(all - threads_.begin());
    }

    // Builder b's speedup at thread count ti over each round's ideal speedup
    // (ideal: the core check's, one per round), the median over the rounds
    // (rounds of unknown ideal, 0, are skipped); none unless ti is
    // ideal_threads_index().
    std::optional<double> over_ideal(const std::vector<std::vector<Measure>>& results, size_t ti, size_t b,
                                     const std::vector<double>& ideal) const {
        if (ideal_threads_index() != ti) return std::nullopt;
        // one / (many * ideal) per round
        std::vector<double> scaled = results[ti][b].ms;
        for (size_t k = 0; k < scaled.size(); ++k) scaled[k] *= k < ideal.size() ? ideal[k] : 0.0;
        return median_of_ratios(results[0][b].ms, scaled);
    }

    // The core check's lines (core_check.h), and each builder's speedup on
    // every CPU over the round's ideal speedup, the median over the rounds.
    void print_scaling(const std::vector<std::vector<Measure>>& results, const std::vector<double>& ideal) const {
        const std::string report = cores_->report();
        if (report.empty()) return;
        std::printf("%s\n", report.c_str());
        const std::optional<size_t> ti = ideal_threads_index();
        if (!ti) return;
        std::string line;
        for (size_t b = 0; b < builders_.size(); ++b)
            if (const auto r = over_ideal(results, *ti, b, ideal))
                line += (line.empty() ? " " : ", ") + builders_[b].name + " " + fmt("%.2f", *r);
        if (!line.empty())
            std::printf("  speedup at %u threads / ideal speedup, median of the rounds' ratios:%s\n", threads_[*ti],
                        line.c_str());
    }

    const BenchArgs& a_;
    std::vector<Builder> builders_;
    std::vector<uint32_t> threads_;
    BuildOptions options_;
    Progress progress_{"bench"};
    bool header_printed_ = false;
    std::optional<CoreCheck> cores_;
#if CANOPY_HAVE_EMBREE
    std::unique_ptr<embree::Device> device_;
    uint32_t device_threads_ = 0;
    std::unique_ptr<embree::Input> input_;
#endif
};

}  // namespace

Runner add_bench(CLI::App& app) {
    auto a = std::make_shared<BenchArgs>();
    a->threads = default_threads();
    CLI::App* bench = app.add_subcommand(
        "bench", "Compare the schedulers (and Embree 3, when compiled in) on scenes and thread counts");
    bench->add_option("scene", a->scenes, "Mesh files or gen:NAME:COUNT[:SEED] (default: gen:sphere:100000)");
    bench->add_option("--threads", a->threads, "Thread counts, comma-separated (0 = all hardware threads)")
        ->capture_default_str();
    bench->add_option("--repeat", a->repeat, "Timed rounds; the tables show medians")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100000u));
    bench->add_option("--gap", a->gap_ms,
                      "Idle milliseconds before each timed build, so that the previous builder's spinning "
                      "threads are asleep")
        ->capture_default_str()
        ->check(CLI::Range(0u, 10000u));
    bench->add_option("--prefault", a->prefault,
                      "Bytes per triangle of memory touched and freed before each timed build, so that builds get "
                      "memory the machine holds rather than memory a virtual machine handed back to its host "
                      "(0: off)")
        ->capture_default_str()
        ->check(CLI::Range(0u, 1024u));
    bench->add_option("--shuffle", a->shuffle,
                      "Put every scene's triangles in a random order (this seed) first: the same triangles in no "
                      "particular order, for seeing how each builder's time depends on the input order");
    bench->add_option("--csv", a->csv,
                      "Also write one CSV row per (scene, threads, builder) to FILE "
                      "(speedup_vs_T1: against the smallest thread count)");
    bench->add_flag("!--no-core-check", a->core_check,
                    "Do not time the reference build on each CPU once per round (the 'cores:' lines below each "
                    "table, which show when the CPUs run at unequal speeds)");
    bench->add_option("--bins", a->bins, "Bins per axis (2-256)")->capture_default_str();
    bench->add_option("--leaf", a->leaf, "Largest leaf (1-255)")->capture_default_str();
    bench->add_option("--rotate-min", a->rotate_min,
                      "Nodes of at least this many primitives may take a tree rotation (0 = none, else >= 256)")
        ->capture_default_str();
    return [a, bench]() {
        if (!*bench) return -1;
        Bench b(*a);
        return b.run();
    };
}

}  // namespace canopy::cli
