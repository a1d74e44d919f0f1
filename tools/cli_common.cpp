#include "cli.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <sstream>

namespace canopy::cli {

std::string default_scheduler() {
    return find_scheduler(CANOPY_DEFAULT_SCHEDULER) ? CANOPY_DEFAULT_SCHEDULER : "sequential";
}

std::string scheduler_names() {
    std::string s;
    for (const auto& e : schedulers()) s += (s.empty() ? "" : ", ") + std::string(e.name);
    return s;
}

const SchedulerEntry& scheduler_or_throw(const std::string& name) {
    const SchedulerEntry* e = find_scheduler(name);
    if (!e) throw UsageError("unknown scheduler '" + name + "' (compiled in: " + scheduler_names() + ")");
    return *e;
}

double median(std::vector<double> v) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string fmt(const char* format, double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, format, v);
    return buf;
}

std::vector<uint32_t> parse_list(const std::string& text, const std::string& what) {
    std::vector<uint32_t> out;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        size_t used = 0;
        unsigned long v = 0;
        try {
            v = std::stoul(item, &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (used == 0 || used != item.size() || v > 1000000)
            throw UsageError(what + ": '" + item + "' is not a number in '" + text + "'");
        out.push_back(static_cast<uint32_t>(v));
    }
    if (out.empty()) throw UsageError(what + ": empty list");
    return out;
}

Progress::Progress(std::string verb) : verb_(std::move(verb)), on_(isatty(STDERR_FILENO) != 0) {}

void Progress::show(const std::string& text) const {
    if (on_) std::fprintf(stderr, "\r\033[Kcanopy %s: %s", verb_.c_str(), text.c_str());
}

void Progress::clear() const {
    if (on_) std::fprintf(stderr, "\r\033[K");
}

}  // namespace canopy::cli
