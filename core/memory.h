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
#include <cstddef>
#include <vector>

namespace canopy {

// Asks the kernel for transparent huge pages on the 2 MiB-aligned interior of
// [p, p + bytes), to take effect for pages not touched yet. Best effort: a
// no-op for arrays under 4 MiB, outside Linux, or when the kernel declines
// (huge pages disabled). Never changes the memory's contents.
void advise_huge_pages(void* p, std::size_t bytes) noexcept;

// Reserves room for n elements in `v` and advises huge pages on it, before
// anything touches that memory.
template <class T>
void reserve_on_huge_pages(std::vector<T>& v, std::size_t n) {
    v.reserve(n);
    advise_huge_pages(v.data(), v.capacity() * sizeof(T));
}

// Doubles v's capacity (at least one more element) on memory advised for
// huge pages before the elements are copied in. (std::vector's own growth
// copies them into fresh memory at once, before any advice can be given:
// the sequential build of 1M random triangles, whose tree outgrows its
// reservation, then faulted 70 MB in 4 KiB pages.)
template <class T>
void grow_on_huge_pages(std::vector<T>& v) {
    std::vector<T> bigger;
    reserve_on_huge_pages(bigger, std::max<std::size_t>(2 * v.capacity(), v.size() + 1));
    bigger.insert(bigger.end(), v.begin(), v.end());
    v.swap(bigger);
}

}  // namespace canopy
