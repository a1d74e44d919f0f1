// canopy: step 1 of the node task, binning: every record's centroid into
// the bins of every valid axis in one pass (with each record's bin indices
// written beside it on request), and the sample a big node chooses its axis
// from.
#pragma once

#include "bin_mapper.h"
#include "bins.h"
#include "task.h"

#include <algorithm>
#include <cassert>
#include <cstdint>

namespace canopy {

// Step 1: bin the centroids of refs[begin, end) on every valid axis, in one
// pass; axes that are not valid are not binned. Accumulates into `out`
// (clear it first).
//
// The bin indices of a block of primitives are computed first and the bins
// updated in a second loop over the same (cache-hot) block. Computed in the
// same loop, each update's store address was known only late, after the
// whole index computation; the next primitive's loads, issued before it,
// were then often found to alias it (neighbours tend to fall in the same
// bin) and replayed. Measured on a 1M-triangle sphere: 40% less time.
//
// Ranges of kTwoBinSetsMin records or more bin every other record into the
// second set (out.odd) and merge it at the end (exact, so the bins are the
// same). Neighbouring records mostly fall in the same bins, and each bin
// update waits for the previous one's store; two sets make two independent
// chains. Measured, sequential builds (alternated runs): 1M sphere 0.94x to
// 0.96x, dragon_vrip_res2 0.98x to 0.99x. Small ranges keep one set:
// clearing and merging a second one would cost more than it saves.
//
// The bins' boxes are simd::MinBox, (lo, -hi): one 256-bit minimum per
// update with AVX instead of a minimum and a maximum on two 128-bit halves.
// Clearing and binning 1M sphere records in ranges of 16, 60, 1,000, 20,000
// and 1M records (a small program against this header, fastest of 30 to 60
// runs, alternated): 0.80x to 0.93x as long; the sequential build of the cow
// runs 4.3% fewer instructions (cachegrind).
inline constexpr uint32_t kTwoBinSetsMin = 256;
// The same for nodes flat on one or two axes (alternate_updates()): their
// records cost less to bin, so the second set's clearing and merging pays
// later (bench/bench_binning, the "AMD EPYC" host, 2026-12-06: at 256
// records two sets took random triangles 1.4 to 1.7 times as long).
inline constexpr uint32_t kTwoBinSetsFlatMin = 1024;
// Nodes binned on one axis from this many records take bin_one_axis().
inline constexpr uint32_t kOneAxisMin = 512;

namespace detail {

// Records r[0], r[S], r[2S], ... as r[0], r[1], r[2]: the hot loops below
// take their records through operator[] (a plain pointer, or this for a
// node's sample, see bin_sample()).
template <uint32_t S>
struct Strided {
    const PrimRef* p;
    const PrimRef& operator[](uint32_t i) const { return p[size_t(i) * S]; }
};

#if CANOPY_PACKED_COUNTS
// Adds record x to bins ki of the three axes of a set (BinArrays::axes()).
inline void update(const BinArrays::Axes& set, const PrimRef& x, const int32_t (&ki)[4]) {
    const auto box = BinArrays::record(x);
    const __m256i one = BinArrays::one();
    BinArrays::add(set.a[0][ki[0]], box, one);
    BinArrays::add(set.a[1][ki[1]], box, one);
    BinArrays::add(set.a[2][ki[2]], box, one);
}
#endif
// Adds record x to set's bins ki on all three axes, through the set (the
// path without AVX2, whose counts are an array of their own).
inline void update(BinArrays& set, const PrimRef& x, const int32_t (&ki)[4]) {
    const auto box = BinArrays::record(x);
    set.add(0, ki[0], box);
    set.add(1, ki[1], box);
    set.add(2, ki[2], box);
}

// What the hot loops hand to update(): the axes' bin pointers as locals with
// AVX2, the set itself otherwise.
#if CANOPY_PACKED_COUNTS
inline BinArrays::Axes hot(BinArrays& set) { return set.axes(); }
#else
inline BinArrays& hot(BinArrays& set) { return set; }
#endif

// The bin updates of a block of records whose indices are in k (bin()'s
// two-set path): record i goes to set s0 for even i and s1 for odd i, except
// that four aligned neighbours (or two) with the same bins on all three axes
// are added as one update (their boxes' minimum, their count), the sets
// alternating. Input in spatial order (scan order, strips, rings) has long
// runs of records in the same bins, and every update of a bin waits for the
// previous one's store: on the 1M sphere 45% of the records binned here
// went in fours and 30% in twos, on dragon_vrip_res2 1% in fours and 14% in
// twos, on random triangles none. Exact (minima and integer sums), so the
// same bins; only the operands' order of a minimum changes, which matters
// for a tie of +0 and -0 alone, and the records hold no -0 (see
// simd::MinBox::counted()). bench/ab/run.sh against one update per record,
// on the Intel Xeon host of 2026-12-04 (9 rounds of 5 warm sequential
// builds, medians of per-round ratios): 1M
// sphere 0.92x (pairs alone 0.955x), 1M stadium 0.90x, 1M random triangles
// 1.00x (in other runs 1.01x to 1.02x: the comparisons), dragon 1.01x, the
// cow 0.98x (the cow and dragon within their noise). The same merging
// in the one-set path (ranges under kTwoBinSetsMin) was slower everywhere
// (1.02x to 1.03x), and eights on top of fours gained nothing (1.00x).
template <class Refs>
inline void merged_updates(BinArrays& set0, BinArrays& set1, Refs r, const int32_t (*k)[4], uint32_t n) {
    uint32_t i = 0;
    auto&& s0 = hot(set0);
    auto&& s1 = hot(set1);
#if CANOPY_PACKED_COUNTS
    const auto row = [&](uint32_t j) { return _mm_load_si128(reinterpret_cast<const __m128i*>(k[j])); };
    const auto add3 = [&](const BinArrays::Axes& set, uint32_t j, __m256 box, uint32_t count) {
        const __m256i inc = _mm256_setr_epi32(0, 0, 0, int(count), 0, 0, 0, 0);
        BinArrays::add(set.a[0][k[j][0]], box, inc);
        BinArrays::add(set.a[1][k[j][1]], box, inc);
        BinArrays::add(set.a[2][k[j][2]], box, inc);
    };
    const auto pair = [&](const BinArrays::Axes& merged, uint32_t j) {
        if (_mm_movemask_epi8(_mm_cmpeq_epi32(row(j), row(j + 1))) == 0xFFFF) {
            add3(merged, j, _mm256_min_ps(BinArrays::record(r[j]), BinArrays::record(r[j + 1])), 2);
        } else {
            update(s0, r[j], k[j]);
            update(s1, r[j + 1], k[j + 1]);
        }
    };
    const BinArrays::Axes* sets[2] = {&s0, &s1};
    uint32_t t = 0;
    for (; i + 3 < n; i += 4) {
        const __m128i a = row(i);
        const __m128i e = _mm_and_si128(_mm_and_si128(_mm_cmpeq_epi32(a, row(i + 1)), _mm_cmpeq_epi32(a, row(i + 2))),
                                        _mm_cmpeq_epi32(a, row(i + 3)));
        if (_mm_movemask_epi8(e) == 0xFFFF) {
            const __m256 box = _mm256_min_ps(_mm256_min_ps(BinArrays::record(r[i]), BinArrays::record(r[i + 1])),
                                             _mm256_min_ps(BinArrays::record(r[i + 2]), BinArrays::record(r[i + 3])));
            add3(*sets[t], i, box, 4);
            t ^= 1;
        } else {
            pair(s0, i);
            pair(s1, i + 2);
        }
    }
#endif
    for (; i + 1 < n; i += 2) {
        update(s0, r[i], k[i]);
        update(s1, r[i + 1], k[i + 1]);
    }
    if (i < n) update(s0, r[i], k[i]);
}

// The bin updates of a block of records on the na < 3 valid axes `axes`
// (bin()'s two-set path for a node flat on the others): record i goes to
// set s0 for even i and s1 for odd i. With one set, each update of a bin
// waited for the previous one's store, and neighbours in spatial order
// share bins: binning the 1M sphere's records in their own order on two
// axes took 3.3 ns a record, on one axis 2.9, where all three axes (two
// sets) took 1.5 (bench/bench_binning, the "AMD EPYC" host, 2026-12-06).
template <int NA, class Refs>
[[gnu::noinline]] void alternate_updates(BinArrays& set0, BinArrays& set1, Refs r, const int32_t (*k)[4],
                                         uint32_t n, const int (&axes)[3]) {
#if CANOPY_PACKED_COUNTS
    simd::MinBox* const b0[2] = {set0.axes().a[axes[0]], set1.axes().a[axes[0]]};
    simd::MinBox* const b1[2] = {set0.axes().a[axes[NA - 1]], set1.axes().a[axes[NA - 1]]};
    const int a0 = axes[0], a1 = axes[NA - 1];
    const __m256i inc = BinArrays::one();
    const auto one = [&](int s, uint32_t i) {
        const __m256 box = BinArrays::record(r[i]);
        BinArrays::add(b0[s][k[i][a0]], box, inc);
        if constexpr (NA == 2) BinArrays::add(b1[s][k[i][a1]], box, inc);
    };
#else
    BinArrays* const sets[2] = {&set0, &set1};
    const auto one = [&](int s, uint32_t i) {
        const auto box = BinArrays::record(r[i]);
        for (int j = 0; j < NA; ++j) sets[s]->add(axes[j], k[i][axes[j]], box);
    };
#endif
    uint32_t i = 0;
    for (; i + 1 < n; i += 2) {
        one(0, i);
        one(1, i + 1);
    }
    if (i < n) one(0, i);
}

// Writes the bin keys (see bin()) of a block of n records whose indices are
// in k to out[0, n).
inline void store_keys(const int32_t (*k)[4], uint32_t n, uint32_t* out) {
    uint32_t i = 0;
#if defined(__AVX2__)
    // Per 128-bit lane: bytes 0, 4 and 8 (the three axes' indices, each
    // below 256) to bytes 0 to 2; then the two lanes' words side by side.
    const __m256i pick = _mm256_setr_epi8(0, 4, 8, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1,  //
                                          0, 4, 8, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
    const __m256i join = _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0);
    for (; i + 1 < n; i += 2) {
        const __m256i v = _mm256_load_si256(reinterpret_cast<const __m256i*>(k[i]));
        const __m256i w = _mm256_permutevar8x32_epi32(_mm256_shuffle_epi8(v, pick), join);
        _mm_storel_epi64(reinterpret_cast<__m128i*>(out + i), _mm256_castsi256_si128(w));
    }
#endif
    for (; i < n; ++i) out[i] = uint32_t(k[i][0]) | uint32_t(k[i][1]) << 8 | uint32_t(k[i][2]) << 16;
}

// The bin indices of records r[0, n) (n <= kBinBlock) on the three axes,
// one row each in k. Pre: see BinMapper::indices4.
template <bool Pre, class Refs = const PrimRef*>
inline void block_indices(Refs r, uint32_t n, const BinMapper& m, int32_t (*k)[4]) {
    uint32_t i0 = 0;
#if defined(__AVX__)
    // Two records at a time in 256-bit vectors, lane for lane the same
    // operations as indices4(centroid()), so the same indices. Against
    // one record per 128-bit step (warm sequential builds, alternated
    // pairs, medians of 7 to 11 pairs): 1M sphere 0.945x as long,
    // dragon_vrip_res2 0.994x, the cow 0.98x.
    {
        const __m256 keep = simd::xyz_mask2();
        const __m256 o = _mm256_set_m128(m.origin4, m.origin4), p = _mm256_set_m128(m.prescale4, m.prescale4);
        const __m256 sc = _mm256_set_m128(m.scale4, m.scale4), last = _mm256_set_m128(m.last4, m.last4);
        for (; i0 + 1 < n; i0 += 2) {
            const __m256 lo = _mm256_and_ps(_mm256_loadu2_m128(&r[i0 + 1].lo.x, &r[i0].lo.x), keep);
            const __m256 hi = _mm256_and_ps(_mm256_loadu2_m128(&r[i0 + 1].hi.x, &r[i0].hi.x), keep);
            __m256 f = _mm256_sub_ps(simd::centroid2(lo, hi), o);
            if constexpr (Pre) f = _mm256_mul_ps(f, p);
            f = _mm256_mul_ps(f, sc);
            f = _mm256_min_ps(_mm256_max_ps(f, _mm256_setzero_ps()), last);
            _mm256_store_si256(reinterpret_cast<__m256i*>(k[i0]), _mm256_cvttps_epi32(f));
        }
    }
#endif
    for (uint32_t i = i0; i < n; ++i)
        _mm_store_si128(reinterpret_cast<__m128i*>(k[i]),
                        m.template indices4<Pre>(simd::centroid(simd::lo(r[i]), simd::hi(r[i]))));
}

// Asks for the records of the block two blocks ahead of the one at r
// (record b0 of a walk ending at `end`) to be cached, when whole.
inline void prefetch_block_ahead(const PrimRef* r, uint32_t b0, uint32_t end) {
    if (b0 + 3 * kBinBlock > end) return;
    const char* p = reinterpret_cast<const char*>(r + 2 * kBinBlock);
    for (uint32_t q = 0; q < kBinBlock * sizeof(PrimRef); q += 64) _mm_prefetch(p + q, _MM_HINT_T0);
}

// bin() over blocks of records; Two: every other record into out.odd;
// Pre: the mapping's prescale is applied (see BinMapper::indices4); keys:
// see bin().
template <bool Two, bool Pre>
inline void bin_blocks(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out,
                       uint32_t* keys) {
    int32_t (*k)[4] = out.index;  // the indices of the current block
    int axes[3], na = 0;
    for (int a = 0; a < 3; ++a)
        if (m.valid[a]) axes[na++] = a;
    for (uint32_t b0 = begin; b0 < end; b0 += kBinBlock) {
        const uint32_t n = std::min(kBinBlock, end - b0);
        const PrimRef* r = refs + b0;
        // Large ranges ask for the block two blocks ahead (4 KiB) to be
        // cached. On this session's Intel Xeon host (bench/ab/run.sh, 9
        // rounds of 5 warm sequential builds): 1M sphere 0.97x as long, 1M
        // random 0.95x, dragon_vrip_res2 0.96x, the 1M stadium 0.99x, the
        // cow 1.00x; one block ahead 1.00x-1.01x and four 1.01x-1.02x
        // against two; prefetching in partition_with() too, 1.01x-1.02x.
        // (On the AMD EPYC host of 2026-12-03 a prefetch in the binning
        // measured 1.01x; its distance was not recorded.)
        if constexpr (Two) prefetch_block_ahead(r, b0, end);
        block_indices<Pre>(r, n, m, k);
        if (keys) store_keys(k, n, keys + b0);
        if constexpr (Two) {
            if (na == 3)
                merged_updates(out, out.odd, r, k, n);
            else if (na == 2)
                alternate_updates<2>(out, out.odd, r, k, n, axes);
            else
                alternate_updates<1>(out, out.odd, r, k, n, axes);
        } else if (na == 3) {
            // The common case, unrolled: the three axes' updates are
            // independent chains.
            auto&& set = hot(out);
            for (uint32_t i = 0; i < n; ++i) update(set, r[i], k[i]);
        } else {
            for (uint32_t i = 0; i < n; ++i) {
                const auto box = BinArrays::record(r[i]);
                for (int j = 0; j < na; ++j) out.add(axes[j], k[i][axes[j]], box);
            }
        }
    }
}

inline bool two_bin_sets(const BinMapper& m, uint32_t begin, uint32_t end) {
    return end - begin >= kTwoBinSetsMin && (end - begin >= kTwoBinSetsFlatMin || m.valid_count() == 3);
}

// Out of line, so that bin() stays small enough to inline into run_node()
// for the many small nodes.
template <bool Pre>
[[gnu::noinline]] void bin_two_sets(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                    BinSet& out, uint32_t* keys) {
    // A node flat on some axis bins and merges only the others.
    out.second(m.bins, m.valid);
    bin_blocks<true, Pre>(refs, begin, end, m, out, keys);
    out.merge(out.odd, m.bins, m.valid);
}

#if CANOPY_PACKED_COUNTS
// bin() of a node with one valid axis, from kOneAxisMin records: what big
// nodes do after choosing their axis from a sample (binning_mapper()), and
// nodes flat on two axes. Its records go round-robin to four sets of that
// axis's bins (the first set's, and the second set's three regions: a
// record waits on the store of the record four back, not two, since one
// axis has the longest runs of neighbours in the same bin), merged into
// the first set at the end. With AVX-512 the indices are computed for that
// axis alone, sixteen records at a time. Binning alone (bench/bench_binning,
// the "AMD EPYC" host, 2026-12-06), ns a record on one axis against all
// three: the 1M sphere in its order 0.90 against 1.49, random triangles
// 0.78 against 1.85, the stadium 0.98 against 1.35 (with two sets and
// all three axes' indices, as flat nodes had: 1.82, 1.25, 2.2).
[[gnu::noinline]] inline void bin_one_axis(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                           BinSet& out, uint32_t* keys) {
    const int a = m.valid[0] ? 0 : m.valid[1] ? 1 : 2;
    BinArrays& odd = out.second(m.bins);
    simd::MinBox* const s0 = out.axes().a[a];
    simd::MinBox* const s1 = odd.axes().a[0];
    simd::MinBox* const s2 = odd.axes().a[1];
    simd::MinBox* const s3 = odd.axes().a[2];
#if !defined(__AVX512F__)
    int32_t (*k)[4] = out.index;
#endif
    const __m256i one = BinArrays::one();
    for (uint32_t b0 = begin; b0 < end; b0 += kBinBlock) {
        const uint32_t n = std::min(kBinBlock, end - b0);
        const PrimRef* r = refs + b0;
        prefetch_block_ahead(r, b0, end);
        uint32_t i = 0;
#if defined(__AVX512F__)
        // Sixteen records at a time: their axis-a corners gathered from
        // eight 512-bit loads by eight permutes, then lane for lane the
        // operations of indices4(centroid()) (so the same indices).
        alignas(64) int32_t idx[kBinBlock];
        for (; i + 16 <= n; i += 16) {
            const __m512i pick = _mm512_setr_epi32(a, 8 + a, 16 + a, 24 + a, 4 + a, 12 + a, 20 + a, 28 + a,  //
                                                   a, 8 + a, 16 + a, 24 + a, 4 + a, 12 + a, 20 + a, 28 + a);
            __m512 w[4];
            for (int j = 0; j < 4; ++j)
                w[j] = _mm512_permutex2var_ps(_mm512_loadu_ps(&r[i + 4 * j].lo.x), pick,
                                              _mm512_loadu_ps(&r[i + 4 * j + 2].lo.x));
            // w[j]: lanes 0-3 the lo of records 4j..4j+3, lanes 4-7 their hi.
            const __m512i join = _mm512_setr_epi32(0, 1, 2, 3, 16, 17, 18, 19, 4, 5, 6, 7, 20, 21, 22, 23);
            const __m512 x0 = _mm512_permutex2var_ps(w[0], join, w[1]);  // lo 0-7, hi 0-7
            const __m512 x1 = _mm512_permutex2var_ps(w[2], join, w[3]);  // lo 8-15, hi 8-15
            const __m512i los = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
            const __m512i his = _mm512_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
            const __m512 lo = _mm512_permutex2var_ps(x0, los, x1), hi = _mm512_permutex2var_ps(x0, his, x1);
            // (Masked forms with a full mask: GCC 12 warns that the
            // unmasked ones start from an uninitialised vector.)
            constexpr __mmask16 all = 0xFFFF;
            const __m512 half = _mm512_set1_ps(0.5f), zero = _mm512_setzero_ps();
            const __m512 c = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(lo, half), _mm512_mul_ps(hi, half)), zero);
            __m512 f = _mm512_mul_ps(_mm512_sub_ps(c, _mm512_set1_ps(m.origin[a])), _mm512_set1_ps(m.scale[a]));
            f = _mm512_mask_max_ps(f, all, f, zero);
            f = _mm512_mask_min_ps(f, all, f, _mm512_set1_ps(float(m.bins - 1)));
            const __m512i ki = _mm512_mask_cvttps_epi32(_mm512_setzero_si512(), all, f);
            _mm512_store_si512(idx + i, ki);
            if (keys) _mm512_storeu_si512(keys + b0 + i, _mm512_mask_slli_epi32(ki, all, ki, unsigned(8 * a)));
        }
        for (uint32_t j = i; j < n; ++j) {
            const __m128i row = m.indices4<false>(simd::centroid(simd::lo(r[j]), simd::hi(r[j])));
            alignas(16) int32_t v[4];
            _mm_store_si128(reinterpret_cast<__m128i*>(v), row);
            idx[j] = v[a];
            if (keys) keys[b0 + j] = uint32_t(v[a]) << (8 * a);
        }
        i = 0;
        for (; i + 3 < n; i += 4) {
            BinArrays::add(s0[idx[i]], BinArrays::record(r[i]), one);
            BinArrays::add(s1[idx[i + 1]], BinArrays::record(r[i + 1]), one);
            BinArrays::add(s2[idx[i + 2]], BinArrays::record(r[i + 2]), one);
            BinArrays::add(s3[idx[i + 3]], BinArrays::record(r[i + 3]), one);
        }
        for (; i < n; ++i) BinArrays::add(s0[idx[i]], BinArrays::record(r[i]), one);
#else
        block_indices<false>(r, n, m, k);
        if (keys) store_keys(k, n, keys + b0);
        for (; i + 3 < n; i += 4) {
            BinArrays::add(s0[k[i][a]], BinArrays::record(r[i]), one);
            BinArrays::add(s1[k[i + 1][a]], BinArrays::record(r[i + 1]), one);
            BinArrays::add(s2[k[i + 2][a]], BinArrays::record(r[i + 2]), one);
            BinArrays::add(s3[k[i + 3][a]], BinArrays::record(r[i + 3]), one);
        }
        for (; i < n; ++i) BinArrays::add(s0[k[i][a]], BinArrays::record(r[i]), one);
#endif
    }
    for (uint32_t b = 0; b < m.bins; ++b) {
        BinArrays::merge_bin(s0[b], s1[b]);
        BinArrays::merge_bin(s0[b], s2[b]);
        BinArrays::merge_bin(s0[b], s3[b]);
    }
}
#endif

