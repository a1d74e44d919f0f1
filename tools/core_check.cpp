#include "core_check.h"

#include "cli.h"
#include "core/scene.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
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

std::string fmt(const char* f, double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, f, v);
    return buf;
}

}  // namespace

CoreCheck::CoreCheck() {
#if CANOPY_CAN_PIN
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof set, &set) != 0) return;
    for (int c = 0; c < CPU_SETSIZE; ++c)
        if (CPU_ISSET(c, &set)) cpus_.push_back(c);
    reference_ = load_scene(kReference).mesh;
    clear();
#endif
}

void CoreCheck::clear() {
    ms_.assign(cpus_.size(), {});
    calling_.assign(cpus_.size(), 0);
    calling_elsewhere_ = 0;
}

void CoreCheck::probe() {
#if CANOPY_CAN_PIN
    const SchedulerEntry& seq = *find_scheduler("sequential");
    const TriangleView view = reference_.view();
    for (size_t i = 0; i < cpus_.size(); ++i) {
        double ms = -1.0;
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
                if (tree.nodes.empty()) return;
                t.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
            }
            ms = median(std::move(t));
        }).join();
        if (ms >= 0.0) ms_[i].push_back(ms);
    }
#endif
}

void CoreCheck::note_calling_cpu() {
#if CANOPY_CAN_PIN
    const int c = sched_getcpu();
    const auto it = std::find(cpus_.begin(), cpus_.end(), c);
    if (it == cpus_.end())
        ++calling_elsewhere_;
    else
        ++calling_[size_t(it - cpus_.begin())];
#endif
}

std::string CoreCheck::report() const {
    if (!available()) return "";
    // The rounds every CPU was timed in (pinning can fail for one).
    size_t rounds = ms_.empty() ? 0 : ms_[0].size();
    for (const auto& v : ms_) rounds = std::min(rounds, v.size());
    if (rounds == 0) return "";
    std::string s = std::string("cores: the reference build (sequential, ") + kReference +
                    ") on a thread pinned to each CPU, median of " + std::to_string(rounds) + " rounds:";
    std::vector<double> spread;  // per round: slowest CPU / fastest
    for (size_t r = 0; r < rounds; ++r) {
        double lo = ms_[0][r], hi = ms_[0][r];
        for (const auto& v : ms_) lo = std::min(lo, v[r]), hi = std::max(hi, v[r]);
        if (lo > 0.0) spread.push_back(hi / lo);
    }
    for (size_t i = 0; i < cpus_.size(); ++i)
        s += (i ? ", cpu" : " cpu") + std::to_string(cpus_[i]) + " " +
             fmt("%.2f ms", median(std::vector<double>(ms_[i].begin(), ms_[i].begin() + long(rounds))));
    if (cpus_.size() > 1 && !spread.empty()) {
        const auto [mn, mx] = std::minmax_element(spread.begin(), spread.end());
        s += "\n  slowest / fastest CPU per round: median " + fmt("%.2f", median(spread)) + ", range " +
             fmt("%.2f", *mn) + " to " + fmt("%.2f", *mx);
        if (cpus_.size() == 2 && *mx >= 1.1)
            s += "\n  unequal CPUs: in such a round a 2-thread build, which waits for its slower thread, is at most "
                 "1 + fastest / slowest times as fast as a 1-thread build on the faster CPU (" +
                 fmt("%.2fx", 1.0 + 1.0 / *mx) + " at this run's widest spread)";
    }
    uint32_t noted = calling_elsewhere_;
    for (uint32_t c : calling_) noted += c;
    if (noted) {
        s += "\n  1-thread builds ended on:";
        for (size_t i = 0; i < cpus_.size(); ++i)
            if (calling_[i]) s += " cpu" + std::to_string(cpus_[i]) + " " + std::to_string(calling_[i]);
        if (calling_elsewhere_) s += " other " + std::to_string(calling_elsewhere_);
    }
    return s;
}

}  // namespace canopy::cli
