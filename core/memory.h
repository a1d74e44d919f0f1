// canopy: backing a build's big arrays with huge pages.
//
// A build writes about 100 bytes per primitive into memory it has just
// allocated. Fresh memory arrives one 4 KiB page at a time, each page a
// fault, and on virtual machines a fault can cost about 10 microseconds: at
// 1M triangles (25,000 pages) that was most of a build's time on this
// project's machine. Linux backs an address range with 2 MiB transparent
// huge pages when asked to (madvise; the transparent_hugepage mode that
// many distributions ship), one fault per 2 MiB.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <memory>
#include <utility>
#include <vector>

namespace canopy {

// Asks the kernel for transparent huge pages on the 2 MiB-aligned interior of
// [p, p + bytes), to take effect for pages not touched yet. Best effort: a
// no-op when that interior is empty, outside Linux, or when the kernel
// declines (huge pages disabled). Never changes the memory's contents.
// Returns whether the kernel took the advice (false for an empty interior).
bool advise_huge_pages(void* p, std::size_t bytes) noexcept;

// Memory for a big array that starts on a 2 MiB boundary, advised for huge
// pages: from kHugeAllocMin bytes on, rounded up to whole 2 MiB, so that all
// of it can be huge pages (a placement buffer of 3.7 MB with a partial last
// one took 454 faults a build, 2026-12-06). (An array from plain operator
// new starts wherever malloc's mapping puts it, just past a 4 KiB page
// boundary, and only its 2 MiB-aligned interior can have huge pages; the
// rest faults in 4 KiB pages. On this project's virtual machine (2026-12-03)
// touching 512 MiB took 32 ms in huge pages and 1,300 ms in 4 KiB pages,
// about 10 microseconds a fault.) Smaller arrays come from plain operator
// new. release_huge() takes the same byte count as allocate_huge() was
// given.
//
// Used for the parallel drivers' node chunks (NodeChunk). The records array
// (RawArray) stays on plain operator new: 2 MiB-aligned, the 1M sphere's
// 2-thread tbb build took longer (alternated pairs, medians of 9: 95 to
// 110 ms against 89 to 95; why was not found). malloc_usable_size() of
// such an allocation includes up to 2 MiB of alignment padding that is
// mapped but never touched, so the heap probe of `canopy build --json`
// counts it.
inline constexpr std::size_t kHugeAllocMin = std::size_t(2) << 20;
void* allocate_huge(std::size_t bytes);
void release_huge(void* p, std::size_t bytes) noexcept;

// A standard allocator over allocate_huge() (the finished Bvh's permutation
// uses plain operator new, core/bvh.h's PrimitiveOrder, and its node array
// a NodeArray, core/node_array.h).
template <class T>
struct HugePageAllocator {
    using value_type = T;
    HugePageAllocator() = default;
    template <class U>
    HugePageAllocator(const HugePageAllocator<U>&) noexcept {}
    T* allocate(std::size_t n) { return static_cast<T*>(allocate_huge(n * sizeof(T))); }
    void deallocate(T* p, std::size_t n) noexcept { release_huge(p, n * sizeof(T)); }
    template <class U>
    bool operator==(const HugePageAllocator<U>&) const noexcept { return true; }
};

// Reserves room for n elements in `v` and advises huge pages on it, before
// anything touches that memory.
template <class T, class A>
void reserve_on_huge_pages(std::vector<T, A>& v, std::size_t n) {
    v.reserve(n);
    advise_huge_pages(v.data(), v.capacity() * sizeof(T));
}

// Page mappings of their own, for arrays that must grow without holding
// their old and their new memory at once (NodeArray, core/node_array.h). A
// mapping is the first `bytes` (readable and writable) of a reservation of
// address space twice as big (inaccessible, so never backed by memory),
// starting on a 2 MiB boundary and advised for huge pages as a whole: it
// grows in place by making more of its reservation accessible. Past the
// reservation it moves into a new one of the same alignment with mremap(),
// which moves page tables, not bytes, and moves huge pages whole. (A first
// version let mremap() grow a plain mapping wherever it liked: it moved
// every time, to an address with another offset from a 2 MiB boundary,
// which splits huge pages, and the 2-thread builds of 4M random triangles
// took 1.11 times as long as with a fresh array beside the storage.)
// Each call throws std::bad_alloc when the kernel refuses.
//
// The heap probe of `canopy build --json` counts operator new; mappings
// are not made through it, so every change in a mapping's accessible bytes
// is reported to the observer set here (tools/alloc_probe.cpp sets one),
// touched or not; the reservation beyond them costs address space only.
// The observer is called from the thread that maps, without a lock; it must
// be thread-safe.
using MappedBytesObserver = void (*)(std::ptrdiff_t delta);
void set_mapped_bytes_observer(MappedBytesObserver observer) noexcept;
// Whether this system has such mappings (Linux); without them NodeArray
// keeps to operator new.
bool growable_mappings_available() noexcept;

struct PageMapping {
    void* p = nullptr;
    std::size_t bytes = 0;      // accessible, a whole number of pages
    std::size_t reserved = 0;   // address space from p on
    std::size_t discarded = 0;  // of `bytes`, given back by discard_pages()
    bool huge = false;          // advised for huge pages: `bytes` a whole number of them
};
// At least `bytes` accessible, rounded up to whole pages: of 2 MiB when
// `huge` and `bytes` is kWholeHugeMin or more, so that the mapping does not
// end in a piece of a huge page, which the kernel fills with 4 KiB pages a
// fault at a time (on the AMD EPYC host of 2026-12-06 a 4 KiB fault took
// about 10 us, and the last 1.6 MiB of the records' storage of 1M
// triangles made 400 of them a build; a whole huge page costs up to 2 MiB
// more, counted, which below 32 MiB would be a sizeable part). In a reservation
// of at least `reserve` bytes (twice `bytes` if more). `counted` false: the
// caller reports the mapping's bytes itself (report_mapped_bytes(), e.g.
// through a PageLedger as it writes them), all of them before the mapping
// is unmapped.
// `huge` false: advised against huge pages instead (memory written sparsely,
// whose count must follow its 4 KiB pages).
inline constexpr std::size_t kWholeHugeMin = std::size_t(32) << 20;
PageMapping map_pages(std::size_t bytes, std::size_t reserve = 0, bool counted = true, bool huge = true);
// Makes at least `bytes` accessible (rounded up as map_pages() rounds),
// keeping the contents; m.p may change.
void grow_pages(PageMapping& m, std::size_t bytes);
// Gives the whole pages inside [offset, offset + bytes) of the mapping back
// to the system (their contents are gone; they read as zeros if touched
// again, which the caller must not do: they are no longer counted) and
// reports them; returns the bytes given back.
// `report` false: for mappings counted by a PageLedger.
std::size_t discard_pages(PageMapping& m, std::size_t offset, std::size_t bytes, bool report = true) noexcept;
// Brings in for writing the pages that [p, p + bytes) touches, in one
// system call (madvise MADV_POPULATE_WRITE, Linux 5.14 and later), instead of
// one page fault for each 4 KiB page as it is first written: zeroed pages
// either way, at about half the cost (32 MiB of 4 KiB pages in 100 KiB
// steps, AMD EPYC host, 2026-12-05: 3.1 to 3.6 ms against 6.9 to 7.8). The
// pages must be ones the caller is about to write. Does nothing where the
// system cannot (the writes then fault as usual).
void populate_pages(void* p, std::size_t bytes) noexcept;
// Moves the pages of [offset, offset + bytes) of the mapping to `to` (a
// range of another mapping, whose pages there are replaced), page tables
// only, nothing copied or zeroed (mremap, MREMAP_DONTUNMAP: the range stays
// mapped here, empty); counted as given back here (the caller counts them
// where they went). Whole huge pages move whole when both ranges are
// 2 MiB-aligned. Returns false, changing nothing, where the system cannot.
// `report` false: for mappings counted by a PageLedger.
bool move_pages(PageMapping& m, std::size_t offset, void* to, std::size_t bytes, bool report = true) noexcept;
// Reports the accessible bytes that were not discarded as given back.
void unmap_pages(PageMapping& m) noexcept;
// Reports `delta` bytes to the observer (for mappings made uncounted).
void report_mapped_bytes(std::ptrdiff_t delta) noexcept;

// The count of an uncounted mapping's bytes (map_pages(..., false)), kept
// in units of `unit` bytes: a unit is reported when it is first written
// (touch(), whichever thread comes first; on huge pages a unit of 2 MiB,
// which a first write brings in whole) and reported as given back when it
// is released (release()). `active` false (heap memory, which the heap
// probe counts): reports nothing. The owner settles the rest before the
// mapping goes: count_untouched() for memory that is handed on whole (a
// NodeArray then unmaps it, reporting all its bytes as given back), or
// release_counted() for memory that goes with its owner.
class PageLedger {
public:
    PageLedger() = default;
    PageLedger(std::size_t bytes, std::size_t unit, bool active);
    // Bytes [from, to) are about to be written.
    void touch(std::size_t from, std::size_t to) noexcept;
    // Marks the units wholly inside [from, to) released (reporting those
    // counted as given back; a range reaching the end takes the last unit,
    // whole or not) and returns their byte range, empty if none, for the
    // caller to give back (discard_pages(..., false)).
    std::pair<std::size_t, std::size_t> release(std::size_t from, std::size_t to) noexcept;
    void count_untouched() noexcept;
    // Whether the unit holding byte `at` is neither counted nor released.
    bool untouched(std::size_t at) const noexcept {
        return at < bytes_ && state_[at / unit_].load(std::memory_order_relaxed) == 0;
    }
    void release_counted() noexcept;

private:
    std::size_t bytes_ = 0, unit_ = 1, units_ = 0;
    std::unique_ptr<std::atomic<unsigned char>[]> state_;  // 0 untouched, 1 counted, 2 released
};

}  // namespace canopy