// Nodes whose centroid extent is below 2^-64 on some axis (prescaled).
[[gnu::noinline]] inline void bin_prescaled(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                            BinSet& out, uint32_t* keys) {
    if (two_bin_sets(m, begin, end)) return bin_two_sets<true>(refs, begin, end, m, out, keys);
    bin_blocks<false, true>(refs, begin, end, m, out, keys);
}

}  // namespace detail

// With `keys`, bin() also writes each record's bin indices, its key, beside
// it: keys[i] for refs[i], byte a the index on axis a (at most 255, as
// kMaxBins is 256); keys outside [begin, end) are not touched. partition()
// then reads a record's side from its key (KeyTest) instead of mapping its
// centroid again.
inline void bin(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out,
                uint32_t* keys = nullptr) {
    if (m.prescaled) return detail::bin_prescaled(refs, begin, end, m, out, keys);
#if CANOPY_PACKED_COUNTS
    if (end - begin >= kOneAxisMin && m.valid_count() == 1) return detail::bin_one_axis(refs, begin, end, m, out, keys);
#endif
    if (detail::two_bin_sets(m, begin, end)) return detail::bin_two_sets<false>(refs, begin, end, m, out, keys);
    detail::bin_blocks<false, false>(refs, begin, end, m, out, keys);
}

