// canopy: steps 1 and 2 for the most common node, four bins and at most
// kBinBlock records, in AVX-512 registers (CANOPY_REGISTER_BINS is 1 where
// that is compiled in, else 0).
#pragma once

#include "bin.h"
#include "evaluate.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cstdint>
#include <limits>

namespace canopy {

// Nodes of 4 bins (5 to 32 primitives with the default 32 bins, most of the
// nodes evaluated) binned and evaluated in registers where AVX-512 is
// compiled in: bin() and evaluate() for them, the same Split (axis, index,
// left count and cost, bit for bit) and the same index rows left in
// `bins.index` for partition_binned(); the bins themselves are not written.
//
// The twelve bins (4 on each axis) are the lanes a * 4 + b of seven 16-lane
// vectors, one per component: lo x, y, z, hi x, y, z and the count. A record
// updates its three lanes with masked minima and maxima of its broadcast
// components (exact: the same boxes as the bins' minima of (lo, -hi), as the
// records hold no -0 and no NaN; see simd::MinBox). The sweeps are then
// prefix and suffix minima within each group of four lanes, and the costs
// are formed lane for lane with the float operations of evaluate_sweeps()
// and simd::Measure::three(): negated extents lo * s + (-hi * s) (written
// lo * s - hi * s, the same IEEE result), then (x y + y z) + z x, or the
// negated sum (x + y) + z for lengths; A_L n_L + A_R n_R. The cheapest
// candidate wins, ties to the lowest lane, that is the lowest axis and then
// the lowest index, as evaluate_sweeps() chooses.
#if defined(__AVX512F__) && defined(__AVX512VL__)
#define CANOPY_REGISTER_BINS 1
// Lane i of the result: lane idx[i] of v. (The masked form, with v as the
// source of lanes not taken, as all are: the unmasked intrinsics start from
// an undefined vector, which GCC 12 warns about as maybe uninitialized.)
inline __m512 permute(__m512i idx, __m512 v) { return _mm512_mask_permutexvar_ps(v, 0xFFFF, idx, v); }
inline __m512i permute(__m512i idx, __m512i v) { return _mm512_mask_permutexvar_epi32(v, 0xFFFF, idx, v); }
inline __m512 to_float(__m512i v) { return _mm512_mask_cvtepi32_ps(_mm512_castsi512_ps(v), 0xFFFF, v); }
// The least of the lanes of `ok` in every lane (+inf when none).
inline __m512 min_of(__m512 v, __mmask16 ok) {
    const auto step = [](__m512 x, __m512i idx) { return _mm512_mask_min_ps(x, 0xFFFF, x, permute(idx, x)); };
    v = _mm512_mask_mov_ps(_mm512_set1_ps(std::numeric_limits<float>::infinity()), ok, v);
    v = step(v, _mm512_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5, 6, 7));
    v = step(v, _mm512_setr_epi32(4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11));
    v = step(v, _mm512_setr_epi32(2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13));
    return step(v, _mm512_setr_epi32(1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14));
}
// Boxes as the lanes of six 16-lane vectors, one per component: lo x, y, z
// (minima) and hi x, y, z (maxima); empty to begin with.
struct LaneBoxes {
    __m512 lo[3], hi[3];
    LaneBoxes() {
        const __m512 inf = _mm512_set1_ps(std::numeric_limits<float>::infinity());
        const __m512 ninf = _mm512_sub_ps(_mm512_setzero_ps(), inf);
        for (int c = 0; c < 3; ++c) {
            lo[c] = inf;
            hi[c] = ninf;
        }
    }
    // Grows the boxes of the lanes of `in` by record x's box (exact: the
    // boxes the bins' minima of (lo, -hi) hold, as the records hold no -0
    // and no NaN; see simd::MinBox).
    void add(const PrimRef& x, __mmask16 in) {
        for (int c = 0; c < 3; ++c) {
            lo[c] = _mm512_mask_min_ps(lo[c], in, lo[c], _mm512_set1_ps((&x.lo.x)[c]));
            hi[c] = _mm512_mask_max_ps(hi[c], in, hi[c], _mm512_set1_ps((&x.hi.x)[c]));
        }
    }
    // The measure of every lane's box with the float operations of
    // simd::Measure::three(): negated extents lo * s + (-hi * s) (written
    // lo * s - hi * s, the same IEEE result), then (x y + y z) + z x, or the
    // negated sum (x + y) + z for lengths.
    __m512 measure(const simd::Measure& m) const {
        const __m512 s = _mm512_set1_ps(_mm_cvtss_f32(m.scale));
        const auto neg_extent = [&](int c) { return _mm512_sub_ps(_mm512_mul_ps(lo[c], s), _mm512_mul_ps(hi[c], s)); };
        const __m512 x = neg_extent(0), y = neg_extent(1), z = neg_extent(2);
        if (m.use_length)  // negated by its sign bit, as simd::negate()
            return _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(_mm512_add_ps(_mm512_add_ps(x, y), z)),
                                                        _mm512_set1_epi32(std::numeric_limits<int32_t>::min())));
        return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(x, y), _mm512_mul_ps(y, z)), _mm512_mul_ps(z, x));
    }
};

