// canopy: NodeArray's storage (see node_array.h).
#include "node_array.h"

#include <algorithm>
#include <cstdint>
#include <new>

namespace canopy {

void NodeArray::reallocate(std::size_t n, std::size_t keep, bool whole) {
    const std::size_t bytes = n * sizeof(Node);
    if (whole && keep && !mapped() && growable_mappings_available()) return move_to_mapping(bytes, keep);
    if (growable_mappings_available() && bytes >= map_min_) {
        if (mapped()) {
            // In place within the reservation, or its pages moved: the old
            // and new sizes are never held at once.
            grow_pages(mapping_, bytes);
        } else {
            PageMapping fresh = map_pages(bytes);
            if (keep) std::memcpy(fresh.p, data_, keep * sizeof(Node));
            release();
            mapping_ = fresh;
        }
        data_ = static_cast<Node*>(mapping_.p);
        capacity_ = mapping_.bytes / sizeof(Node);
        return;
    }
    Node* fresh = static_cast<Node*>(::operator new(bytes));
    advise_huge_pages(fresh, bytes);
    if (keep) std::memcpy(static_cast<void*>(fresh), data_, keep * sizeof(Node));
    release();  // keeps size_
    data_ = fresh;
    capacity_ = n;
}

void NodeArray::move_to_mapping(std::size_t bytes, std::size_t keep) {
    // Copied a piece at a time, each piece of the heap storage given back
    // once copied and the mapping counted as it is written (PageLedger), so
    // that the two are never held whole at once; the mapping's part past
    // the copy is counted at the end.
    // On huge pages from 8 MiB: a huge page is counted whole when the copy
    // first writes it, up to 2 MiB more than copied, which matters only
    // while the old storage and that much are more than the new storage
    // (the new one is counted whole in the end), below about 8 MiB.
    const bool huge = bytes >= (std::size_t(8) << 20);
    PageMapping fresh = map_pages(bytes, 0, false, huge);
    PageLedger ledger(fresh.bytes, huge ? std::size_t(2) << 20 : 4096, true);
    constexpr std::size_t kPiece = std::size_t(256) << 10;
    const char* const src = reinterpret_cast<const char*>(data_);
    char* const dst = static_cast<char*>(fresh.p);
    const std::size_t total = keep * sizeof(Node);
    const char* given = src;  // given back up to the page boundary at or after this
    for (std::size_t at = 0; at < total; at += kPiece) {
        const std::size_t len = std::min(kPiece, total - at);
        ledger.touch(at, at + len);
        std::memcpy(dst + at, src + at, len);
        discard(given, src + at + len);
        given = reinterpret_cast<const char*>(reinterpret_cast<std::uintptr_t>(src + at + len) & ~std::uintptr_t(4095));
        given = std::max(given, src);
    }
    ledger.count_untouched();
    release();  // keeps size_; reports the pages given back again as the heap takes the block off
    mapping_ = fresh;
    data_ = static_cast<Node*>(mapping_.p);
    capacity_ = mapping_.bytes / sizeof(Node);
}

NodeArray::NodeArray(Uncounted u, std::size_t n) {
    if (!growable_mappings_available()) {
        resize(n);
        return;
    }
    mapping_ = map_pages(std::max<std::size_t>(n, 1) * sizeof(Node), 0, false, u.huge);
    data_ = static_cast<Node*>(mapping_.p);
    capacity_ = mapping_.bytes / sizeof(Node);
    size_ = n;
}

std::size_t NodeArray::discard(const void* from, const void* to) noexcept {
    if (data_ == nullptr || to <= from) return 0;
    const std::size_t offset = std::size_t(static_cast<const char*>(from) - reinterpret_cast<const char*>(data_));
    const std::size_t bytes = std::size_t(static_cast<const char*>(to) - static_cast<const char*>(from));
    if (mapped()) return discard_pages(mapping_, offset, bytes);
    // Heap storage: its whole pages go back all the same (malloc keeps
    // nothing of its own inside a block), and are reported as given back;
    // release() reports them again once the block is freed, when the heap
    // probe takes the whole block off.
    PageMapping inside{data_, capacity_ * sizeof(Node), capacity_ * sizeof(Node), 0};
    const std::size_t given = discard_pages(inside, offset, bytes);
    heap_discarded_ += given;
    return given;
}

bool NodeArray::give_pages(const void* from, void* to, std::size_t bytes) noexcept {
    if (!mapped()) return false;
    return move_pages(mapping_, std::size_t(static_cast<const char*>(from) - reinterpret_cast<const char*>(data_)), to,
                      bytes);
}

void NodeArray::release() noexcept {
    if (data_ == nullptr) return;
    if (mapped()) {
        unmap_pages(mapping_);
    } else {
        ::operator delete(data_);
        if (heap_discarded_) report_mapped_bytes(std::ptrdiff_t(heap_discarded_));
        heap_discarded_ = 0;
    }
    data_ = nullptr;
    capacity_ = 0;
}

}  // namespace canopy
