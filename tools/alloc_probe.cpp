// Replaceable global allocation functions that keep a count of the bytes the
// heap holds and its high-water mark (see alloc_probe.h).
//
// What a block counts: malloc_usable_size() of it (the bytes asked for plus
// malloc's rounding, at most a few dozen bytes), which unsized deletes can
// look up again. Not for big over-aligned blocks: glibc serves
// aligned_alloc(2 MiB, n) from a mapping of n + 2 MiB and reports the
// unused tail as usable, up to 2 MiB of address space that is never
// touched (the 4M scenes' node chunks, core/memory.h, made the probe report
// 82 bytes per triangle where the process's resident size had not grown).
// Those blocks count the bytes asked for, rounded up to the alignment,
// kept in a small table until they are released.
#include "alloc_probe.h"

#include "core/memory.h"

#include <malloc.h>

#include <array>
#include <atomic>
#include <cstdlib>
#include <mutex>
#include <new>

namespace {

std::atomic<size_t> g_held{0};
std::atomic<size_t> g_peak{0};
std::atomic<size_t> g_base{0};

// Blocks aligned to more than this are counted by their requested size.
constexpr size_t kExactAlign = 4096;

// The requested sizes of the live over-aligned blocks, unordered, searched
// linearly: a build holds a few dozen such blocks at once (the 4M scenes'
// node chunks at 2 threads: about 32), each one megabytes of node work.
// Past kSlots live blocks the table is full and further blocks are counted
// by malloc_usable_size, on allocation and release alike.
class ExactSizes {
public:
    bool insert(void* p, size_t bytes) noexcept {
        const std::lock_guard lock(mutex_);
        if (used_ == kSlots) return false;
        entries_[used_++] = {p, bytes};
        return true;
    }
    // The size recorded for p, removed from the table; 0 when p has none.
    size_t take(void* p) noexcept {
        const std::lock_guard lock(mutex_);
        for (size_t i = 0; i < used_; ++i)
            if (entries_[i].p == p) {
                const size_t bytes = entries_[i].bytes;
                entries_[i] = entries_[--used_];
                return bytes;
            }
        return 0;
    }

private:
    static constexpr size_t kSlots = 512;
    struct Entry {
        void* p;
        size_t bytes;
    };
    std::mutex mutex_;
    size_t used_ = 0;
    std::array<Entry, kSlots> entries_{};
};

ExactSizes g_exact;

void note_alloc(size_t bytes) {
    const size_t held = g_held.fetch_add(bytes, std::memory_order_relaxed) + bytes;
    size_t peak = g_peak.load(std::memory_order_relaxed);
    while (held > peak && !g_peak.compare_exchange_weak(peak, held, std::memory_order_relaxed)) {
    }
}

void* allocate(size_t n, size_t align) {
    if (n == 0) n = 1;
    if (align <= alignof(std::max_align_t)) {
        void* p = std::malloc(n);
        if (!p) throw std::bad_alloc();
        note_alloc(malloc_usable_size(p));
        return p;
    }
    const size_t rounded = (n + align - 1) / align * align;
    void* p = std::aligned_alloc(align, rounded);
    if (!p) throw std::bad_alloc();
    note_alloc(align > kExactAlign && g_exact.insert(p, rounded) ? rounded : malloc_usable_size(p));
    return p;
}

void release(void* p) noexcept {
    if (!p) return;
    g_held.fetch_sub(malloc_usable_size(p), std::memory_order_relaxed);
    std::free(p);
}

// Over-aligned blocks come back through the aligned deletes only.
void release_aligned(void* p, size_t align) noexcept {
    if (!p) return;
    const size_t exact = align > kExactAlign ? g_exact.take(p) : 0;
    g_held.fetch_sub(exact != 0 ? exact : malloc_usable_size(p), std::memory_order_relaxed);
    std::free(p);
}

// Page mappings the library makes itself (core/memory.h: a big node
// array), counted like heap blocks, whole, touched or not.
void note_mapped(std::ptrdiff_t delta) {
    if (delta >= 0)
        note_alloc(size_t(delta));
    else
        g_held.fetch_sub(size_t(-delta), std::memory_order_relaxed);
}

}  // namespace

namespace canopy::alloc_probe {

void start() {
    canopy::set_mapped_bytes_observer(note_mapped);
    const size_t held = g_held.load(std::memory_order_relaxed);
    g_base.store(held, std::memory_order_relaxed);
    g_peak.store(held, std::memory_order_relaxed);
}

size_t peak_since_start() {
    const size_t peak = g_peak.load(std::memory_order_relaxed), base = g_base.load(std::memory_order_relaxed);
    return peak > base ? peak - base : 0;
}

}  // namespace canopy::alloc_probe

void* operator new(size_t n) { return allocate(n, 0); }
void* operator new[](size_t n) { return allocate(n, 0); }
void* operator new(size_t n, std::align_val_t a) { return allocate(n, size_t(a)); }
void* operator new[](size_t n, std::align_val_t a) { return allocate(n, size_t(a)); }
void* operator new(size_t n, const std::nothrow_t&) noexcept {
    try {
        return allocate(n, 0);
    } catch (...) {
        return nullptr;
    }
}
void* operator new[](size_t n, const std::nothrow_t&) noexcept {
    try {
        return allocate(n, 0);
    } catch (...) {
        return nullptr;
    }
}
void operator delete(void* p) noexcept { release(p); }
void operator delete[](void* p) noexcept { release(p); }
void operator delete(void* p, size_t) noexcept { release(p); }
void operator delete[](void* p, size_t) noexcept { release(p); }
void operator delete(void* p, std::align_val_t a) noexcept { release_aligned(p, size_t(a)); }
void operator delete[](void* p, std::align_val_t a) noexcept { release_aligned(p, size_t(a)); }
void operator delete(void* p, size_t, std::align_val_t a) noexcept { release_aligned(p, size_t(a)); }
void operator delete[](void* p, size_t, std::align_val_t a) noexcept { release_aligned(p, size_t(a)); }
void operator delete(void* p, const std::nothrow_t&) noexcept { release(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { release(p); }
