// canopy: a seeded random source that gives the same numbers everywhere.
#pragma once

#include <cstdint>
#include <random>

namespace canopy {

// Uniform doubles in [0, 1) from std::mt19937_64, whose output sequence the
// standard fixes, mapped by hand: the top 53 bits of one 64-bit draw
// (std::uniform_real_distribution differs between standard libraries). The
// generated scenes (core/generators.cpp), the sweep's ray set (`canopy sweep`)
// and the stress tests draw from it, so that a seed means the same scene
// and the same rays on every platform.
class Rng {
public:
    explicit Rng(uint64_t seed) : engine_(seed) {}
    double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
    double range(double lo, double hi) { return lo + (hi - lo) * uniform(); }
    uint64_t next() { return engine_(); }  // one raw 64-bit draw

private:
    std::mt19937_64 engine_;
};

}  // namespace canopy
