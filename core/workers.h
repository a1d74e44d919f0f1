// canopy: per-worker scratch of the parallel drivers, kept by the build
// state so that a warm builder (core/builder.h) reuses it between builds.
#pragma once

#include "kernel.h"
#include "layout.h"

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

namespace canopy {

// Per-worker scratch: bins, the nodes it created (task records and inline
// subtree blocks), its counters.
// One per thread, each on cache lines of its own: the record vector and the
// skip counters change at every node, and two workers sharing a line made
// the threads invalidate each other's copy at every node (false sharing).
struct alignas(64) Worker {
    std::unique_ptr<BinSet> bins;  // made by Workers::reset()
    PlacementArena out;
    SkipCounts skip;
    uint32_t id = 0;  // the trace's track
};

struct Workers {
    std::vector<Worker> w;
    OverflowArea overflow;  // one-off builds' (reset(..., over_records))

    Workers() = default;
    Workers(uint32_t count, uint32_t primitives, uint32_t bins = kMaxBins) { reset(count, primitives, bins); }

    // `count` workers with empty arenas and counters, keeping the memory of
    // earlier builds (bins, record vectors, node chunks). `primitives`: the
    // build's size, which sets the workers' chunk size for subtree blocks
    // unless `chunk_nodes` does: about a sixteenth of a worker's share of
    // the nodes (one node per primitive is typical), between 256 KiB and
    // 4 MiB. The unused part of the chunk each worker is filling is held
    // until the build ends, beside the records, so it is kept small beside
    // the scene (until late on 2026-12-02: a quarter of the share, at least
    // 1 MiB).
    // `over_records`: the blocks are kept over their records (SubtreeBlock),
    // the nodes that do not fit over them in the overflow area or, a few
    // (and those past a dense area's slots), in the chunks.
    // `bins`: the build's bins option; each worker's bin set has room for
    // the most its nodes use (bins_for() of the whole scene), no more.
    // `area_dense_min`: OverflowArea::reset()'s (tests lower it).
    void reset(uint32_t count, uint32_t primitives, uint32_t bins, uint32_t chunk_nodes = 0,
               bool over_records = false, size_t area_dense_min = OverflowArea::kHugeAreaMin) {
        w.resize(count);
        const uint32_t max_bins = bins_for(std::max(primitives, 1u), bins);
        overflow.reset(over_records ? primitives : 0, area_dense_min);
        // Over their records (a one-off build), the chunks take only the
        // nodes past the records of subtrees with a few more nodes than
        // records (PlacementArena::kSpillMax; the overflow area takes the
        // others): an eighth of that size, from 1,024 nodes.
        const size_t share = size_t(primitives) / ((over_records ? 128 : 16) * size_t(std::max(1u, count)));
        size_t chunk = chunk_nodes ? chunk_nodes
                                   : std::clamp<size_t>(share, size_t(1) << (over_records ? 10 : 13), size_t(1) << 17);
        // From 1 MiB on, a whole number of huge pages (2 MiB, 65,536
        // nodes): such a chunk starts on a 2 MiB boundary (NodeChunk,
        // allocate_huge) and faults one huge page at a time. The 4M scenes'
        // chunks at 2 threads were 125,000 nodes, under the 4 MiB from which
        // arrays were advised, and faulted in 4 KiB pages: about 52,000
        // page faults per build of the 4M random scene, 2,200 after
        // (perf stat); tbb at 2 threads 0.86x the time (three alternated
        // pairs of --repeat 5 medians, 695-702 ms against 791-890).
        if (!chunk_nodes && chunk >= (size_t(1) << 15)) chunk = (chunk + 0xFFFF) & ~size_t(0xFFFF);
        for (uint32_t i = 0; i < count; ++i) {
            if (!w[i].bins || w[i].bins->max_bins() != ((max_bins + 3) & ~3u))
                w[i].bins = std::make_unique<BinSet>(max_bins);
            w[i].id = i;
            w[i].skip = SkipCounts{};
            w[i].out.reset();
            w[i].out.chunk_nodes = chunk;
            w[i].out.over_records = over_records;
            w[i].out.overflow = over_records ? &overflow : nullptr;
        }
    }
    Worker& operator[](size_t i) { return w[i]; }
    size_t size() const { return w.size(); }
};

}  // namespace canopy
