// canopy tool: what the verbs share. Each verb lives in its own file and
// registers itself with add_<verb>(app), which returns a runner called when
// that subcommand was given.
#pragma once

#include "core/build.h"
#include "schedulers/registry.h"

#include <CLI/CLI.hpp>

#include <functional>
#include <string>
#include <vector>

#ifndef CANOPY_DEFAULT_SCHEDULER
#define CANOPY_DEFAULT_SCHEDULER "sequential"
#endif

namespace canopy::cli {

// Exit statuses.
enum Exit { kOk = 0, kInput = 1, kUsage = 2, kInvalid = 3 };

// Thrown by a verb for a usage error found after parsing (exit 2).
struct UsageError : Error {
    explicit UsageError(const std::string& w) : Error(w) {}
};

using Runner = std::function<int()>;  // called once, outside any hot path

// The scheduler the tools use when none is named (the Meson option, or
// sequential when that one is not compiled in).
std::string default_scheduler();
// "a, b, c" of the compiled-in schedulers.
std::string scheduler_names();
// The entry for `name`, or UsageError naming the ones compiled in.
const SchedulerEntry& scheduler_or_throw(const std::string& name);
// Median of a sample (0 for an empty one).
double median(std::vector<double> v);
// One number printf-formatted ("%.2f", "%.3fx", ...).
std::string fmt(const char* format, double v);
// Parses "1,2,4" into numbers (UsageError on junk).
std::vector<uint32_t> parse_list(const std::string& text, const std::string& what);

// One line of progress on stderr, redrawn in place, only when stderr is a
// terminal (pipes and files stay clean).
class Progress {
public:
    explicit Progress(std::string verb);
    void show(const std::string& text) const;
    void clear() const;

private:
    std::string verb_;
    bool on_;
};

// The verbs.
Runner add_build(CLI::App& app);
Runner add_info(CLI::App& app);
Runner add_bench(CLI::App& app);
Runner add_sweep(CLI::App& app);
Runner add_render(CLI::App& app);

}  // namespace canopy::cli
