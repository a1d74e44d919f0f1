// canopy: huge-page advice for big arrays (see memory.h).
#include "memory.h"

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

void* map_pages(std::size_t bytes) {
    void* p = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    report_mapped(std::ptrdiff_t(bytes));
#if defined(MADV_HUGEPAGE)
    // The whole mapping, not only its 2 MiB-aligned interior as
    // advise_huge_pages() does: advice on part of a mapping splits it into
    // areas of different kinds, and mremap() refuses (EFAULT) to grow a
    // range over more than one. Growing keeps the advice.
    (void)madvise(p, bytes, MADV_HUGEPAGE);  // advice only
#endif
    return p;
}

void* remap_pages(void* p, std::size_t old_bytes, std::size_t new_bytes) {
    // Counted before a growth and after a shrink: the observer's high-water
    // mark then covers the moment both sizes' pages may be held.
    if (new_bytes > old_bytes) report_mapped(std::ptrdiff_t(new_bytes - old_bytes));
    void* q = mremap(p, old_bytes, new_bytes, MREMAP_MAYMOVE);
    if (q == MAP_FAILED) {
        if (new_bytes > old_bytes) report_mapped(-std::ptrdiff_t(new_bytes - old_bytes));
        throw std::bad_alloc();
    }
    if (new_bytes < old_bytes) report_mapped(-std::ptrdiff_t(old_bytes - new_bytes));
    return q;
}

void unmap_pages(void* p, std::size_t bytes) noexcept {
    if (p == nullptr) return;
    (void)munmap(p, bytes);  // fails only for an invalid range, which a caller's bug would be
    report_mapped(-std::ptrdiff_t(bytes));
}
#else
bool growable_mappings_available() noexcept { return false; }
void* map_pages(std::size_t) { throw std::bad_alloc(); }
void* remap_pages(void*, std::size_t, std::size_t) { throw std::bad_alloc(); }
void unmap_pages(void*, std::size_t) noexcept {}
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
