// canopy: step 3 of the node task, the partition: the records of a node
// reordered in place around its split, the children's bounds grown on the
// way.
//
// The canonical partition is in place and swaps misplaced records in pairs:
// the k-th record of the left part that goes right trades places with the
// k-th record of the right part that goes left (see partition()). The pairs
// depend only on each record's side, so a team-parallel node that finds the
// sides by chunks reproduces the result bit for bit (team_partition.h).
#pragma once

#include "bin_mapper.h"
#include "bins.h"
#include "evaluate.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cstdint>
#include <type_traits>

namespace canopy {

// The largest area a box grown with simd::hi_area() has seen (0 if none).
inline float max_area_of(const simd::Box4& b) { return std::max(0.0f, simd::lane3(b.hi)); }

// Child bounds, centroid bounds and largest areas, accumulated while
// partitioning. `hi_area` is simd::hi_area() of the record.
struct ChildBounds4 {
    simd::Box4 bounds[2], cbounds[2];  // [0] left, [1] right
    void add(int side, __m128 lo, __m128 hi_area, __m128 c) {
        bounds[side].grow(lo, hi_area);
        cbounds[side].grow(c, c);
    }
    void merge(const ChildBounds4& o) {
        for (int k = 0; k < 2; ++k) {
            bounds[k].grow(o.bounds[k]);
            cbounds[k].grow(o.cbounds[k]);
        }
    }
};

// What a partition (or a middle split) leaves: where the right child starts,
// and both children's bounds and centroid bounds, accumulated on the way.
// Kept as the accumulators' vectors until emit() writes the children: a
// partition returns this through memory, and vectors stored and loaded
// whole forward from store to load, where boxes of three-float corners
// copied in 16-byte pieces did not (a stall after every partition).
struct PartitionResult {
    ChildBounds4 acc;
    uint32_t mid = 0;

    Box left_bounds() const { return acc.bounds[0].box(); }
    Box right_bounds() const { return acc.bounds[1].box(); }
    Box left_cbounds() const { return acc.cbounds[0].box(); }
    Box right_cbounds() const { return acc.cbounds[1].box(); }
    float left_max_area() const { return max_area_of(acc.bounds[0]); }
    float right_max_area() const { return max_area_of(acc.bounds[1]); }
    void merge(const PartitionResult& o) { acc.merge(o.acc); }  // for blocked partitions
};

// The bin index of a centroid coordinate on one axis never decreases as the
// coordinate grows (a subtraction, two multiplications by positive numbers,
// a clamp and a truncation, each monotone in IEEE arithmetic). So the
// centroids below split index k on an axis are exactly those whose
// coordinate is below one float: the smallest float whose index is at
// least k. Found from an estimate by stepping to neighbouring floats with
// the mapping itself, or, should the estimate be far off, by a bisection
// over the floats in their order.
inline float split_threshold(const BinMapper& m, int axis, uint32_t k) {
    const auto index = [&](float c) {
        Vec3 v = m.origin;
        v[axis] = c;
        return m.index(v, axis);
    };
    // Floats in their order as unsigned integers (-0 just below +0), and
    // back: neighbouring floats are neighbouring keys.
    const auto key = [](float f) {
        const uint32_t u = std::bit_cast<uint32_t>(f);
        return (u >> 31) ? ~u : (u | 0x80000000u);
    };
    const auto from_key = [](uint32_t q) { return std::bit_cast<float>((q >> 31) ? (q & 0x7FFFFFFFu) : ~q); };
    constexpr float kMax = std::numeric_limits<float>::max();
    const double step = double(m.scale[axis]) * double(m.prescale[axis]);
    const double estimate = double(m.origin[axis]) + double(k) / step;
    if (std::abs(estimate) < double(kMax)) {
        uint32_t q = key(static_cast<float>(estimate));
        for (int i = 0; i < 8; ++i) {
            if (index(from_key(q)) < k) {
                ++q;
            } else if (index(from_key(q - 1)) >= k) {
                --q;
            } else {
                return from_key(q);
            }
        }
    }
    // Bisection over the finite floats.
    uint32_t lo = key(-kMax), hi = key(kMax);
    while (lo < hi) {  // the smallest key in [lo, hi] whose float has index >= k
        const uint32_t mid = lo + (hi - lo) / 2;
        if (index(from_key(mid)) >= k)
            hi = mid;
        else
            lo = mid + 1;
    }
    return from_key(lo);
}

// The side test of a plane split in registers: the centroid's bin indices on
// all axes compared with the split index at once, the split axis's lane
// taken from the sign mask (no trip through memory). Pre: the mapping's
// prescale is applied (needed only when m.prescaled, see BinMapper).
template <bool Pre = true>
struct SideIndexTest {
    const BinMapper& m;
    __m128i index4;
    int axis;
    SideIndexTest(const BinMapper& mapper, const Split& s)
        : m(mapper), index4(_mm_set1_epi32(int32_t(s.index))), axis(s.axis) {}
    bool left(__m128 c, __m128 /*hi_area*/) const {
        const __m128i lt = _mm_cmplt_epi32(m.template indices4<Pre>(c), index4);
        return (_mm_movemask_ps(_mm_castsi128_ps(lt)) >> axis) & 1;
    }
#if defined(__AVX2__)
    // left() of eight records, from their centroids' coordinates on the
    // split axis (the same operations on that lane): bit k for c[k].
    uint32_t left8(__m256 c) const {
        const auto lane = [&](__m128 v) { return _mm256_set1_ps(simd::lane(v, axis)); };
        __m256 f = _mm256_sub_ps(c, lane(m.origin4));
        if constexpr (Pre) f = _mm256_mul_ps(f, lane(m.prescale4));
        f = _mm256_mul_ps(f, lane(m.scale4));
        f = _mm256_min_ps(_mm256_max_ps(f, _mm256_setzero_ps()), lane(m.last4));
        const __m256i lt = _mm256_cmpgt_epi32(_mm256_set1_epi32(_mm_cvtsi128_si32(index4)), _mm256_cvttps_epi32(f));
        return uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(lt)));
    }
