// canopy: huge-page advice for big arrays (see memory.h).
#include "memory.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstring>
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
    // Whole huge pages: a last part of one would fault 4 KiB at a time.
    bytes = (bytes + kHugeAllocMin - 1) / kHugeAllocMin * kHugeAllocMin;
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

void report_mapped_bytes(std::ptrdiff_t delta) noexcept { report_mapped(delta); }

PageLedger::PageLedger(std::size_t bytes, std::size_t unit, bool active)
    : bytes_(active ? bytes : 0), unit_(std::max<std::size_t>(unit, 1)), units_((bytes_ + unit_ - 1) / unit_),
      state_(new std::atomic<unsigned char>[units_]) {
    for (std::size_t i = 0; i < units_; ++i) state_[i].store(0, std::memory_order_relaxed);
}

void PageLedger::touch(std::size_t from, std::size_t to) noexcept {
    to = std::min(to, bytes_);
    if (from >= to) return;
    for (std::size_t u = from / unit_; u <= (to - 1) / unit_; ++u) {
        unsigned char untouched = 0;
        if (state_[u].load(std::memory_order_relaxed) == 0 &&
            state_[u].compare_exchange_strong(untouched, 1, std::memory_order_relaxed))
            report_mapped(std::ptrdiff_t(std::min(bytes_, (u + 1) * unit_) - u * unit_));
    }
}

std::pair<std::size_t, std::size_t> PageLedger::release(std::size_t from, std::size_t to) noexcept {
    // A range that reaches the end takes the last unit, whole or not.
    const std::size_t first = (from + unit_ - 1) / unit_, last = to >= bytes_ ? units_ : to / unit_;
    if (first >= last) return {0, 0};
    for (std::size_t u = first; u < last; ++u)
        if (state_[u].exchange(2, std::memory_order_relaxed) == 1)
            report_mapped(-std::ptrdiff_t(std::min(bytes_, (u + 1) * unit_) - u * unit_));
    return {first * unit_, std::min(bytes_, last * unit_)};
}

void PageLedger::count_untouched() noexcept { touch(0, bytes_); }

void PageLedger::release_counted() noexcept { (void)release(0, bytes_); }

void set_mapped_bytes_observer(MappedBytesObserver observer) noexcept {
    g_mapped_observer.store(observer, std::memory_order_release);
}

#if defined(__linux__)
bool growable_mappings_available() noexcept { return true; }

