// canopy bench's check of the machine's cores: how long one small reference
// build takes pinned to each CPU the process may use, once per round, and
// on which CPU the calling thread ran the 1-thread builds.
//
// Why: on a shared virtual machine the vCPUs do not always run at the same
// speed (a host core's other hardware thread busy with another guest's
// work, say). On this project's 2-vCPU machine, 2026-12-06, the dragon's
// sequential build pinned to one vCPU took 22.6 to 23.2 ms and to the
// other 28.9 to 30.2 for minutes at a time, then both 22.9 to 24.0; a
// 2-thread build, which waits for its slower thread, cannot then be more
// than 1 + 22.6 / 29.5 = 1.77 times as fast as a 1-thread build on the
// faster vCPU, whatever the scheduler. The check makes that visible next
// to the speedups it bounds.
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

    // Times the reference build on each CPU (a thread pinned to it, the
    // median of a few builds) and keeps the times as one more round.
    void probe();
    // Notes the CPU the calling thread is on now (after a 1-thread build).
    void note_calling_cpu();

    // Lines for the report below a scene's table ("" when not available).
    std::string report() const;
    // Forgets the rounds and the CPUs noted (a new scene).
    void clear();

    // The reference: a sequential build of this generated scene.
    static constexpr const char* kReference = "gen:sphere:30000";

private:
    std::vector<int> cpus_;
    TriangleMesh reference_;
    BuildOptions options_;
    std::vector<std::vector<double>> ms_;  // ms_[i]: the reference's time on cpus_[i], per round
    std::vector<uint32_t> calling_;        // calling_[i]: 1-thread builds that ended on cpus_[i]
    uint32_t calling_elsewhere_ = 0;
};

}  // namespace canopy::cli
