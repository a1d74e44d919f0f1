// canopy: huge-page advice for big arrays (see memory.h).
#include "memory.h"

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <new>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace canopy {

namespace {
constexpr std::align_val_t kHugeAlign{std::size_t(2) << 20};
}

void* allocate_huge(std::size_t bytes) {
    if (bytes < kHugeAllocMin) return ::operator new(bytes);
    void* p = ::operator new(bytes, kHugeAlign);
    advise_huge_pages(p, bytes);
    return p;
}

// Unsized deletes: clang does not declare the sized ones without
// -fsized-deallocation (the fuzz build).
void release_huge(void* p, std::size_t bytes) noexcept {
    if (bytes < kHugeAllocMin) return ::operator delete(p);
    ::operator delete(p, kHugeAlign);
}

namespace {
std::atomic<MappedBytesObserver> g_mapped_observer{nullptr};

void report_mapped(std::ptrdiff_t delta) noexcept {
    if (const MappedBytesObserver f = g_mapped_observer.load(std::memory_order_acquire)) f(delta);
}
}  // namespace

void set_mapped_bytes_observer(MappedBytesObserver observer) noexcept {
    g_mapped_observer.store(observer, std::memory_order_release);
}

#if defined(__linux__)
bool growable_mappings_available() noexcept { return true; }

namespace {
constexpr std::size_t kPage = 4096, kHugePage = std::size_t(2) << 20;
std::size_t round_up(std::size_t bytes, std::size_t unit) { return (bytes + unit - 1) / unit * unit; }

// Address space for `reserved` bytes from a 2 MiB boundary, inaccessible,
// advised for huge pages as a whole (advice on part of it would split it
// into areas of different kinds, which mremap() refuses to take together).
void* reserve_aligned(std::size_t reserved) {
    const std::size_t span = reserved + kHugePage;
    void* raw = mmap(nullptr, span, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (raw == MAP_FAILED) throw std::bad_alloc();
    const auto at = reinterpret_cast<std::uintptr_t>(raw);
    const std::uintptr_t start = (at + kHugePage - 1) & ~std::uintptr_t(kHugePage - 1);
    if (start > at) (void)munmap(raw, start - at);
    if (at + span > start + reserved) (void)munmap(reinterpret_cast<void*>(start + reserved), at + span - start - reserved);
#if defined(MADV_HUGEPAGE)
    (void)madvise(reinterpret_cast<void*>(start), reserved, MADV_HUGEPAGE);  // advice only
#endif
    return reinterpret_cast<void*>(start);
}
}  // namespace

PageMapping map_pages(std::size_t bytes) {
    PageMapping m;
    m.bytes = round_up(std::max<std::size_t>(bytes, 1), kPage);
    m.reserved = round_up(2 * m.bytes, kHugePage);
    m.p = reserve_aligned(m.reserved);
    report_mapped(std::ptrdiff_t(m.bytes));
    if (mprotect(m.p, m.bytes, PROT_READ | PROT_WRITE) != 0) {
        PageMapping failed = m;
        unmap_pages(failed);
        throw std::bad_alloc();
    }
    return m;
}

void grow_pages(PageMapping& m, std::size_t bytes) {
    bytes = round_up(bytes, kPage);
    if (bytes <= m.bytes) return;
    // Counted before it is made: the observer's high-water mark covers it.
    report_mapped(std::ptrdiff_t(bytes - m.bytes));
    if (bytes <= m.reserved) {
        if (mprotect(static_cast<char*>(m.p) + m.bytes, bytes - m.bytes, PROT_READ | PROT_WRITE) != 0) {
            report_mapped(-std::ptrdiff_t(bytes - m.bytes));
            throw std::bad_alloc();
        }
        m.bytes = bytes;
        return;
    }
    // A new reservation; the pages move there, onto the same alignment.
    const std::size_t reserved = round_up(2 * bytes, kHugePage);
    void* q = nullptr;
    try {
        q = reserve_aligned(reserved);
    } catch (...) {
        report_mapped(-std::ptrdiff_t(bytes - m.bytes));
        throw;
    }
    if (mremap(m.p, m.bytes, m.bytes, MREMAP_MAYMOVE | MREMAP_FIXED, q) == MAP_FAILED) {
        (void)munmap(q, reserved);
        report_mapped(-std::ptrdiff_t(bytes - m.bytes));
        throw std::bad_alloc();
    }
    // mremap() left a hole where the pages were; the rest of the old
    // reservation goes too.
    if (m.reserved > m.bytes) (void)munmap(static_cast<char*>(m.p) + m.bytes, m.reserved - m.bytes);
    const std::size_t moved = m.bytes;
    m.p = q;
    m.reserved = reserved;
    // Made accessible after the move, so that it joins the moved area (one
    // area again, which a later move needs).
    if (mprotect(static_cast<char*>(q) + moved, bytes - moved, PROT_READ | PROT_WRITE) != 0) {
        report_mapped(-std::ptrdiff_t(bytes - moved));
        throw std::bad_alloc();  // m is the moved mapping, still valid
    }
    m.bytes = bytes;
}

void unmap_pages(PageMapping& m) noexcept {
    if (m.p == nullptr) return;
    (void)munmap(m.p, m.reserved);  // fails only for an invalid range, which a caller's bug would be
    report_mapped(-std::ptrdiff_t(m.bytes));
    m = PageMapping{};
}
#else
bool growable_mappings_available() noexcept { return false; }
PageMapping map_pages(std::size_t) { throw std::bad_alloc(); }
void grow_pages(PageMapping&, std::size_t) { throw std::bad_alloc(); }
void unmap_pages(PageMapping& m) noexcept { m = PageMapping{}; }
#endif

void advise_huge_pages(void* p, std::size_t bytes) noexcept {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
    if (p == nullptr || bytes < kHuge) return;
    const std::uintptr_t begin = (reinterpret_cast<std::uintptr_t>(p) + kHuge - 1) & ~(kHuge - 1);
    const std::uintptr_t end = (reinterpret_cast<std::uintptr_t>(p) + bytes) & ~(kHuge - 1);
    if (end > begin) (void)madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);  // advice only
#else
    (void)p;
    (void)bytes;
#endif
}

}  // namespace canopy
