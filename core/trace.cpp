#include "trace.h"

#include "error.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <set>

namespace canopy {

void write_chrome_trace(const TraceLog& log, const std::string& path, const std::string& scheduler,
                        uint32_t threads) {
    std::ofstream out(path, std::ios::trunc);
    if (!out) throw Error(path + ": cannot open for writing");
    const auto& kinds = TraceSpan::kKindNames;
    std::set<uint32_t> workers;
    for (const TraceSpan& s : log.spans()) workers.insert(s.worker);
    out << "{\"displayTimeUnit\":\"ms\",\"otherData\":{\"scheduler\":\"" << scheduler
        << "\",\"threads\":" << threads << "},\"traceEvents\":[\n";
    out << "{\"name\":\"process_name\",\"ph\":\"M\",\"pid\":1,\"tid\":0,\"args\":{\"name\":\"canopy build ("
        << scheduler << ")\"}}";
    for (uint32_t w : workers)
        out << ",\n{\"name\":\"thread_name\",\"ph\":\"M\",\"pid\":1,\"tid\":" << w
            << ",\"args\":{\"name\":\"worker " << w << "\"}}";
    char buf[512];
    for (const TraceSpan& s : log.spans()) {
        const double ts = double(s.start_ns) / 1000.0, dur = double(s.end_ns - s.start_ns) / 1000.0;
        const bool phase = s.node_phase();
        char name[64];
        if (phase)
            std::snprintf(name, sizeof name, "node %u: %s", s.node, kinds[s.kind]);
        else if (s.build_phase())
            std::snprintf(name, sizeof name, "build: %s", kinds[s.kind]);
        else
            std::snprintf(name, sizeof name, "node %u", s.node);
        std::snprintf(buf, sizeof buf,
                      ",\n{\"name\":\"%s\",\"cat\":\"%s\",\"ph\":\"X\",\"pid\":1,\"tid\":%u,\"ts\":%.3f,"
                      "\"dur\":%.3f,\"args\":{\"node\":%u,\"primitives\":%u,\"level\":%u,\"mode\":\"%s\"}}",
                      name, phase ? "phase" : s.build_phase() ? "build" : kinds[s.kind], s.worker, ts, dur, s.node,
                      s.count, unsigned(s.depth), kinds[s.kind]);
        out << buf;
    }
    out << "\n]}\n";
    out.flush();
    if (!out) throw Error(path + ": write failed");
}

}  // namespace canopy
