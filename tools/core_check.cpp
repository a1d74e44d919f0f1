#include "core_check.h"

#include "cli.h"
#include "core/scene.h"

#include <algorithm>
#include <chrono>
#include <thread>

#if defined(__linux__)
#include <pthread.h>
#include <sched.h>
#define CANOPY_CAN_PIN 1
#else
#define CANOPY_CAN_PIN 0
#endif

namespace canopy::cli {

namespace {

// Builds run per CPU and round; their median is the round's time.
constexpr int kBuilds = 3;

}  // namespace

CoreCheck::CoreCheck() {
#if CANOPY_CAN_PIN
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof set, &set) != 0) return;
    for (int c = 0; c < CPU_SETSIZE; ++c)
        if (CPU_ISSET(c, &set)) cpus_.push_back(c);
    reference_ = load_scene(kReference).mesh;
#endif
}

void CoreCheck::clear() { rounds_.clear(); }

void CoreCheck::probe() {
    Round& round = rounds_.emplace_back(Round{std::vector<double>(cpus_.size(), 0.0),
                                              std::vector<uint32_t>(cpus_.size(), 0)});
#if CANOPY_CAN_PIN
    const SchedulerEntry& seq = *find_scheduler("sequential");
    const TriangleView view = reference_.view();
    for (size_t i = 0; i < cpus_.size(); ++i) {
        // A thread of its own, so that the calling thread (which runs the
        // 1-thread builds) is not moved by the pinning.
        std::thread([&] {
            cpu_set_t one;
            CPU_ZERO(&one);
            CPU_SET(cpus_[i], &one);
            if (pthread_setaffinity_np(pthread_self(), sizeof one, &one) != 0) return;
            std::vector<double> t;
            for (int b = 0; b < kBuilds; ++b) {
                const auto t0 = std::chrono::steady_clock::now();
                const Bvh tree = seq.build_triangles(view, options_);
                const auto t1 = std::chrono::steady_clock::now();
                t.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
            }
            round.ms[i] = median(std::move(t));
        }).join();
    }
#endif
}

void CoreCheck::note_calling_cpu() {
#if CANOPY_CAN_PIN
    if (rounds_.empty()) return;
    const auto it = std::find(cpus_.begin(), cpus_.end(), sched_getcpu());
    if (it != cpus_.end()) ++rounds_.back().calling[size_t(it - cpus_.begin())];
#endif
}

std::vector<double> CoreCheck::ideal_speedups() const {
    std::vector<double> ideal;
    for (const Round& r : rounds_) {
        const size_t home = size_t(std::max_element(r.calling.begin(), r.calling.end()) - r.calling.begin());
        const bool known = home < r.calling.size() && r.calling[home] > 0 &&
                           std::all_of(r.ms.begin(), r.ms.end(), [](double ms) { return ms > 0.0; });
        double sum = 0.0;
        if (known)
            for (double ms : r.ms) sum += r.ms[home] / ms;
        ideal.push_back(sum);
    }
    return ideal;
}

namespace {
// "median (lowest to highest)" of the positive values; "" if none.
std::string spread_text(std::vector<double> v) {
    v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return !(x > 0.0); }), v.end());
    if (v.empty()) return "";
    const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
    return fmt("%.2f", median(v)) + " (" + fmt("%.2f", *lo) + " to " + fmt("%.2f", *hi) + ")";
}
}  // namespace

std::string CoreCheck::report() const {
    if (!available() || rounds_.empty()) return "";
    std::string s = std::string("cores: the reference build (sequential, ") + kReference +
                    ") on a thread pinned to each CPU, medians of " + std::to_string(rounds_.size()) + " rounds:";
    std::vector<double> spread;  // per round: slowest CPU / fastest
    for (size_t i = 0; i < cpus_.size(); ++i) {
        std::vector<double> t;
        for (const Round& r : rounds_)
            if (r.ms[i] > 0.0) t.push_back(r.ms[i]);
        s += (i ? ", cpu" : " cpu") + std::to_string(cpus_[i]) + " " + (t.empty() ? "-" : fmt("%.2f ms", median(t)));
    }
    for (const Round& r : rounds_) {
        const auto [lo, hi] = std::minmax_element(r.ms.begin(), r.ms.end());
        if (*lo > 0.0) spread.push_back(*hi / *lo);
    }
    if (cpus_.size() > 1 && !spread.empty()) s += "; slowest / fastest per round: " + spread_text(spread);
    std::vector<uint32_t> calling(cpus_.size(), 0);
    for (const Round& r : rounds_)
        for (size_t i = 0; i < cpus_.size(); ++i) calling[i] += r.calling[i];
    std::string where;
    for (size_t i = 0; i < cpus_.size(); ++i)
        if (calling[i]) where += (where.empty() ? " cpu" : ", cpu") + std::to_string(cpus_[i]) + " " + std::to_string(calling[i]);
    if (!where.empty()) s += "\n  1-thread builds ended on:" + where;
    const std::string ideal = spread_text(ideal_speedups());
    if (cpus_.size() > 1 && !ideal.empty())
        s += "\n  ideal speedup of a build on all " + std::to_string(cpus_.size()) +
             " CPUs over a 1-thread build on the CPU where that round's ran (sum of its time / each CPU's), "
             "per round: " + ideal;
    return s;
}

}  // namespace canopy::cli
