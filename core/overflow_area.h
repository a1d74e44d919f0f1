// canopy: where a one-off parallel build keeps the nodes of subtrees that do
// not fit over their own records.
//
// A worker writes each subtree it builds below the task cutoff over the
// subtree's records (core/layout.h, SubtreeBlock); a subtree has at most
// 2k - 1 nodes for k records, so the nodes past the first k fit in k slots
// too. The overflow area gives every subtree slots at its records' range,
// [slot(begin), slot(begin + k)): one array for all workers, in the order
// of the subtrees' ranges whoever built them, so that the placement, which
// consumes the subtrees in that order, can give the pages back as it goes
// (place_beside_records()). Meshes' trees put a few percent of their
// subtrees' nodes here, random triangles' trees 0.86 nodes per record (0.835
// to 0.888 per subtree, 1M to 4M triangles). The area is address space until
// written, each page counted when first written (PageLedger): 4 KiB pages,
// which a sparse first write brings in one at a time, except in a big area
// (kHugeAreaMin), where a 2 MiB region that a dense subtree (write()) reaches
// first becomes a huge page, counted whole. A big area is also dense: a
// subtree of k records has 7k/8 slots (slot(): random triangles' subtrees
// fill 0.98 of them; the nodes that do not fit go to the worker's chunks),
// so that its huge pages hold little that is never written. The area also
// sees every block's size, which tells, before the placement, when the tree
// cannot fit over its records (watch_front()).
#pragma once

#include "memory.h"
#include "node.h"
#include "node_array.h"

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <algorithm>
#include <memory>
#include <utility>

namespace canopy {

class OverflowArea {
public:
    static constexpr std::size_t kUnit = 4096;

    OverflowArea() = default;
    OverflowArea(OverflowArea&& o) noexcept { swap(o); }
    OverflowArea& operator=(OverflowArea&& o) noexcept {
        OverflowArea(std::move(o)).swap(*this);
        return *this;
    }
    void swap(OverflowArea& o) noexcept {
        std::swap(mapping_, o.mapping_);
        std::swap(ledger_, o.ledger_);
        std::swap(heap_, o.heap_);
        std::swap(data_, o.data_);
        std::swap(front_, o.front_);
        std::swap(regions_, o.regions_);
        std::swap(dense_, o.dense_);
        any_huge_.store(o.any_huge_.exchange(any_huge_.load()));
    }
    ~OverflowArea() { reset(0); }

    // Room for the nodes of n records (the build's primitives; 0 lets it
    // go), dense from `dense_min` bytes (kHugeAreaMin; tests lower it).
    void reset(std::size_t n, std::size_t dense_min = kHugeAreaMin) {
        if (mapping_.p) {
            ledger_.release_counted();
            mapping_.discarded = mapping_.bytes;  // the ledger did the reporting
            unmap_pages(mapping_);
        }
        heap_.reset();
        data_ = nullptr;
        front_.reset();
        regions_.reset();
        dense_ = false;
        any_huge_.store(false, std::memory_order_relaxed);
        if (n == 0) return;
        if (growable_mappings_available()) {
            // A dense area's mapping ends at its last slot, so that the
            // last region, which no subtree fills, stays on 4 KiB pages.
            dense_ = n * sizeof(Node) >= dense_min;
            mapping_ = map_pages(slot(n) * sizeof(Node), 0, false, false);
            ledger_ = PageLedger(mapping_.bytes, kUnit, true);
            data_ = static_cast<Node*>(mapping_.p);
            if (dense_) regions_.reset(new Region[mapping_.bytes / kRegion + 1]);
        } else {
            heap_.reset(new Node[n]);  // counted by the heap
            data_ = heap_.get();
        }
    }
    Node* data() const noexcept { return data_; }

    // The first slot of the subtree whose records start at `record`: the
    // record itself, or in a dense area 7/8 of it (rounded up), so that a
    // subtree of records [b, e) has the slots [slot(b), slot(e)).
    std::size_t slot(std::size_t record) const noexcept { return dense_ ? record - record / 8 : record; }