// Nodes of at least kSampleMin primitives with two or three valid axes
// choose their split axis from a sample: every sample_step()-th record (from
// the node's first) binned on every valid axis and evaluated; then all
// records are binned on that axis alone (bin_one_axis()) and evaluated for
// the split (binning_mapper()). A sample taken by position makes a tree
// depend a little on the order of the records, never on threads.
inline constexpr uint32_t kSampleMin = 512;
inline bool samples_axis(const BinMapper& m, uint32_t n) {
    return n >= kSampleMin && !m.prescaled && m.valid_count() >= 2;
}

// The sample's step for a node of n records (see also sample_step(t) below,
// for nodes with large primitives): 4, doubled while the sample
// keeps at least kSampleTarget records, up to kSampleMaxStep (4 below 8,192
// records, 32 from 32,768). A bigger node's sample is a smaller share of
// it: a quarter of a node that is not in the cache made the sample pass
// cost nearly what the full one-axis pass does (it brought in every line),
// and a thousand records or more choose the axis about as well. Against
// every fourth record throughout (2026-12-06, "AMD EPYC" host, medians of
// 5 alternated rounds' ratios): sequential 1M sphere 0.90x, 1M stadium
// 0.89x, 1M random 0.97x, dragon_vrip_res2 0.93x; tbb at 2 threads 1M
// sphere 0.88x, dragon 0.94x, 1M random 0.96x. SAH within 0.01% on the
// sphere, stadium and random scenes and the dragons, bunny and cow (for
// scenes with a few large primitives, see sample_step(t) below). (Sample
// steps of 8 or 16 throughout gained less on the big scenes and cost more
// SAH.) The chunks of a team's node start at multiples of 64 records from
// its first, so a step divides them.
inline constexpr uint32_t kSampleStep = 4;
inline constexpr uint32_t kSampleMaxStep = 32;
inline constexpr uint32_t kSampleTarget = 1024;
inline uint32_t sample_step(uint32_t n) {
    uint32_t s = kSampleStep;
    while (s < kSampleMaxStep && n / (2 * s) >= kSampleTarget) s *= 2;
    return s;
}
// A node holding a primitive whose box has at least 1/kSampleLargePrim of
// the node's half area keeps every fourth record whatever its size: a few
// large primitives (a room's walls, a cathedral's floor) weigh on the SAH of
// every split far beyond their number, and a sparse sample that misses
// them picks the axis from the small ones. With the step by size alone,
// `gen:room:1000000` went from 12.9996 to 13.2428 (+1.9%; no sample at all
// gives 12.9988) and Sibenik to 26.61 (+2.3%; 27.11 and 27.39 at 64 and
// 128 bins, against 26.50 and 26.56); with this rule both trees are the
// ones every fourth record gave, at every bin count, from 1/16 to 1/1024
// (1/8 left Sibenik at 26.52). The sphere, stadium and random scenes and
// the dragon keep the sparse sample's trees; 1M random triangles build in
// 0.998x the time (sequential; 1/64: 1.033x, its deeper nodes' larger
// triangles counting as large).
inline constexpr double kSampleLargePrim = 32.0;
inline uint32_t sample_step(const NodeTask& t) {
    if (double(t.max_area) * kSampleLargePrim >= t.bounds.half_area()) return kSampleStep;
    return sample_step(t.size());
}

