// cross_core: how much dearer it is here for one core to work on memory
// another core wrote last than on memory it wrote itself. A 2-thread build
// does that at the top of the tree (the team's root reads records both
// threads prepared, the root's children read records both threads
// partitioned, the placement copies nodes both threads built), so its
// speedup depends on it.
//
//   ./build/bench/cross_core [MIB] [BATCHES] [PAUSE_MS]   (default 4 12 2000)
//
// Two threads take turns on one buffer of MIB MiB: the first reads and
// writes every cache line of it twice (the second pass is timed: the lines
// are its own), then the second thread does the same once (timed: every
// line comes from the first core). Each batch of 200 turns prints the two
// medians and their ratio, then the program sleeps PAUSE_MS.
//
// On this project's "AMD EPYC" virtual machine (2 vCPUs, 2026-12-06) the
// ratio was 1.21 to 1.22 for a while and then 3.32 to 3.40 (4 MiB: 41 us
// against 116, the local pass 34 us throughout), in one run: the host moves
// the two vCPUs between a placement where they share a cache and one where
// they do not, for minutes at a time. canopy's 2-thread builds were
// slower in its dear state on 2026-12-06, but over 40 probes of the dragon
// on 2026-12-07 their fraction of the ideal speedup did not follow it
// (correlation 0.07; docs/performance-log.md, "2026-12-07, early").
#include "tools/cli.h"  // canopy::cli::median

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;

double micros(Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::micro>(b - a).count();
}

// Reads and writes one float in every 64-byte line; the sum keeps the loop
// from being optimised away and makes each line's write depend on its read.
float touch_lines(std::vector<float>& buf) {
    float s = 0.0f;
    for (size_t i = 0; i < buf.size(); i += 16) {
        s += buf[i];
        buf[i] = s * 0.5f;
    }
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    const long mib = argc > 1 ? std::atol(argv[1]) : 4;
    const long batches = argc > 2 ? std::atol(argv[2]) : 12;
    const long pause_ms = argc > 3 ? std::atol(argv[3]) : 2000;
    if (mib < 1 || mib > 4096 || batches < 1 || pause_ms < 0) {
        std::fprintf(stderr, "usage: cross_core [MIB 1-4096] [BATCHES >= 1] [PAUSE_MS >= 0]\n");
        return 2;
    }
    constexpr int kTurns = 200;
    std::vector<float> buf(size_t(mib) << 18, 1.0f);
    std::atomic<int> turn{0};  // 0: first thread's, 1: second thread's
    std::atomic<bool> stop{false};
    std::vector<double> remote;
    remote.reserve(kTurns);
    volatile float sink = 0.0f;

    std::thread second([&] {
        while (true) {
            while (turn.load(std::memory_order_acquire) != 1)
                if (stop.load(std::memory_order_relaxed)) return;
            const auto t0 = Clock::now();
            sink = touch_lines(buf);
            remote.push_back(micros(t0, Clock::now()));
            turn.store(0, std::memory_order_release);
        }
    });

    std::printf("%ld MiB, %d turns a batch\n", mib, kTurns);
    for (long b = 0; b < batches; ++b) {
        std::vector<double> local;
        local.reserve(kTurns);
        remote.clear();
        for (int k = 0; k < kTurns; ++k) {
            sink = touch_lines(buf);  // brings every line to this core
            const auto t0 = Clock::now();
            sink = touch_lines(buf);
            local.push_back(micros(t0, Clock::now()));
            turn.store(1, std::memory_order_release);
            while (turn.load(std::memory_order_acquire) != 0) {
            }
        }
        const double l = canopy::cli::median(local), r = canopy::cli::median(remote);
        std::printf("batch %ld: own lines %.0f us, lines the other core wrote %.0f us (%.2fx)\n", b, l, r, r / l);
        std::fflush(stdout);
        if (b + 1 < batches) std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms));
    }
    stop.store(true);
    second.join();
    return 0;
}
