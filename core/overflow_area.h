// canopy: where a one-off parallel build keeps the nodes of subtrees that do
// not fit over their own records.
//
// A worker writes each subtree it builds below the task cutoff over the
// subtree's records (core/layout.h, SubtreeBlock); a subtree has at most
// 2k - 1 nodes for k records, so the nodes past the first k fit in k slots
// too. The overflow area gives every subtree those k slots at the same
// index as its records, [begin, begin + k): one array for all workers, in
// the order of the subtrees' ranges whoever built them, so that the
// placement, which consumes the subtrees in that order, can give the pages
// back as it goes (place_beside_records()). Meshes' trees put a few percent
// of their subtrees' nodes here, random triangles' trees 0.86 nodes per
// record. The area is address space until written: 4 KiB pages (no huge
// pages, which a sparse first write would bring in 2 MiB at a time), each
// counted when first written (PageLedger). The area also sees every
// block's size, which tells, before the placement, when the tree cannot
// fit over its records (watch_front()).
#pragma once

#include "memory.h"
#include "node.h"
#include "node_array.h"

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
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
    }
    ~OverflowArea() { reset(0); }

    // Room for nodes [0, n) (n: the build's primitives; 0 lets it go).
    void reset(std::size_t n) {
        if (mapping_.p) {
            ledger_.release_counted();
            mapping_.discarded = mapping_.bytes;  // the ledger did the reporting
            unmap_pages(mapping_);
        }
        heap_.reset();
        data_ = nullptr;
        front_.reset();
        if (n == 0) return;
        if (growable_mappings_available()) {
            mapping_ = map_pages(n * sizeof(Node), 0, false, false);
            ledger_ = PageLedger(mapping_.bytes, kUnit, true);
            data_ = static_cast<Node*>(mapping_.p);
        } else {
            heap_.reset(new Node[n]);  // counted by the heap
            data_ = heap_.get();
        }
    }
    Node* data() const noexcept { return data_; }

    // Writes nodes [at, at + k), their pages brought in by one system call
    // (populate_pages(); a subtree writes 512 nodes or more here, 4 pages
    // or more). Random triangles write about 0.86 nodes per record here,
    // 6,700 pages of 4 KiB per million: with a fault per page, a 2-thread
    // build of 1M random triangles took 8,440 page faults (1,349 with one
    // call per subtree, and 0.975 to 0.977 times the time).
    void write(std::size_t at, const Node* src, std::size_t k) noexcept {
        if (mapping_.p) {
            ledger_.touch(at * sizeof(Node), (at + k) * sizeof(Node));
            populate_pages(data_ + at, k * sizeof(Node));
        }
        std::memcpy(static_cast<void*>(data_ + at), src, k * sizeof(Node));
    }
    // Gives back the pages wholly inside nodes [from, to), which must not be
    // read or written again.
    void release(std::size_t from, std::size_t to) noexcept {
        if (!mapping_.p) return;
        const auto [a, b] = ledger_.release(from * sizeof(Node), to * sizeof(Node));
        if (b > a) discard_pages(mapping_, a, b - a, false);
    }

    // Moves the pages of nodes [from, from + bytes / sizeof(Node)) (whole
    // pages) to `to`, in another mapping, without copying, and counts them
    // as given back here (core/memory.h, move_pages()); gives them back
    // where they cannot move. They must not be read or written again here.
    bool give(std::size_t from, void* to, std::size_t bytes) noexcept {
        if (!mapping_.p) return false;
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

private:
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
};

}  // namespace canopy