    // Writes nodes [at, at + k), their pages brought in by one system call
    // (populate_pages(); a subtree writes 512 nodes or more here, 4 pages
    // or more). Random triangles write about 0.86 nodes per record here,
    // 6,700 pages of 4 KiB per million: with a fault per page, a 2-thread
    // build of 1M random triangles took 8,440 page faults (1,349 with one
    // call per subtree, and 0.975 to 0.977 times the time).
    //
    // `dense`: the subtree writes at least half as many nodes here as it
    // has records, so its neighbours likely do too. In a dense area, a 2 MiB
    // region whose first write is dense becomes a huge page (advised before
    // anything in it is touched), counted whole. On a virtual machine whose
    // guest pays a fault per 4 KiB page on first write even after
    // populate_pages() (the AMD EPYC host of 2026-12-06: 32 MiB populated in
    // 7 ms, then written in 3 to 52 ms; as huge pages 1.6 ms, then 3), the
    // area on 4 KiB pages took about 35 ms of CPU a 2-thread build of 1M
    // random triangles.
    void write(std::size_t at, const Node* src, std::size_t k, bool dense = false) noexcept {
        if (mapping_.p) {
            if (dense_) decide_regions(at * sizeof(Node), (at + k) * sizeof(Node), dense);
            ledger_.touch(at * sizeof(Node), (at + k) * sizeof(Node));
            populate_pages(data_ + at, k * sizeof(Node));
        }
        std::memcpy(static_cast<void*>(data_ + at), src, k * sizeof(Node));
    }
    // Gives back the pages wholly inside nodes [from, to), which must not be
    // read or written again; a huge page once all its 4 KiB pages have been
    // (ranges given back must not overlap).
    void release(std::size_t from, std::size_t to) noexcept {
        if (!mapping_.p) return;
        const std::size_t a = from * sizeof(Node), b = to * sizeof(Node);
        if (!dense_) return release_bytes(a, b);
        for (std::size_t r = a / kRegion; r * kRegion < b; ++r) {
            const std::size_t lo = std::max(a, r * kRegion), hi = std::min(b, (r + 1) * kRegion);
            Region& g = regions_[r];
            if (g.state.load(std::memory_order_acquire) != kHuge) {
                release_bytes(lo, hi);
                continue;
            }
            const std::size_t plo = (lo + kUnit - 1) / kUnit * kUnit, phi = hi / kUnit * kUnit;
            if (phi <= plo) continue;
            const std::size_t done = g.released.fetch_add(phi - plo, std::memory_order_acq_rel) + (phi - plo);
            if (done == kRegion) release_bytes(r * kRegion, (r + 1) * kRegion);
        }
    }

    // Moves the pages of nodes [from, from + bytes / sizeof(Node)) (whole
    // pages) to `to`, in another mapping, without copying, and counts them
    // as given back here (core/memory.h, move_pages()); gives them back
    // where they cannot move. They must not be read or written again here.
    bool give(std::size_t from, void* to, std::size_t bytes) noexcept {
        if (!mapping_.p) return false;
        if (dense_) {
            // A huge page moves only whole, none of it given back yet.
            const std::size_t a = from * sizeof(Node), r = a / kRegion;
            const Region& g = regions_[r];
            if (g.state.load(std::memory_order_acquire) == kHuge &&
                (a % kRegion != 0 || bytes != kRegion || g.released.load(std::memory_order_acquire) != 0)) {
                release(from, from + bytes / sizeof(Node));
                return false;
            }
        }
        const auto [a, b] = ledger_.release(from * sizeof(Node), from * sizeof(Node) + bytes);
        if (b > a && b - a == bytes && move_pages(mapping_, a, to, bytes, false)) return true;
        if (b > a) discard_pages(mapping_, a, b - a, false);
        return false;
    }