#endif
};

// The same side as SideIndexTest, found by comparing the centroid's
// coordinate on the split axis with split_threshold(): one comparison
// instead of the index computation, for a few steps of the mapping per
// node, so partition() uses it from kThresholdTestMin records on. Measured
// (sequential, alternated runs, medians of 5 to 7): 1M sphere 0.96x to 0.98x
// as long, dragon_vrip_res2 the same within noise (used from 65 records
// on, it was 1.03x on the dragon, which has many mid-sized nodes).
inline constexpr uint32_t kThresholdTestMin = 256;
struct SideTest {
    __m128 threshold4;
    int axis;
    SideTest(const BinMapper& m, const Split& s)
        : threshold4(_mm_set1_ps(split_threshold(m, s.axis, s.index))), axis(s.axis) {}
    bool left(__m128 c, __m128 /*hi_area*/) const {
        return (_mm_movemask_ps(_mm_cmplt_ps(c, threshold4)) >> axis) & 1;
    }
#if defined(__AVX2__)
    uint32_t left8(__m256 c) const {
        return uint32_t(_mm256_movemask_ps(_mm256_cmp_ps(c, _mm256_set1_ps(_mm_cvtss_f32(threshold4)), _CMP_LT_OQ)));
    }
#endif
};

// The side of a plane split read from the bin keys bin() wrote (keys[i]
// for refs[i]): the split axis's byte compared with the split index. The
// same indices as evaluate() counted, so the same sides as SideIndexTest
// and SideTest. Eight records a step from 32 bytes of keys, where SideTest
// gathers the split axis's coordinates from 512 bytes of records and forms
// their centroids. A partition by keys (partition_by_keys(), and the
// team-parallel node's) reads no record but the misplaced ones it swaps:
// the children's bounds come from the bins (bounds_from_bins()).
// run_node() and the team-parallel node keep the keys in the permutation's
// slots of the node's range (free until the node's leaves write them).
struct KeyTest {
    const uint32_t* keys;
    const PrimRef* refs;
    uint32_t shift;  // 8 * the split axis
    uint32_t index;
    KeyTest(const uint32_t* k, const PrimRef* r, const Split& s)
        : keys(k), refs(r), shift(8 * uint32_t(s.axis)), index(s.index) {}
    bool left_at(const uint32_t* q) const { return ((*q >> shift) & 0xFFu) < index; }
};

// The side test of a size split: primitives whose area is below the cut go
// left, the large ones right.
struct SizeTest {
    __m128 cut4;
    explicit SizeTest(const Split& s) : cut4(_mm_set1_ps(s.size_cut)) {}
    bool left(__m128 /*c*/, __m128 hi_area) const {
        return (_mm_movemask_ps(_mm_cmplt_ps(hi_area, cut4)) >> 3) & 1;
    }
};

