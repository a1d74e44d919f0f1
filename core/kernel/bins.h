// canopy: the bins a node is binned into (per axis: a box, the largest
// primitive area, a count), and the per-worker set that holds them.
#pragma once

#include "../options.h"
#include "simd.h"

#include <array>
#include <cassert>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <new>

namespace canopy {

// Per-axis bins: the box of the primitives, their largest area (lane 3 of
// the box's hi, see MinBox::with_area()) and their count.
//
// With AVX2 a bin's count is kept in lane 3 of its box (the lo half's spare
// lane) as an integer: an update is one minimum (MinBox::counted() leaves
// that lane alone) and one integer add, instead of the minimum and a
// separate increment in memory: half the stores. Measured against separate
// counts (bench/ab/run.sh: warm sequential builds of both versions in one
// process, alternated build by build; medians of per-round ratios, several
// runs): the cow 0.96x to 0.97x as long (one run 1.005x), dragon_vrip_res2
// 0.97x (one run 1.00x), the 1M sphere 0.94x to 0.98x (one run 1.02x); in
// the reverse order old/new 1.01x to 1.04x.
// (Otherwise: counts[axis][b]. Stored bin-major instead, so that evaluate()
// could load a bin's three counts as one vector, the sequential dragon build
// took 1% to 2% longer in three alternated comparisons; why is not known.)
#if defined(__AVX2__)
#define CANOPY_PACKED_COUNTS 1
#else
#define CANOPY_PACKED_COUNTS 0
#endif
//
// The bins of axis a are base[a * stride, a * stride + bins), stride being
// the node's bin count rounded up to four (clear() sets it), in storage a
// BinSet owns: a node's bins lie together (3 KiB for 32 bins), and the
// second set of the binning of large ranges right after them. (Until
// 2026-12-05 each axis had room for kMaxBins, 8 KiB apart, and the second
// set was 24 KiB further: a node's hot bins spread over six or seven 4 KiB
// pages. On this project's virtual machine the time of the bin updates
// depended on which physical pages the bins got, stable for as long as a
// set lived: binning the same 202,520 records into twelve sets allocated
// one after another took 0.8 ms for most and 1.0 to 1.9 ms for a third of
// them, and whole sequential builds of dragon_vrip_res2 took 33 ms in some
// processes and 41 to 50 in others, the extra samples all in the bin
// updates. With the bins of a node together, 3 of 72 sets were slow (1.2
// to 1.6 ms), and 1 of 10 dragon processes. Why pages differ was not
// found: no hardware counters here. README, "Slow pages for the bins";
// the measurements in docs/performance-log.md.)
struct BinArrays {
    simd::MinBox* base = nullptr;  // (lo, -hi): see simd::MinBox
    uint32_t stride = 0;
#if !CANOPY_PACKED_COUNTS
    uint32_t* counts = nullptr;  // bin k of axis a: counts[a * stride + k]
#endif
    simd::MinBox& at(int axis, uint32_t k) { return base[size_t(axis) * stride + k]; }
    const simd::MinBox& at(int axis, uint32_t k) const { return base[size_t(axis) * stride + k]; }
    // The three axes' first bins, for the hot loops (locals stay in
    // registers, where the fields would be reloaded after every store).
    struct Axes {
        simd::MinBox* a[3];
    };
    Axes axes() const { return {{base, base + stride, base + 2 * size_t(stride)}}; }
#if CANOPY_PACKED_COUNTS
    // An empty bin: an empty box with count 0.
    static simd::MinBox empty() {
        const float inf = std::numeric_limits<float>::infinity();
        return simd::MinBox{_mm256_setr_ps(inf, inf, inf, 0.0f, inf, inf, inf, inf)};
    }
    // What add() takes for a record.
    static __m256 record(const PrimRef& x) { return simd::MinBox::counted(x); }
    // Adds `inc` records (lane 3 of inc) whose boxes' minimum is rec to bin b.
    static void add(simd::MinBox& b, __m256 rec, __m256i inc) {
        b.v = _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(_mm256_min_ps(rec, b.v)), inc));
    }
    static __m256i one() { return _mm256_setr_epi32(0, 0, 0, 1, 0, 0, 0, 0); }
    // Merges bin `from` into bin `into`: the boxes' minimum, lane 3 the
    // counts' sum.
    static void merge_bin(simd::MinBox& into, const simd::MinBox& from) {
        const __m256 x = from.v, y = into.v;
        const __m256 sum = _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(x), _mm256_castps_si256(y)));
        into.v = _mm256_blend_ps(_mm256_min_ps(y, x), sum, 0x08);
    }
    // Adds a record (record()) to bin k of an axis.
    void add(int axis, int32_t k, __m256 rec) { add(at(axis, uint32_t(k)), rec, one()); }
    uint32_t count(int axis, uint32_t b) const {
        return uint32_t(_mm_extract_epi32(_mm_castps_si128(_mm256_castps256_ps128(at(axis, b).v)), 3));
    }
    void set_count(int axis, uint32_t b, uint32_t n) {  // for tests
        simd::MinBox& x = at(axis, b);
        const __m128i lo = _mm_insert_epi32(_mm_castps_si128(_mm256_castps256_ps128(x.v)), int(n), 3);
        x.v = _mm256_insertf128_ps(x.v, _mm_castsi128_ps(lo), 0);
    }
    // Bin b's counts on the three axes, (x, y, z, 0).
    __m128i count_row(uint32_t b) const {
        const __m128 x = _mm256_castps256_ps128(at(0, b).v), y = _mm256_castps256_ps128(at(1, b).v),
                     z = _mm256_castps256_ps128(at(2, b).v);
        // (x3, y3, z3, 0) from (x2, y2, x3, y3) and (z2, 0, z3, 0).
        return _mm_castps_si128(_mm_movehl_ps(_mm_unpackhi_ps(z, _mm_setzero_ps()), _mm_unpackhi_ps(x, y)));
    }
