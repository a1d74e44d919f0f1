// canopy: nodes of at most kExactMaxPrims primitives, split exactly: every
// partition of their records costed, none binned.
#pragma once

#include "evaluate.h"
#include "partition.h"

#include <algorithm>
#include <bit>
#include <cstdint>

namespace canopy {

// Small nodes are split exactly. A node of at most kExactMaxPrims
// primitives that got past the SAH lower bound (leaf_by_bound() in
// kernel.h) is not binned: every partition of its records into two
// non-empty sets is costed with the SAH, with the same measure as the bins'
// sweeps (simd::Measure, in the same float operations), and the cheapest
// wins. The planes between bins realise only some of those
// partitions, and the others are often cheaper (two walls and two small
// objects between them: no plane puts the walls together); the cost of a
// partition the bins also see is bit for bit the one evaluate() computes, so
// the exact choice is never worse than the binned one. Such nodes are 43% of
// the evaluations on `dragon_vrip_res2`, and most of them split (3 in 4): with
// 4 records there are 7 partitions, from the boxes of the 15 subsets of
// records, each one minimum of a smaller subset's box and one record's;
// cheaper than mapping, binning, sweeping and partitioning by bins.
// (Measured, sequential builds, instructions per build: the cow 10.85 ->
// 10.00 million, the dragon 460.0 -> 429.7 million. A first version of this
// code ran 10.07 and 432.0 at 4 records, 10.51 and 447.0 at 5, 11.31 and
// 472.1 at 6: the subsets double with each record.)
inline constexpr uint32_t kExactMaxPrims = 4;

// The cheapest split of the records r[0, n), 2 <= n <= kExactMaxPrims, inside
// `node_bounds`: `left` gets the bit mask (bit i: r[i]) of the set holding
// r[0], which becomes the left child, and `cost` the split's SAH cost (as
// Split::cost). Ties go to the lowest mask. False when the node's measure is
// zero, so that no split is cheaper than another (as evaluate() finds none).
inline bool exact_split_in_memory(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                                  uint32_t& left, double& cost) {
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    const uint32_t full = (1u << n) - 1;
    // sub[mask]: the box of the records in mask; sub[0] is empty.
    simd::MinBox sub[1u << kExactMaxPrims];
    for (uint32_t mask = 1; mask <= full; ++mask) {
        sub[mask] = sub[mask & (mask - 1)];
        sub[mask].grow(simd::MinBox::of(r[std::countr_zero(mask)]));
    }
    // measures[mask] for 0 < mask < full, three at a time (the last three
    // may run up to sub[full]; measures past it are not read).
    alignas(16) float measures[(1u << kExactMaxPrims) + 4] = {};
    for (uint32_t mask = 1; mask < full; mask += 3)
        _mm_storeu_ps(measures + mask, measure.three(sub[mask], sub[mask + 1], sub[mask + 2]));
    // Each partition once: the masks holding record 0 (odd), but the full one.
    float best = 0.0f;
    uint32_t best_mask = 0;
    for (uint32_t mask = 1; mask < full; mask += 2) {
        const uint32_t rest = full & ~mask;
        // A_L n_L + A_R n_R as evaluate() forms it (the sum is commutative).
        const float sum = measures[mask] * float(std::popcount(mask)) + measures[rest] * float(std::popcount(rest));
        if (best_mask == 0 || sum < best) {
            best = sum;
            best_mask = mask;
        }
    }
    left = best_mask;
    cost = costs.cost(best, opt);
    return true;
}

#if CANOPY_REGISTER_BINS
// exact_split() in AVX-512 registers: lane `mask` of LaneBoxes holds the
// box of the records in mask (record j grows the lanes whose number has bit
// j set: the constant lane masks 0xAAAA, 0xCCCC, 0xF0F0, 0xFF00), every
// lane's measure is formed with the float operations of
// simd::Measure::three(), and A_L n_L + A_R n_R as exact_split_in_memory()
// forms it (the rest's lane found by xor with the full mask); the cheapest
// odd mask below the full one wins, the lowest on a tie. The same result
// bit for bit.
inline bool exact_split_in_registers(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                                     uint32_t& left, double& cost) {
    assert(n >= 2 && n <= kExactMaxPrims);
    static_assert(kExactMaxPrims <= 4);
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    constexpr __mmask16 has[4] = {0xAAAA, 0xCCCC, 0xF0F0, 0xFF00};  // lanes whose mask holds record j
    LaneBoxes sub;
    for (uint32_t j = 0; j < n; ++j) sub.add(r[j], has[j]);
    const __m512 measures = sub.measure(measure);
    // measure * popcount per lane, and the same of the rest (lane full ^ mask).
    const __m512 counts = _mm512_setr_ps(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
    const __m512 weighted = _mm512_mul_ps(measures, counts);
    const uint32_t full = (1u << n) - 1;
    const __m512i rest = _mm512_xor_si512(_mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                                          _mm512_set1_epi32(int32_t(full)));
    const __m512 sum = _mm512_add_ps(weighted, permute(rest, weighted));
    const __mmask16 candidates = __mmask16(0xAAAA & ((1u << full) - 1));  // odd masks below full
    const __m512 low = min_of(sum, candidates);
    left = uint32_t(std::countr_zero(unsigned(_mm512_mask_cmpeq_ps_mask(candidates, sum, low))));
    cost = costs.cost(_mm512_cvtss_f32(low), opt);
    return true;
}
#endif

// The cheapest split of the records r[0, n), 2 <= n <= kExactMaxPrims: see
// exact_split_in_memory(); in registers where AVX-512 is compiled in, for
// nodes of 3 or 4 records (sequential builds, alternated, medians of 5 to 7
// rounds: 1M sphere 0.984x-0.986x as long, dragon_vrip_res2 0.970x-0.975x,
// 1M stadium 0.989x; for 2 records too, 1M random triangles took 1.019x:
// their single partition costs less in memory than 16 lanes).
inline bool exact_split(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                        uint32_t& left, double& cost) {
#if CANOPY_REGISTER_BINS
    if (n >= 3) return exact_split_in_registers(r, n, node_bounds, opt, left, cost);
#endif
    return exact_split_in_memory(r, n, node_bounds, opt, left, cost);
}

// The partition of a small node by a mask from exact_split(): the records of
// the mask first, then the others, each in their earlier order; child bounds
// accumulated as partition() does (each side's records grown in the same
// order, so the same boxes). All records are loaded before any is stored,
// each as one 256-bit vector, and the accumulators are locals grown with
// blends: copied through an array first and grown through an indexed
// ChildBounds4, both stayed in memory, and a profile of the 1M sphere had
// 7% of the node task's samples on the reload after those stores.
#if defined(__AVX__)
inline PartitionResult partition_by_mask(PrimRef* refs, uint32_t begin, uint32_t end, uint32_t left) {
    const uint32_t n = end - begin;
    __m256 rec[kExactMaxPrims];
    for (uint32_t i = 0; i < n; ++i) rec[i] = _mm256_loadu_ps(&refs[begin + i].lo.x);
    const uint32_t mid = begin + uint32_t(std::popcount(left));
    uint32_t at_left = begin, at_right = mid;
    simd::Box4 b0, b1, c0, c1;
    const __m128 keep = simd::xyz_mask();
    for (uint32_t i = 0; i < n; ++i) {
        const uint32_t goes_left = (left >> i) & 1;
        _mm256_storeu_ps(&refs[goes_left ? at_left : at_right].lo.x, rec[i]);
        at_left += goes_left;
        at_right += goes_left ^ 1u;
        const __m128 lo = _mm_and_ps(_mm256_castps256_ps128(rec[i]), keep);
        const __m128 hi_area = _mm256_extractf128_ps(rec[i], 1);
        const __m128 c = simd::centroid(lo, _mm_and_ps(hi_area, keep));
        // All ones where the record goes left.
        const __m128 m = _mm_castsi128_ps(_mm_set1_epi32(-int32_t(goes_left)));
        const __m128 inf = simd::pos_inf(), ninf = simd::neg_inf();
        b0.grow(_mm_blendv_ps(inf, lo, m), _mm_blendv_ps(ninf, hi_area, m));
        c0.grow(_mm_blendv_ps(inf, c, m), _mm_blendv_ps(ninf, c, m));
        b1.grow(_mm_blendv_ps(lo, inf, m), _mm_blendv_ps(hi_area, ninf, m));
        c1.grow(_mm_blendv_ps(c, inf, m), _mm_blendv_ps(c, ninf, m));
    }
    PartitionResult r;
    r.acc.bounds[0] = b0;
    r.acc.bounds[1] = b1;
    r.acc.cbounds[0] = c0;
    r.acc.cbounds[1] = c1;
    r.mid = mid;
    return r;
}
#else
inline PartitionResult partition_by_mask(PrimRef* refs, uint32_t begin, uint32_t end, uint32_t left) {
    const uint32_t n = end - begin;
    PrimRef copy[kExactMaxPrims];
    std::copy(refs + begin, refs + end, copy);
    ChildBounds4 acc;
    uint32_t at = begin;
    for (int side = 0; side < 2; ++side)
        for (uint32_t i = 0; i < n; ++i) {
            if (((left >> i) & 1) == uint32_t(side)) continue;  // side 0 takes the mask's records
            const PrimRef& x = copy[i];
            const __m128 lo = simd::lo(x);
            acc.add(side, lo, simd::hi_area(x), simd::centroid(lo, simd::hi(x)));
            refs[at++] = x;
        }
    return PartitionResult{acc, begin + uint32_t(std::popcount(left))};
}
#endif

}  // namespace canopy