// Calls f with the split's side test (one dispatch per node, not per record).
// With keys (bin() wrote them for refs), a plane split's sides are read from
// them (KeyTest, which grows no bounds: the caller takes the children's
// bounds from the bins).
template <class F>
decltype(auto) with_side_test(const BinMapper& m, const Split& s, const uint32_t* keys, const PrimRef* refs,
                              F&& f) {
    if (s.by_size()) return f(SizeTest(s));
    if (keys) return f(KeyTest(keys, refs, s));
    return f(SideTest(m, s));
}
// Without keys. (Not a call of the one above with null keys: that would
// instantiate f for KeyTest too, which callers like goes_left() cannot take.)
template <class F>
decltype(auto) with_side_test(const BinMapper& m, const Split& s, F&& f) {
    if (s.by_size()) return f(SizeTest(s));
    return f(SideTest(m, s));
}

inline bool goes_left(const PrimRef& r, const BinMapper& m, const Split& s) {
    return with_side_test(m, s, [&](const auto& side) {
        return side.left(simd::centroid(simd::lo(r), simd::hi(r)), simd::hi_area(r));
    });
}

// Step 3: the partition, in place. With mid = begin + the split's
// left_count, the records of [begin, mid) that go right and the records of
// [mid, end) that go left are equally many; the k-th of the first (in
// position order) trades places with the k-th of the second, and every other
// record stays where it is. Child bounds are accumulated in the same pass.
// The result depends only on which side each record goes to, not on the
// order in which the sides are found, so a team-parallel node reproduces it
// bit for bit from side bits found by chunks (see mark_sides() and
// swap_misplaced() in team_partition.h).
//
// In place, the records need one buffer: until 2026-12-02 the partition was
// the stable one, written to a second buffer of the same size (32 more bytes
// per primitive at the peak of a build). In alternated sequential runs the
// in-place version took the same time on the 1M sphere and up to 3% longer
// on `dragon_vrip_res2` and the bunny; it writes only the misplaced records.
//
// Sides are found 64 records at a time, as a bit mask, without a branch; the
// child bounds are then grown over the mask's set bits and over its clear
// bits, and the misplaced pairs swapped. A branch per record on its side,
// as the first version had, mispredicts wherever neighbouring records go
// different ways: on `dragon_vrip_res2` an estimated 15% of the build went
// to them, and the mask made the sequential build 0.81x as long (bunny
// 0.77x, 1M random triangles 0.71x; the 1M sphere 1.02x).
inline constexpr uint32_t kSideBlock = 64;

// Bit k set: record r[k] goes left (n <= kSideBlock). No branch. With
// KeyTest from the records' keys, eight at a time (the records are not read).
//
// With AVX2, a whole block of a plane split takes the split axis's
// coordinates of eight records at a time (their lo and hi lanes loaded into
// one vector each), forms those centroid coordinates with the operations of
// simd::centroid() and tests eight at once (left8). Against one record's
// full centroid per step (warm sequential builds, alternated pairs, medians
// of 9): dragon_vrip_res2 0.984x as long. Gathers instead of the loads were
// slower (1M sphere 1.036x).
template <class Test>
uint64_t left_mask(const PrimRef* r, uint32_t n, const Test& side) {
    if constexpr (std::is_same_v<Test, KeyTest>) {
        const uint32_t* q = side.keys + (r - side.refs);
        uint64_t mask = 0;
        uint32_t k = 0;
#if defined(__AVX2__)
        const __m128i shift = _mm_cvtsi32_si128(int(side.shift));
        const __m256i byte = _mm256_set1_epi32(0xFF), index = _mm256_set1_epi32(int32_t(side.index));
        for (; k + 8 <= n; k += 8) {
            const __m256i v = _mm256_and_si256(
                _mm256_srl_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(q + k)), shift), byte);
            mask |= uint64_t(uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(index, v))))) << k;
        }