namespace {
constexpr std::size_t kPage = 4096, kHugePage = std::size_t(2) << 20;
std::size_t round_up(std::size_t bytes, std::size_t unit) { return (bytes + unit - 1) / unit * unit; }
// What a mapping's accessible size is a whole number of (map_pages()).
std::size_t mapping_unit(bool huge, std::size_t bytes) {
    return huge && bytes >= kWholeHugeMin ? kHugePage : kPage;
}

// Address space for `reserved` bytes from a 2 MiB boundary, inaccessible,
// advised for huge pages as a whole (advice on part of it would split it
// into areas of different kinds, which mremap() refuses to take together).
void* reserve_aligned(std::size_t reserved, bool huge = true) {
    const std::size_t span = reserved + kHugePage;
    void* raw = mmap(nullptr, span, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (raw == MAP_FAILED) throw std::bad_alloc();
    const auto at = reinterpret_cast<std::uintptr_t>(raw);
    const std::uintptr_t start = (at + kHugePage - 1) & ~std::uintptr_t(kHugePage - 1);
    if (start > at) (void)munmap(raw, start - at);
    if (at + span > start + reserved) (void)munmap(reinterpret_cast<void*>(start + reserved), at + span - start - reserved);
#if defined(MADV_HUGEPAGE) && defined(MADV_NOHUGEPAGE)
    (void)madvise(reinterpret_cast<void*>(start), reserved, huge ? MADV_HUGEPAGE : MADV_NOHUGEPAGE);  // advice only
#endif
    return reinterpret_cast<void*>(start);
}
}  // namespace

PageMapping map_pages(std::size_t bytes, std::size_t reserve, bool counted, bool huge) {
    PageMapping m;
    m.huge = huge;
    m.bytes = round_up(std::max<std::size_t>(bytes, 1), mapping_unit(huge, bytes));
    m.reserved = round_up(std::max(2 * m.bytes, reserve), kHugePage);
    m.p = reserve_aligned(m.reserved, huge);
    if (counted) report_mapped(std::ptrdiff_t(m.bytes));
    if (mprotect(m.p, m.bytes, PROT_READ | PROT_WRITE) != 0) {
        PageMapping failed = m;
        if (!counted) failed.discarded = failed.bytes;  // nothing to take back
        unmap_pages(failed);
        throw std::bad_alloc();
    }
    return m;
}

void grow_pages(PageMapping& m, std::size_t bytes) {
    bytes = round_up(bytes, mapping_unit(m.huge, bytes));
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
        q = reserve_aligned(reserved, m.huge);
    } catch (...) {
        report_mapped(-std::ptrdiff_t(bytes - m.bytes));
        throw;
    }
    if (mremap(m.p, m.bytes, m.bytes, MREMAP_MAYMOVE | MREMAP_FIXED, q) == MAP_FAILED) {
        // Pages moved in from elsewhere (move_pages()) make the mapping
        // several areas, which mremap() does not take together: copied.
        if (mprotect(q, m.bytes, PROT_READ | PROT_WRITE) != 0) {
            (void)munmap(q, reserved);
            report_mapped(-std::ptrdiff_t(bytes - m.bytes));
            throw std::bad_alloc();
        }
        report_mapped(std::ptrdiff_t(m.bytes));  // both held while it copies
        std::memcpy(q, m.p, m.bytes);
        (void)munmap(m.p, m.reserved);
        report_mapped(-std::ptrdiff_t(m.bytes - m.discarded));
        m.discarded = 0;
    } else if (m.reserved > m.bytes) {
        // mremap() left a hole where the pages were; the rest of the old
        // reservation goes too.
        (void)munmap(static_cast<char*>(m.p) + m.bytes, m.reserved - m.bytes);
    }
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

std::size_t discard_pages(PageMapping& m, std::size_t offset, std::size_t bytes, bool report) noexcept {
    if (m.p == nullptr) return 0;
    // Whole pages by address (m.p need not be page-aligned: heap storage).
    const auto base = reinterpret_cast<std::uintptr_t>(m.p);
    const std::uintptr_t first = round_up(base + std::min(offset, m.bytes), kPage),
                         last = (base + std::min(m.bytes, offset + bytes)) / kPage * kPage;
    if (first >= last) return 0;
    if (madvise(reinterpret_cast<void*>(first), last - first, MADV_DONTNEED) != 0) return 0;
    if (report) {
        m.discarded += last - first;
        report_mapped(-std::ptrdiff_t(last - first));
    }
    return last - first;
}

void populate_pages(void* p, std::size_t bytes) noexcept {
#if defined(MADV_POPULATE_WRITE)
    static std::atomic<bool> unsupported{false};
    if (p == nullptr || bytes == 0 || unsupported.load(std::memory_order_relaxed)) return;
    const auto base = reinterpret_cast<std::uintptr_t>(p);
    const std::uintptr_t first = base / kPage * kPage, last = round_up(base + bytes, kPage);
    if (madvise(reinterpret_cast<void*>(first), last - first, MADV_POPULATE_WRITE) != 0 && errno == EINVAL)
        unsupported.store(true, std::memory_order_relaxed);  // a kernel before 5.14
#else
    (void)p, (void)bytes;
#endif
}

bool move_pages(PageMapping& m, std::size_t offset, void* to, std::size_t bytes, bool report) noexcept {
#if defined(MREMAP_DONTUNMAP)
    if (m.p == nullptr || offset % kPage || bytes % kPage || offset + bytes > m.bytes) return false;
    if (mremap(static_cast<char*>(m.p) + offset, bytes, bytes, MREMAP_MAYMOVE | MREMAP_FIXED | MREMAP_DONTUNMAP, to) ==
        MAP_FAILED)
        return false;
    if (report) {
        m.discarded += bytes;
        report_mapped(-std::ptrdiff_t(bytes));
    }
    return true;
#else
    (void)m, (void)offset, (void)to, (void)bytes, (void)report;
    return false;
#endif
}

void unmap_pages(PageMapping& m) noexcept {
    if (m.p == nullptr) return;
    (void)munmap(m.p, m.reserved);  // fails only for an invalid range, which a caller's bug would be
    report_mapped(-std::ptrdiff_t(m.bytes - m.discarded));
    m = PageMapping{};
}
#else
bool growable_mappings_available() noexcept { return false; }
PageMapping map_pages(std::size_t, std::size_t, bool, bool) { throw std::bad_alloc(); }
void grow_pages(PageMapping&, std::size_t) { throw std::bad_alloc(); }
std::size_t discard_pages(PageMapping&, std::size_t, std::size_t, bool) noexcept { return 0; }
bool move_pages(PageMapping&, std::size_t, void*, std::size_t, bool) noexcept { return false; }
void populate_pages(void*, std::size_t) noexcept {}
void unmap_pages(PageMapping& m) noexcept { m = PageMapping{}; }
#endif

bool advise_huge_pages(void* p, std::size_t bytes) noexcept {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
    if (p == nullptr || bytes < kHuge) return false;
    const std::uintptr_t begin = (reinterpret_cast<std::uintptr_t>(p) + kHuge - 1) & ~(kHuge - 1);
    const std::uintptr_t end = (reinterpret_cast<std::uintptr_t>(p) + bytes) & ~(kHuge - 1);
    return end > begin && madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE) == 0;
#else
    (void)p;
    (void)bytes;
    return false;
#endif
}

}  // namespace canopy
