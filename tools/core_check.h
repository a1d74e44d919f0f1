// canopy bench's check of the machine's cores: how long one small reference
// build takes pinned to each CPU the process may use, once per round, and
// on which CPU the calling thread ran that round's 1-thread builds.
//
// Why: on a shared virtual machine the vCPUs do not always run at the same
// speed (a host core's other hardware thread busy with another guest's
// work, say). On this project's 2-vCPU machine, 2026-12-06, the dragon's
// sequential build pinned to one vCPU took 22.6 to 23.2 ms and to the
// other 28.9 to 30.2 for minutes at a time, then both 22.9 to 24.0. A
// build on both, which waits for its slower thread, can then be at most
// 1 + 22.6 / 29.5 = 1.77 times as fast as a 1-thread build on the faster
// vCPU, or 1 + 29.5 / 22.6 = 2.31 times one on the slower, whatever the
// scheduler: the speedup a run shows depends on where its 1-thread builds
// ran. The check gives that bound (the ideal speedup) per round, so that a
// speedup can be read against it.
#pragma once

#include "core/mesh.h"
#include "core/options.h"

#include <cstdint>
#include <string>
#include <vector>

namespace canopy::cli {

class CoreCheck {
public:
    // The CPUs this process may run on (its affinity mask); none where
    // threads cannot be pinned (not Linux), which turns the check off.
    CoreCheck();
    bool available() const { return !cpus_.empty(); }
    size_t cpus() const { return cpus_.size(); }

    // Starts a round: times the reference build on each CPU (a thread
    // pinned to it, the median of a few builds).
    void probe();
    // Notes the CPU the calling thread is on now (after a 1-thread build
    // of this round).
    void note_calling_cpu();

    // Per round: the ideal speedup of a build on every CPU over a 1-thread
    // build on the CPU where most of the round's 1-thread builds ended,
    // the sum over the CPUs of (time there / time on each CPU); 0 where
    // unknown (no probe, or no 1-thread build noted).
    std::vector<double> ideal_speedups() const;
    // Lines for the report below a scene's table ("" when not available).
    std::string report() const;
    // Forgets the rounds (a new scene).
    void clear();

    // The reference: a sequential build of this generated scene.
    static constexpr const char* kReference = "gen:sphere:30000";

private:
    struct Round {
        std::vector<double> ms;        // the reference's time on each CPU (0: not timed)
        std::vector<uint32_t> calling; // 1-thread builds that ended on each CPU
    };
    std::vector<int> cpus_;
    TriangleMesh reference_;
    BuildOptions options_;
    std::vector<Round> rounds_;
};

}  // namespace canopy::cli