inline Split bin_evaluate_4(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& bins,
                            const Box& node_bounds, const BuildOptions& opt) {
    assert(m.bins == 4 && !m.prescaled && end - begin <= kBinBlock);
    const uint32_t n = std::min(end - begin, kBinBlock);
    const PrimRef* r = refs + begin;
    int32_t (*k)[4] = bins.index;
    detail::block_indices<false>(r, n, m, k);

    LaneBoxes bin;
    __m512i count = _mm512_setzero_si512();
    const __m512i one = _mm512_set1_epi32(1);
    // Lane a * 4 + b is bin b of axis a; lanes 12 to 15 match no index.
    const __m512i lane_bin = _mm512_setr_epi32(0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, -1, -1, -1, -1);
    // A record's index row (lanes 0 to 3 of its 128 bits) spread so that
    // lane a * 4 + b holds its index on axis a.
    const __m512i spread = _mm512_setr_epi32(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3);
    for (uint32_t i = 0; i < n; ++i) {
        const __m512i row = _mm512_castsi128_si512(_mm_load_si128(reinterpret_cast<const __m128i*>(k[i])));
        const __mmask16 in = _mm512_cmpeq_epi32_mask(permute(spread, row), lane_bin);
        bin.add(r[i], in);
        count = _mm512_mask_add_epi32(count, in, count, one);
    }

    Split best;
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return best;
    const simd::Measure& measure = costs.measure;

    // Inclusive prefix (bins 0..b) and suffix (bins b..3) within each axis's
    // four lanes, in two steps each.
    const __m512i back1 = _mm512_setr_epi32(0, 0, 1, 2, 4, 4, 5, 6, 8, 8, 9, 10, 12, 12, 13, 14);
    const __m512i back2 = _mm512_setr_epi32(0, 1, 0, 1, 4, 5, 4, 5, 8, 9, 8, 9, 12, 13, 12, 13);
    const __m512i ahead1 = _mm512_setr_epi32(1, 2, 3, 3, 5, 6, 7, 7, 9, 10, 11, 11, 13, 14, 15, 15);
    const __m512i ahead2 = _mm512_setr_epi32(2, 3, 2, 3, 6, 7, 6, 7, 10, 11, 10, 11, 14, 15, 14, 15);
    constexpr __mmask16 b_ge1 = 0xEEEE, b_ge2 = 0xCCCC, b_le2 = 0x7777, b_le1 = 0x3333;
    const auto vmin = [](__m512 v, __mmask16 k, __m512 w) { return _mm512_mask_min_ps(v, k, v, w); };
    const auto vmax = [](__m512 v, __mmask16 k, __m512 w) { return _mm512_mask_max_ps(v, k, v, w); };
    // Two steps of op, from the lanes one and then two bins back (or ahead).
    const auto sweep = [&](__m512 v, auto op, bool back) {
        v = op(v, back ? b_ge1 : b_le2, permute(back ? back1 : ahead1, v));
        return op(v, back ? b_ge2 : b_le1, permute(back ? back2 : ahead2, v));
    };
    // Candidate a * 4 + j (j = 1..3: bins [0, j) left): its left side is the
    // prefix of lane a * 4 + j - 1, its right side the suffix of its own lane.
    LaneBoxes left, right;
    for (int c = 0; c < 3; ++c) {
        left.lo[c] = permute(back1, sweep(bin.lo[c], vmin, true));
        left.hi[c] = permute(back1, sweep(bin.hi[c], vmax, true));
        right.lo[c] = sweep(bin.lo[c], vmin, false);
        right.hi[c] = sweep(bin.hi[c], vmax, false);
    }
    const __m512 left_measure = left.measure(measure), right_measure = right.measure(measure);
    __m512i left_count = _mm512_mask_add_epi32(count, b_ge1, count, permute(back1, count));
    left_count = _mm512_mask_add_epi32(left_count, b_ge2, left_count, permute(back2, left_count));
    left_count = permute(back1, left_count);
    __m512i right_count = _mm512_mask_add_epi32(count, b_le2, count, permute(ahead1, count));
    right_count = _mm512_mask_add_epi32(right_count, b_le1, right_count, permute(ahead2, right_count));
    const __m512 sum = _mm512_add_ps(_mm512_mul_ps(left_measure, to_float(left_count)),
                                     _mm512_mul_ps(right_measure, to_float(right_count)));
    // Candidates: split index 1 to 3 of a valid axis, both sides non-empty.
    const __mmask16 valid =
        __mmask16((m.valid[0] ? 0x000E : 0) | (m.valid[1] ? 0x00E0 : 0) | (m.valid[2] ? 0x0E00 : 0));
    const __m512i zero = _mm512_setzero_si512();
    const __mmask16 ok =
        _mm512_mask_cmpneq_epi32_mask(_mm512_mask_cmpneq_epi32_mask(valid, left_count, zero), right_count, zero);
    if (ok == 0) return best;
    const __m512 low = min_of(sum, ok);
    const uint32_t lane = uint32_t(std::countr_zero(unsigned(_mm512_mask_cmpeq_ps_mask(ok, sum, low))));
    alignas(64) int32_t lefts[16];
    _mm512_store_si512(lefts, left_count);
    best.axis = int(lane / 4);
    best.index = lane % 4;
    best.left_count = uint32_t(lefts[lane]);
    best.cost = costs.cost(_mm512_cvtss_f32(low), opt);
    return best;
}
#else
#define CANOPY_REGISTER_BINS 0
#endif

}  // namespace canopy