    // The records' storage `storage`, whose front, before `records`, a
    // parallel build never writes: the tree's nodes move there when the
    // tree fits over its records (place_over_records()), and otherwise the
    // front is given back. Watched, it is given back as soon as the blocks
    // built so far (count_block()) have more nodes than the storage has
    // slots, which proves that the tree will not fit: random triangles'
    // trees (1.86 nodes per record) pass that point at about three fifths
    // of their blocks, before the build's peak, where the front (a tenth of
    // a node per record) otherwise counted until the placement (a 2-thread
    // build of 100,000 random triangles: 73.7 bytes per triangle at the
    // peak).
    void watch_front(NodeArray& storage, const void* records) {
        front_ = std::make_unique<Front>();
        front_->storage = &storage;
        front_->records = records;
    }
    // A block of `nodes` nodes is built (any thread).
    void count_block(std::size_t nodes) noexcept {
        if (!front_) return;
        Front& f = *front_;
        const std::uint64_t sum = f.block_nodes.fetch_add(nodes, std::memory_order_relaxed) + nodes;
        if (sum > f.storage->capacity()) give_front(*f.storage, f.records);
    }
    // Gives the front of `storage` (before `records`) back, once: unless
    // count_block() already has (the placement's call, for a tree that does
    // not fit over its records).
    void give_front(NodeArray& storage, const void* records) noexcept {
        if (front_ && front_->given.exchange(true, std::memory_order_relaxed)) return;
        storage.discard(storage.data(), records);
    }
    // Whether the watched front was given back.
    bool front_given() const noexcept { return front_ && front_->given.load(std::memory_order_relaxed); }

    // Areas from this size on (983,040 records and more) are dense and may
    // have huge regions: the records' storage (1.1 slots a record) is then
    // a mapping of whole huge pages, and the placement of a tree that does
    // not fit over its records moves the storage's and the area's pages
    // into its new array 2 MiB at a time (place_beside_records()). From 28
    // MiB on, the trees of 920,000 to 950,000 random triangles, whose
    // storage is smaller, peaked at 71.6 to 75.6 bytes per triangle.
    static constexpr std::size_t kHugeAreaMin = std::size_t(30) << 20;
    static constexpr std::size_t kRegion = std::size_t(2) << 20;

    // Whether some region became a huge page.
    bool any_huge() const noexcept { return any_huge_.load(std::memory_order_relaxed); }

private:
    static constexpr unsigned char kUndecided = 0, kDeciding = 1, kSmall = 2, kHuge = 3;
    struct Region {
        std::atomic<unsigned char> state{kUndecided};
        std::atomic<std::size_t> released{0};  // a huge region's bytes given back so far
    };

    void release_bytes(std::size_t a, std::size_t b) noexcept {
        const auto [x, y] = ledger_.release(a, b);
        if (y > x) discard_pages(mapping_, x, y - x, false);
    }

    // Decides the regions bytes [from, to) reach, on the first write to
    // each: a dense write turns a whole region inside the mapping into a
    // huge page, counted whole before anything in it is written. A write
    // that finds a region being decided by another thread waits for the
    // advice to be given, so that no 4 KiB page comes in before it.
    void decide_regions(std::size_t from, std::size_t to, bool dense) noexcept {
        for (std::size_t r = from / kRegion; r * kRegion < to; ++r) {
            std::atomic<unsigned char>& st = regions_[r].state;
            unsigned char s = st.load(std::memory_order_acquire);
            if (s == kUndecided && st.compare_exchange_strong(s, kDeciding, std::memory_order_acq_rel)) {
                const bool whole = (r + 1) * kRegion <= mapping_.bytes;
                const bool huge = dense && whole &&
                                  advise_huge_pages(static_cast<char*>(mapping_.p) + r * kRegion, kRegion);
                if (huge) {
                    ledger_.touch(r * kRegion, (r + 1) * kRegion);
                    any_huge_.store(true, std::memory_order_relaxed);
                }
                st.store(huge ? kHuge : kSmall, std::memory_order_release);
                continue;
            }
            while (st.load(std::memory_order_acquire) == kDeciding) {
#if defined(__x86_64__) || defined(__i386__)
                __builtin_ia32_pause();
#endif
            }
        }
    }

    struct Front {
        NodeArray* storage = nullptr;
        const void* records = nullptr;
        std::atomic<std::uint64_t> block_nodes{0};
        std::atomic<bool> given{false};
    };
    std::unique_ptr<Front> front_;
    PageMapping mapping_;
    PageLedger ledger_;
    std::unique_ptr<Node[]> heap_;
    Node* data_ = nullptr;
    std::unique_ptr<Region[]> regions_;  // a dense area's 2 MiB regions
    bool dense_ = false;
    std::atomic<bool> any_huge_{false};
};

}  // namespace canopy
