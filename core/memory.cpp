// canopy: huge-page advice for big arrays (see memory.h).
#include "memory.h"

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