#endif
        for (; k < n; ++k) mask |= uint64_t(side.left_at(q + k)) << k;
        return mask;
    } else {
#if defined(__AVX2__)
        if constexpr (!std::is_same_v<Test, SizeTest>) {
            if (n == kSideBlock) {
                const __m256 half = _mm256_set1_ps(0.5f);
                const float* base = &r[0].lo.x + side.axis;
                uint64_t mask = 0;
                for (uint32_t j = 0; j < kSideBlock / 8; ++j) {
                    const float* q = base + 64 * j;
                    const __m256 lo = _mm256_setr_ps(q[0], q[8], q[16], q[24], q[32], q[40], q[48], q[56]);
                    const __m256 hi = _mm256_setr_ps(q[4], q[12], q[20], q[28], q[36], q[44], q[52], q[60]);
                    const __m256 c = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(lo, half), _mm256_mul_ps(hi, half)),
                                                   _mm256_setzero_ps());
                    mask |= uint64_t(side.left8(c)) << (8 * j);
                }
                return mask;
            }
        }
#endif
        uint64_t mask = 0;
        for (uint32_t k = 0; k < n; ++k)
            mask |= uint64_t(side.left(simd::centroid(simd::lo(r[k]), simd::hi(r[k])), simd::hi_area(r[k]))) << k;
        return mask;
    }
}
inline uint64_t block_bits(uint32_t n) { return n >= 64 ? ~uint64_t(0) : (uint64_t(1) << n) - 1; }

// Grows side `Side` of `acc` (a constant side, so the accumulators stay in
// registers) with the records of block r whose bits are set.
//
// Every other record goes into a second pair of accumulators, merged at the
// end, so that each minimum and maximum waits on the one two records back,
// not on the previous one. The result is the same bits: minima and maxima
// do not depend on order here (the records hold no NaN, and prepare made
// every -0 +0). Warm sequential builds, alternated pairs, medians of 7:
// 1M sphere 0.979x as long, dragon_vrip_res2 0.980x.
//
// With AVX2, two records at a time: each record is one 256-bit load (lo, id,
// hi, area), two records' lo halves and hi halves are paired into one
// vector each, and one minimum or maximum grows both records' boxes and
// centroid boxes (lane for lane the operations of simd::centroid(), so the
// same bits; the halves are folded at the end). About 7 vector operations
// a record instead of 12. bench/ab/run.sh on the Intel Xeon host of
// 2026-12-04, against the loop below (9 rounds of 5 warm sequential builds,
// two runs): 1M sphere 0.955x as long, 1M stadium 0.97x, 1M random 0.97x,
// dragon_vrip_res2 0.965x and 0.98x, the cow 0.99x. (An AVX-512 version,
// two records per 512-bit vector with masked minima, took 1.00x-1.04x as long
// on the AMD EPYC host on 2026-12-04 morning; this one was not measured
// there.)
template <int Side>
inline void grow_side(const PrimRef* r, uint64_t bits, ChildBounds4& acc) {
    const auto one = [&](const PrimRef& x, ChildBounds4& into) {
        const __m128 lo = simd::lo(x);
        into.add(Side, lo, simd::hi_area(x), simd::centroid(lo, simd::hi(x)));
    };
#if defined(__AVX2__)
    const __m256 keep = simd::xyz_mask2();
    __m256 bmin = _mm256_set1_ps(std::numeric_limits<float>::infinity());
    __m256 bmax = _mm256_set1_ps(-std::numeric_limits<float>::infinity());
    __m256 cmin = bmin, cmax = bmax;
    for (; bits & (bits - 1); bits &= bits - 1) {
        const __m256 va = _mm256_load_ps(&r[std::countr_zero(bits)].lo.x);
        bits &= bits - 1;
        const __m256 vb = _mm256_load_ps(&r[std::countr_zero(bits)].lo.x);
        const __m256 lo2 = _mm256_and_ps(_mm256_permute2f128_ps(va, vb, 0x20), keep);  // (lo a, lo b)
        const __m256 ha2 = _mm256_permute2f128_ps(va, vb, 0x31);                        // (hi a, hi b), areas
        const __m256 c2 = simd::centroid2(lo2, _mm256_and_ps(ha2, keep));
        bmin = _mm256_min_ps(bmin, lo2);
        bmax = _mm256_max_ps(bmax, ha2);
        cmin = _mm256_min_ps(cmin, c2);
        cmax = _mm256_max_ps(cmax, c2);
    }
    if (bits) one(r[std::countr_zero(bits)], acc);
    const auto lo128 = [](__m256 v) { return _mm256_castps256_ps128(v); };
    const auto hi128 = [](__m256 v) { return _mm256_extractf128_ps(v, 1); };
    acc.bounds[Side].grow(_mm_min_ps(lo128(bmin), hi128(bmin)), _mm_max_ps(lo128(bmax), hi128(bmax)));
    acc.cbounds[Side].grow(_mm_min_ps(lo128(cmin), hi128(cmin)), _mm_max_ps(lo128(cmax), hi128(cmax)));
#else
    ChildBounds4 second;
    for (; bits; bits &= bits - 1) {
        one(r[std::countr_zero(bits)], acc);
        bits &= bits - 1;
        if (!bits) break;
        one(r[std::countr_zero(bits)], second);
    }
    acc.merge(second);
#endif
}

