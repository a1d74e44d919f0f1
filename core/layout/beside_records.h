// canopy: placing a tree that does not fit over its records into a new
// array beside them, giving back the records' pages and the overflow area's
// as the copies consume them (place_over_records() in core/layout.h).
#pragma once

#include "move_blocks.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace canopy {

// The step in which place_beside_records() gives back the pages it has
// consumed (of the records' storage and the overflow area): one system call
// per 256 KiB consumed. The new array's pages are counted in units of 2 MiB,
// a huge page, which a first write brings in whole.
inline constexpr size_t kDiscardUnit = size_t(256) << 10;
inline constexpr size_t kTouchUnit = size_t(2) << 20;
inline constexpr size_t kHugeMin = size_t(56) << 20;
inline constexpr size_t kRunsMin = size_t(192) << 20;

// place_beside_records()'s thresholds (tests lower them to reach its paths
// with small trees).
struct BesideRecordsSizes {
    size_t huge_min = kHugeMin;  // the new array on huge pages from here (and pages moved to it)
    size_t runs_min = kRunsMin;  // moving pages, the copies split into runs from here
};

// Places a tree that does not fit over its records (place_over_records())
// into a new array of `total` nodes beside the records' storage `nodes`,
// without holding both whole: the blocks are copied in the order of their
// ranges, split into one run per worker (cut as move_blocks() cuts them,
// but into memory of their own, so that the runs never wait for each
// other), and each run gives back to the system the pages of the records'
// storage and of the overflow area (which holds each block's nodes at its
// range too) below the next block's range, as it goes, while the new
// array's pages are counted as they are first written (PageLedger). With
// 1.86 nodes per record the new array grows by about as many bytes as the
// storage and the overflow area give back, so the peak stays near that of
// the end of the build (the storage and the overflow area). Returns the
// new array (the caller swaps it in). `area`: the arenas' overflow area.
template <class ForEach>
NodeArray place_beside_records(std::span<const BlockMove> moves, const PrimRef* refs, OverflowArea& area,
                               NodeArray& nodes, size_t total, size_t groups, ForEach&& for_each,
                               BesideRecordsSizes sizes = {}) {
    // On huge pages from kHugeMin bytes (counted 2 MiB at a time as first
    // written); smaller arrays, for which the 2 MiB a run may have counted
    // ahead of its writes would be a sizeable part, fault in 4 KiB pages
    // (and count them), about five times as slow per byte (a 64 MiB mapping
    // touched in 12.4 ms against 2.6, 2026-12-05). Also on huge pages when
    // the overflow area has huge pages (OverflowArea::any_huge(): random
    // triangles' trees from 983,040 records) and the storage is a mapping,
    // so that the area's huge pages move whole into the new array instead of
    // being held until every 4 KiB of them is consumed.
    const bool huge = total * sizeof(Node) >= sizes.huge_min || (area.any_huge() && nodes.mapped());
    NodeArray out(NodeArray::Uncounted{huge}, total);
    PageLedger touched(out.capacity() * sizeof(Node), huge ? kTouchUnit : 4096, out.mapped());
    // Steps of kDiscardUnit, smaller for small trees (each run may hold up
    // to a step of the storage and of the area that it has consumed).
    const size_t step = std::clamp<size_t>(total / 128, 4096 / sizeof(PrimRef), kDiscardUnit / sizeof(PrimRef));
    // With the new array on huge pages and the storage a mapping (on huge
    // pages too), the storage's consumed huge pages go to the new array
    // (NodeArray::give_pages(): page tables move, nothing is zeroed), and so
    // do the overflow area's consumed 2 MiB (4 KiB pages), before the run
    // writes there: about as many bytes as the new array needs (1.86 nodes
    // per record: 1 from the storage, 0.86 from the area). The storage goes
    // in whole huge pages and the area in whole 2 MiB, each run keeping the
    // last of each for the next huge page it writes; a run takes only huge
    // pages wholly inside its own slots, before it writes them, so no other
    // run writes there. Measured on an AMD EPYC host (2026-12-05): giving
    // back part of a huge page splits it, and a fresh huge page is zeroed
    // by the kernel (which at times must compact memory to find one): the
    // placement of 1M random triangles took 11.3 to 12.8 ms that way
    // against 4.4 to 5.5 (traced 2-thread tbb builds), and alternated builds
    // of 4M random triangles 1.07 times as long as before the new array
    // (0.996 with the pages moved). The area's 2 MiB come with its blocks'
    // unused range ends never brought in, which the run would fault in 4
    // KiB at a time: populated by one system call as they move (on the host
    // of 2026-12-06, where a 4 KiB fault took about 10 us, the placement of
    // 1M random triangles took 12.5 ms against 14.1, and of 4M 38.9 against
    // 43.6; giving the area's pages back instead of moving them took 8.2 and
    // 125: fresh huge pages are slow to come from the host when it has
    // taken back the memory, as for the 4M scene; medians of 7 and 3 traced
    // 2-thread tbb builds, alternated). A dense area's huge pages
    // (core/overflow_area.h) move as one page table entry each. A run then
    // holds up to about 6 MiB it has consumed or not yet written, so below
    // kRunsMin bytes of new array the copies run as one.
    const bool recycle = huge && out.mapped() && nodes.mapped();
    const std::uintptr_t storage_unit = recycle ? (std::uintptr_t(2) << 20) - 1 : std::uintptr_t(4095);
    groups = std::clamp<size_t>(recycle && total * sizeof(Node) < sizes.runs_min ? 1 : groups, 1,
                                std::max<size_t>(moves.size(), 1));
    const std::vector<size_t> first = cut_runs(moves, groups);
    constexpr size_t kHuge = size_t(2) << 20;
    for_each(groups, [&](size_t r) {
        if (first[r] == first[r + 1]) return;
        // This run's records are given back in steps, from the first page
        // (or huge page) boundary in them to the last below what is
        // consumed (the pages it shares with its neighbours go with the
        // storage and the area).
        constexpr size_t kPageNodes = 4096 / sizeof(Node);
        const size_t start = r == 0 ? 0 : moves[first[r]].block->root.begin;
        std::uintptr_t storage_done = (reinterpret_cast<std::uintptr_t>(refs + start) + storage_unit) & ~storage_unit;
        // The first run's records up to that boundary share their huge page
        // with the storage's front, given back before (so the page is split
        // already): given back too as soon as they are consumed, rather than
        // with the storage at the end, since the placement's peak comes
        // while it writes its first new huge pages.
        const std::uintptr_t head_end = r == 0 ? storage_done : 0;
        // The area's slots of records [0, x) end at area.slot(x).
        size_t area_done = (area.slot(start) + kPageNodes - 1) / kPageNodes * kPageNodes, released = start;
        // The run's slots, and its consumed huge pages of the storage not
        // yet handed on or given back (at most one kept).
        const size_t slots_from = size_t(moves[first[r]].c) * sizeof(Node);
        const size_t slots_to = (size_t(moves[first[r + 1] - 1].c) + moves[first[r + 1] - 1].block->size - 1) * sizeof(Node);
        std::uintptr_t spare = 0;
        // Likewise a consumed 2 MiB of the overflow area (4 KiB pages, moved
        // as they are), its first node.
        constexpr size_t kNone = ~size_t(0), kHugeNodes = kHuge / sizeof(Node);
        size_t area_spare = kNone;
        char* const base = reinterpret_cast<char*>(out.data());
        for (size_t k = first[r]; k < first[r + 1]; ++k) {
            const BlockMove& m = moves[k];
            const SubtreeBlock& b = *m.block;
            const size_t from = size_t(m.c) * sizeof(Node), to = (size_t(m.c) + b.size - 1) * sizeof(Node);
            if (recycle && (spare || area_spare != kNone)) {
                for (size_t u = from / kHuge * kHuge; u < to && (spare || area_spare != kNone); u += kHuge) {
                    if (u < slots_from || u + kHuge > slots_to || !touched.untouched(u)) continue;
                    // Counted there by touch() below, as given back here.
                    if (spare) {
                        if (nodes.give_pages(reinterpret_cast<const void*>(spare), base + u, kHuge)) spare = 0;
                    } else {
                        // The area's unused range ends were never brought
                        // in: brought in now, by one system call, rather
                        // than by a fault per 4 KiB page as the run writes.
                        if (area.give(area_spare, base + u, kHuge)) populate_pages(base + u, kHuge);
                        area_spare = kNone;
                    }
                }
            }
            touched.touch(from, to);
            place_block_body(*m.arena, b, refs, m.c, out.data() + m.c);
            // Every record before the next block's is consumed.
            const size_t consumed = k + 1 < moves.size() ? moves[k + 1].block->root.begin
                                                         : size_t(b.root.begin) + b.over_records;
            // Every `step` records, and as soon as a whole 2 MiB of the area
            // or of the storage is consumed, to be handed on to the next new
            // huge page before the run touches it fresh.
            const bool whole_unit = recycle && (area.slot(consumed) / kHugeNodes > area.slot(released) / kHugeNodes ||
                                                (reinterpret_cast<std::uintptr_t>(refs + consumed) & ~storage_unit) >=
                                                    storage_done + kHuge);
            if (consumed >= released + step || whole_unit || k + 1 == first[r + 1]) {
                const std::uintptr_t head = reinterpret_cast<std::uintptr_t>(refs) & ~std::uintptr_t(4095);
                if (head_end > head && released < size_t(head_end - reinterpret_cast<std::uintptr_t>(refs)) / sizeof(PrimRef) &&
                    consumed >= size_t(head_end - reinterpret_cast<std::uintptr_t>(refs)) / sizeof(PrimRef))
                    nodes.discard(reinterpret_cast<const void*>(head), reinterpret_cast<const void*>(head_end));
                std::uintptr_t storage_to = reinterpret_cast<std::uintptr_t>(refs + consumed) & ~storage_unit;
                if (recycle && storage_to > storage_done) {
                    // Keeps the last whole huge page for the next one the run writes.
                    if (spare) nodes.discard(reinterpret_cast<const void*>(spare), reinterpret_cast<const void*>(spare + kHuge));
                    spare = storage_to - kHuge;
                    storage_to = spare;
                }
                if (storage_to > storage_done)
                    nodes.discard(reinterpret_cast<const void*>(storage_done), reinterpret_cast<const void*>(storage_to));
                storage_done = std::max(storage_done, recycle && spare ? spare + kHuge : storage_to);
                // Recycling, the area goes in whole 2 MiB, the last kept
                // for the next huge page the run writes.
                const size_t area_end = area.slot(consumed);
                const size_t area_to = recycle ? area_end / kHugeNodes * kHugeNodes : area_end / kPageNodes * kPageNodes;
                if (recycle && area_to >= area_done + kHugeNodes) {
                    if (area_spare != kNone) area.release(area_spare, area_spare + kHugeNodes);
                    area_spare = area_to - kHugeNodes;
                    area.release(area_done, area_spare);
                } else if (area_to > area_done) {
                    area.release(area_done, area_to);
                }
                area_done = std::max(area_done, area_to);
                released = consumed;
            }
        }
        if (spare) nodes.discard(reinterpret_cast<const void*>(spare), reinterpret_cast<const void*>(spare + kHuge));
        if (area_spare != kNone) area.release(area_spare, area_spare + kHugeNodes);
    });
    touched.count_untouched();
    return out;
}

}  // namespace canopy