#else
    static simd::MinBox empty() { return simd::MinBox{}; }
    static auto record(const PrimRef& x) { return simd::MinBox::with_area(x); }
    template <class Rec>  // record()
    void add(int axis, int32_t k, const Rec& rec) {
        at(axis, uint32_t(k)).grow(rec);
        counts[size_t(axis) * stride + uint32_t(k)]++;
    }
    uint32_t count(int axis, uint32_t b) const { return counts[size_t(axis) * stride + b]; }
    void set_count(int axis, uint32_t b, uint32_t n) { counts[size_t(axis) * stride + b] = n; }
#endif

    Box box(int axis, uint32_t b) const { return at(axis, b).box4().box(); }
    // Empties the first `bins` bins of each axis (and up to the next
    // multiple of 4) and sets the stride for them.
    void clear(uint32_t bins) {
        // Four bins at a time: most nodes have 4 bins; std::fill_n became a
        // memset call per axis for the counts and a loop of one box per turn
        // for the boxes.
        static_assert(kMaxBins % 4 == 0);
        stride = (bins + 3) & ~3u;
        const simd::MinBox none = empty();
        simd::MinBox* const b = base;
        for (uint32_t i = 0; i < 3 * stride; i += 4) {
            b[i] = b[i + 1] = b[i + 2] = b[i + 3] = none;
#if !CANOPY_PACKED_COUNTS
            _mm_storeu_si128(reinterpret_cast<__m128i*>(counts + i), _mm_setzero_si128());
#endif
        }
    }
    // The same for the axes `axes` only (the others keep what they hold).
    using AxisSet = std::array<bool, 3>;
    static constexpr AxisSet kAllAxes{true, true, true};
    void clear(uint32_t bins, const AxisSet& axes) {
        stride = (bins + 3) & ~3u;
        const simd::MinBox none = empty();
        simd::MinBox* const b = base;
        for (uint32_t i = 0; i < 3 * stride; i += 4) {
            if (!axes[i / stride]) continue;
            b[i] = b[i + 1] = b[i + 2] = b[i + 3] = none;
#if !CANOPY_PACKED_COUNTS
            _mm_storeu_si128(reinterpret_cast<__m128i*>(counts + i), _mm_setzero_si128());
#endif
        }
    }
    // Exact merge (min/max and integer sums): order-independent. Both sets
    // cleared for the same bins (on `axes`, which alone are merged).
    void merge(const BinArrays& o, uint32_t bins, const AxisSet& axes = kAllAxes) {
        assert(o.stride == stride && bins <= stride);
        for (int a = 0; a < 3; ++a)
            for (uint32_t b = 0; b < bins && axes[a]; ++b) {
#if CANOPY_PACKED_COUNTS
                merge_bin(at(a, b), o.at(a, b));
#else
                at(a, b).grow(o.at(a, b));
                counts[size_t(a) * stride + b] += o.counts[size_t(a) * o.stride + b];
#endif
            }
    }
};