// The side mask of a block of n <= kSideBlock records, with their bounds
// grown into the side each goes to.
// (KeyTest: the mask alone, see there.)
template <class Test>
inline uint64_t mark_block(const PrimRef* r, uint32_t n, const Test& side, ChildBounds4& acc) {
    if constexpr (std::is_same_v<Test, KeyTest>) {
        return left_mask(r, n, side);
    } else {
        const uint64_t left = left_mask(r, n, side);
        grow_side<0>(r, left, acc);
        grow_side<1>(r, ~left & block_bits(n), acc);
        return left;
    }
}

inline void swap_refs(PrimRef& a, PrimRef& b) {
    const __m128 a0 = _mm_load_ps(&a.lo.x), a1 = _mm_load_ps(&a.hi.x);
    const __m128 b0 = _mm_load_ps(&b.lo.x), b1 = _mm_load_ps(&b.hi.x);
    _mm_store_ps(&a.lo.x, b0);
    _mm_store_ps(&a.hi.x, b1);
    _mm_store_ps(&b.lo.x, a0);
    _mm_store_ps(&b.hi.x, a1);
}

inline PartitionResult result_of(const ChildBounds4& acc, uint32_t mid) { return PartitionResult{acc, mid}; }

// The partition of one block refs[b, e) (at most kSideBlock records) whose
// sides are `left`, with left part [b, mid): the left part is the mask's
// low bits.
inline PartitionResult partition_block(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e, uint64_t left) {
    ChildBounds4 acc;
    PrimRef* r = refs + b;
    grow_side<0>(r, left, acc);
    grow_side<1>(r, ~left & block_bits(e - b), acc);
    const uint64_t low = block_bits(mid - b);
    for (uint64_t mi = ~left & low, mj = left & ~low; mi; mi &= mi - 1, mj &= mj - 1)
        swap_refs(r[std::countr_zero(mi)], r[std::countr_zero(mj)]);
    return result_of(acc, mid);
}

// A keyed partition (KeyTest) reads a block's keys, not its records, and
// then swaps its misplaced records: nothing brings those records' lines in
// ahead of the swaps, and the lines of a big node are in no cache of this
// core when another core read them last (the team's binning of a node, or
// the parent's partition on another thread). In a 2-thread build of the 1M
// sphere (the "AMD EPYC" host, 2026-12-05) the root's partition by halves
// took 1.6 to 1.7 ms where the same partition on one thread right after its
// own binning took 0.6; the same partition run a second time in place took
// 0.55. So the partitions of such nodes ask for the lines of the block
// kPrefetchBlocks ahead, to write: the team's partition by halves always,
// and in a parallel build (KernelContext::shared) every node of
// kPrefetchMin records or more (smaller ones are mostly in this core's
// caches: every keyed partition prefetching made the sequential 1M sphere
// 1.011x as long, those of kPrefetchMin and more 1.003x to 1.006x). The
// root's partition then took 1.3 ms.
inline constexpr uint32_t kPrefetchBlocks = 2;
inline constexpr uint32_t kPrefetchMin = 1u << 16;
inline void prefetch_for_write(const PrimRef* refs, uint32_t n) {
    for (uint32_t k = 0; k < n; k += 2) __builtin_prefetch(refs + k, 1, 3);  // two records a line
}
// The block kPrefetchBlocks ahead of a walk over blocks of kSideBlock
// records, when whole inside it: going up, the next block starting at
// `next` and the walk ending at `end`; going down, the next block ending at
// `next_end` and the walk starting at `begin`.
inline constexpr uint32_t kPrefetchAhead = (kPrefetchBlocks - 1) * kSideBlock;
inline void prefetch_up(const PrimRef* refs, uint32_t next, uint32_t end) {
    if (next + kPrefetchAhead + kSideBlock <= end) prefetch_for_write(refs + next + kPrefetchAhead, kSideBlock);
}
inline void prefetch_down(const PrimRef* refs, uint32_t next_end, uint32_t begin) {
    if (next_end >= begin + kPrefetchAhead + kSideBlock)
        prefetch_for_write(refs + next_end - kPrefetchAhead - kSideBlock, kSideBlock);
}