namespace detail {
template <uint32_t S>
inline void bin_sample(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out) {
    constexpr uint32_t span = S * kBinBlock;
    BinArrays& odd = out.second(m.bins, m.valid);
    int axes[3] = {0, 0, 0}, na = 0;
    for (int a = 0; a < 3; ++a)
        if (m.valid[a]) axes[na++] = a;
    for (uint32_t b0 = begin; b0 < end; b0 += span) {
        const uint32_t e = static_cast<uint32_t>(std::min<uint64_t>(end, uint64_t(b0) + span));
        const uint32_t q = (e - b0 + S - 1) / S;
        const Strided<S> r{refs + b0};
        block_indices<false>(r, q, m, out.index);
        if (na == 3)
            merged_updates(out, odd, r, out.index, q);
        else
            alternate_updates<2>(out, odd, r, out.index, q, axes);
    }
    out.merge(odd, m.bins, m.valid);
}
}  // namespace detail

// Step 1 on the sample: bins records begin, begin + step, ... below end
// into `out` (accumulating); `step` is sample_step(t) of the node. A team's
// chunks start at multiples of the step from the node's first record, so
// their samples are the node's.
inline void bin_sample(const PrimRef* refs, uint32_t begin, uint32_t end, uint32_t step, const BinMapper& m,
                       BinSet& out) {
    static_assert(kSampleStep == 4 && kSampleMaxStep == 32 && kBinBlock % kSampleMaxStep == 0);
    switch (step) {
    case 4: return detail::bin_sample<4>(refs, begin, end, m, out);
    case 8: return detail::bin_sample<8>(refs, begin, end, m, out);
    case 16: return detail::bin_sample<16>(refs, begin, end, m, out);
    default: assert(step == 32); return detail::bin_sample<32>(refs, begin, end, m, out);
    }
}

}  // namespace canopy