// bin() goes over the records in blocks of this many (see there).
inline constexpr uint32_t kBinBlock = 64;

// The bins a node is binned into, with a second set (odd) that bin() uses as
// scratch for large ranges (see there); only the first set is the result.
// `index` holds the bin indices (one lane per axis) of the last block of
// records that bin() went over: for a node of at most kBinBlock records,
// those of all its records, which partition_binned() reuses. Room for up to
// `max_bins` bins per axis (clear() no more) in each set; the first set's
// bins lie after `index`, the second's right after them (second()), all in
// one block the set owns. Not copyable: the sets point into the block.
// A build makes its sets for the most bins its root uses (bins_for(n,
// bins); 32 by default below kWideBinsMin primitives: 6 KiB of boxes, not
// the 48 KiB of kMaxBins, which with a set per worker were 2 to 3 bytes per
// triangle of the peak memory of 2-thread builds of 33,000 to 50,000
// triangles). With the bins in an allocation of their own, apart from
// `index` (until then both were arrays of the object), 2-thread builds of
// 1M random triangles took 1.02x as long (alternated, 2026-12-05).
struct BinSet : BinArrays {
    BinArrays odd;
    int32_t (*index)[4] = nullptr;  // kBinBlock rows

    explicit BinSet(uint32_t max_bins = kMaxBins)  // clear() before use
        : capacity((std::min(max_bins, kMaxBins) + 3) & ~3u), block(allocate(capacity)) {
        index = reinterpret_cast<int32_t(*)[4]>(block.get());
        base = reinterpret_cast<simd::MinBox*>(block.get() + kIndexBytes);
        std::uninitialized_default_construct_n(base, 6 * size_t(capacity));
        stride = capacity;
#if !CANOPY_PACKED_COUNTS
        counts = reinterpret_cast<uint32_t*>(base + 6 * size_t(capacity));
#endif
    }
    BinSet(const BinSet&) = delete;
    BinSet& operator=(const BinSet&) = delete;
    // The second set, cleared, right after the first set's bins and with
    // their stride (the first set cleared for at least `bins` bins).
    // With `axes`, only those axes' bins are cleared.
    BinArrays& second(uint32_t bins, const AxisSet& axes = kAllAxes) {
        assert(bins <= stride && stride <= capacity);
        (void)bins;
        odd.base = base + 3 * size_t(stride);
#if !CANOPY_PACKED_COUNTS
        odd.counts = counts + 3 * size_t(stride);
#endif
        odd.clear(stride, axes);
        return odd;
    }
    // Bins per axis it has room for (a multiple of 4).
    uint32_t max_bins() const { return capacity; }

private:
    static constexpr size_t kIndexBytes = sizeof(int32_t[kBinBlock][4]);
    static constexpr std::align_val_t kAlign{64};
    struct Free {
        void operator()(std::byte* p) const { ::operator delete(p, kAlign); }
    };
    static std::byte* allocate(uint32_t capacity) {
        size_t bytes = kIndexBytes + 6 * size_t(capacity) * sizeof(simd::MinBox);
#if !CANOPY_PACKED_COUNTS
        bytes += 6 * size_t(capacity) * sizeof(uint32_t);
#endif
        return static_cast<std::byte*>(::operator new(bytes, kAlign));
    }
    uint32_t capacity;
    std::unique_ptr<std::byte, Free> block;
};

}  // namespace canopy