// The partition loop over refs[b, e) with left part [b, mid).
template <class Test>
PartitionResult partition_with(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e, const Test& side,
                               bool shared = false) {
    // One block (most nodes): one mask.
    if (e - b <= kSideBlock) return partition_block(refs, b, mid, e, left_mask(refs + b, e - b, side));
    ChildBounds4 acc;
    // A cursor in each part, i in [b, mid) and j in [mid, e), each with the
    // misplaced records of its current block as bits (mi: going right, mj:
    // going left); pairs are swapped in order while both have some.
    uint32_t i = b, j = mid;
    uint64_t mi = 0, mj = 0;
    const bool prefetch = std::is_same_v<Test, KeyTest> && shared && e - b >= kPrefetchMin;
    PrimRef* ri = refs + b;
    PrimRef* rj = refs + mid;
    for (;;) {
        if (!mi) {
            if (i >= mid) break;
            const uint32_t n = std::min(kSideBlock, mid - i);
            ri = refs + i;
            mi = ~mark_block(ri, n, side, acc) & block_bits(n);
            i += n;
            if (prefetch) prefetch_up(refs, i, mid);
        }
        if (!mj) {
            if (j >= e) break;
            const uint32_t n = std::min(kSideBlock, e - j);
            rj = refs + j;
            mj = mark_block(rj, n, side, acc);
            j += n;
            if (prefetch) prefetch_up(refs, j, e);
        }
        for (; mi && mj; mi &= mi - 1, mj &= mj - 1) swap_refs(ri[std::countr_zero(mi)], rj[std::countr_zero(mj)]);
    }
    // What is left of either part has no misplaced record: bounds only.
    for (; i < mid; i += kSideBlock) mark_block(refs + i, std::min(kSideBlock, mid - i), side, acc);
    for (; j < e; j += kSideBlock) mark_block(refs + j, std::min(kSideBlock, e - j), side, acc);
    return result_of(acc, mid);
}

// Size splits are rare; their loop stays out of line, so that the plane
// partition inlines into run_node.
[[gnu::noinline]] inline PartitionResult partition_by_size(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e,
                                                           const Split& s) {
    return partition_with(refs, b, mid, e, SizeTest(s));
}

inline PartitionResult partition(PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, const Split& s) {
    const uint32_t mid = begin + s.left_count;
    if (s.by_size()) return partition_by_size(refs, begin, mid, end, s);
    if (end - begin < kThresholdTestMin)
        return m.prescaled ? partition_with(refs, begin, mid, end, SideIndexTest<true>(m, s))
                           : partition_with(refs, begin, mid, end, SideIndexTest<false>(m, s));
    return partition_with(refs, begin, mid, end, SideTest(m, s));
}

// The records of partition() of plane split s, the sides read from the keys
// bin() wrote (KeyTest): the result has the right child's start but no
// bounds (bounds_from_bins() gives them).
inline PartitionResult partition_by_keys(PrimRef* refs, uint32_t begin, uint32_t end, const Split& s,
                                         const uint32_t* keys, bool shared = false) {
    return partition_with(refs, begin, begin + s.left_count, end, KeyTest(keys, refs, s), shared);
}

// partition() of a plane split of a node of at most kBinBlock records right
// after bin() went over it: the sides are read from the bin indices bin()
// left in `bins.index` instead of being computed again from the centroids
// (the same indices, so the same sides and the same result).
inline PartitionResult partition_binned(PrimRef* refs, uint32_t begin, uint32_t end, const Split& s,
                                        const BinSet& bins) {
    static_assert(kBinBlock <= kSideBlock);
    assert(end - begin <= kBinBlock);
    const uint32_t n = std::min(end - begin, kBinBlock);  // for the compiler's bounds analysis
    uint64_t left = 0;
    for (uint32_t i = 0; i < n; ++i) left |= uint64_t(uint32_t(bins.index[i][s.axis]) < s.index) << i;
    return partition_block(refs, begin, begin + s.left_count, end, left);
}

}  // namespace canopy
