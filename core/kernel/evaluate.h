// canopy: step 2 of the node task, evaluation: the SAH cost of the bins-1
// planes on every valid axis, swept on the three axes at once, and the best
// split.
#pragma once

#include "bin_mapper.h"
#include "bins.h"

#include <bit>
#include <cstdint>

namespace canopy {

// The best split found by evaluate() (or by the size split, size_split.h).
struct Split {
    static constexpr int kSizeAxis = 3;  // a size split, not a plane
    int axis = -1;        // -1: no split exists
    uint32_t index = 0;   // bins [0, index) go left, [index, bins) right
    double cost = 0.0;    // C_t + C_i * (A_L n_L + A_R n_R) / A
    uint32_t left_count = 0;
    float size_cut = 0.0f;  // size split: area < size_cut goes left
    bool found() const { return axis >= 0; }
    bool by_size() const { return axis == kSizeAxis; }
};

// The area measure of the SAH. When the node's box has zero half area (all
// primitives on a line), the half area cannot rank splits, and the sum of
// extents is used instead.
inline double area_measure(const Box& b, bool use_length) {
    if (b.is_empty()) return 0.0;
    return use_length ? b.extent(0) + b.extent(1) + b.extent(2) : b.half_area();
}

// A node's SAH measure (simd::Measure: the half area, or the sum of extents
// for a node of zero area) and the cost of a split from its A_L n_L + A_R n_R
// in that measure: C_t + C_i * sum / A. Not `valid` when the node's own
// measure is zero: no split can be costed then (no split is found).
struct NodeCosts {
    simd::Measure measure;
    double inv_parent = 0.0;
    bool valid = false;
    [[gnu::always_inline]] explicit NodeCosts(const Box& node) : measure(node, !(node.half_area() > 0.0)) {
        const float parent = measure(simd::Box4::of(node));
        valid = parent > 0.0f;
        // Taken first, the division runs beside the sweeps instead of after them.
        if (valid) inv_parent = 1.0 / double(parent);
    }
    double cost(float sum, const BuildOptions& opt) const {
        return double(opt.traversal_cost) + double(opt.intersection_cost) * double(sum) * inv_parent;
    }
};

// Step 2: evaluate the bins-1 partitions on every valid axis by a suffix
// sweep (right areas) and a prefix sweep (left areas). Ties go to the lowest
// axis, then the lowest split index.
namespace detail {
// The sweeps for m.bins bins, or for exactly Fixed bins (Fixed > 0): the
// same operations in the same order, with loops of a known trip count that
// the compiler unrolls and whose sweep values stay in registers.
//
// Counts convert to float with the signed conversion, exact below 2^31. A
// node of 2^31 primitives or more (Huge) needs the unsigned one; that is
// found after the sweeps, from the node's count (the sweep's total), and the
// sweeps are then run again with it. (Summing the counts first, to choose
// before sweeping, was about 1% of the cow's build instructions.)
//
// The result is written into `best` field by field (set to Split{} first), not
// returned: a Split returned through memory was copied in 16-byte pieces
// across fields stored one by one, which cannot forward from store to load.
// Returns true for a node of 2^31 primitives or more seen with the signed
// conversion (`best` is then no split).
template <uint32_t Fixed, bool Huge>
bool evaluate_sweeps(const BinSet& bins, const BinMapper& m, const Box& node_bounds, const BuildOptions& opt,
                     Split& best) {
    best = Split{};
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    const uint32_t nb = Fixed ? Fixed : m.bins;
    // The three axes are swept together, one lane each (lane 3 unused).
    // Bin b's counts as one vector: with packed counts gathered from the
    // bins' lanes 3 (BinArrays::count_row()), otherwise transposed four bins
    // at a time (clear() zeroes counts in groups of four, so a group past the
    // last bin reads zeros).
    static_assert(kMaxBins % 4 == 0 && (Fixed % 4 == 0));
    __m128i count_rows[Fixed ? Fixed : kMaxBins];
#if CANOPY_PACKED_COUNTS
    for (uint32_t b = 0; b < nb; ++b) count_rows[b] = bins.count_row(b);
#else
    for (uint32_t b = 0; b < nb; b += 4) {
        const auto row = [&](int a) {
            return _mm_castsi128_ps(
                _mm_loadu_si128(reinterpret_cast<const __m128i*>(bins.counts + size_t(a) * bins.stride + b)));
        };
        __m128 x = row(0), y = row(1), z = row(2), w = _mm_setzero_ps();
        _MM_TRANSPOSE4_PS(x, y, z, w);
        count_rows[b] = _mm_castps_si128(x);
        count_rows[b + 1] = _mm_castps_si128(y);
        count_rows[b + 2] = _mm_castps_si128(z);
        count_rows[b + 3] = _mm_castps_si128(w);
    }
#endif
    const auto counts = [&](uint32_t b) { return count_rows[b]; };
    const __m128i zero = _mm_setzero_si128();
    const auto to_float = [](__m128i c) { return Huge ? simd::to_float(c) : _mm_cvtepi32_ps(c); };
    __m128 right_cost[Fixed ? Fixed : kMaxBins];  // A_R n_R of the split before bin b; -1: empty
    // The sweeps' boxes start as empty bins. With packed counts their lane 3
    // starts at 0, so that the minimum with the bins' counts (small integers,
    // as floats subnormal) stays 0: Measure then computes with no subnormal.
    const simd::MinBox empty = BinArrays::empty();
    const BinArrays::Axes ax = bins.axes();
    simd::MinBox acc[3] = {empty, empty, empty};
    __m128i n = zero;
    for (uint32_t b = nb - 1; b > 0; --b) {
        for (int a = 0; a < 3; ++a) acc[a].grow(ax.a[a][b]);
        n = _mm_add_epi32(n, counts(b));
        const __m128 empty = _mm_castsi128_ps(_mm_cmpeq_epi32(n, zero));
        const __m128 cost = _mm_mul_ps(measure.three(acc), to_float(n));
        right_cost[b] = simd::select(empty, _mm_set1_ps(-1.0f), cost);
    }
    if constexpr (!Huge) {
        // Every lane's total is the node's count (or 0 on an axis not binned).
        if (_mm_movemask_ps(_mm_castsi128_ps(_mm_add_epi32(n, counts(0)))) != 0) {
            return true;
        }
    }
    const __m128 valid = _mm_castsi128_ps(
        _mm_set_epi32(0, m.valid[2] ? -1 : 0, m.valid[1] ? -1 : 0, m.valid[0] ? -1 : 0));
    __m128 best_sum = simd::pos_inf();  // per axis: A_L n_L + A_R n_R of its best split
    __m128 found = _mm_setzero_ps();
    __m128i best_index = zero, best_left = zero;
    for (int a = 0; a < 3; ++a) acc[a] = empty;
    n = zero;
    for (uint32_t s = 1; s < nb; ++s) {
        for (int a = 0; a < 3; ++a) acc[a].grow(ax.a[a][s - 1]);
        n = _mm_add_epi32(n, counts(s - 1));
        const __m128 sum = _mm_add_ps(_mm_mul_ps(measure.three(acc), to_float(n)), right_cost[s]);
        // A candidate: a valid axis, both sides non-empty, and strictly
        // better than the axis's best so far (the lowest index wins ties).
        const __m128 left_empty = _mm_castsi128_ps(_mm_cmpeq_epi32(n, zero));
        const __m128 ok = _mm_andnot_ps(left_empty, _mm_and_ps(valid, _mm_cmpge_ps(right_cost[s], _mm_setzero_ps())));
        const __m128 take = _mm_and_ps(ok, _mm_or_ps(_mm_andnot_ps(found, ok), _mm_cmplt_ps(sum, best_sum)));
        const __m128i takei = _mm_castps_si128(take);
        best_sum = simd::select(take, sum, best_sum);
        best_index = simd::select(takei, _mm_set1_epi32(int32_t(s)), best_index);
        best_left = simd::select(takei, n, best_left);
        found = _mm_or_ps(found, take);
    }
    // Across axes: the lowest cost, the lowest axis on a tie (the sums are
    // finite: measures of at most 3 times counts).
    if (_mm_movemask_ps(found) == 0) return false;
    const __m128 sums = simd::select(found, best_sum, simd::pos_inf());
    __m128 low = _mm_min_ps(sums, _mm_shuffle_ps(sums, sums, _MM_SHUFFLE(2, 3, 0, 1)));
    low = _mm_min_ps(low, _mm_shuffle_ps(low, low, _MM_SHUFFLE(1, 0, 3, 2)));  // the minimum in every lane
    const int a = std::countr_zero(unsigned(_mm_movemask_ps(_mm_and_ps(found, _mm_cmpeq_ps(sums, low)))));
    alignas(16) int32_t idx[4], left[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(idx), best_index);
    _mm_store_si128(reinterpret_cast<__m128i*>(left), best_left);
    best.axis = a;
    best.index = uint32_t(idx[a]);
    best.left_count = uint32_t(left[a]);
    best.cost = costs.cost(_mm_cvtss_f32(low), opt);
    return false;
}
// The sweeps with the signed count conversion, again with the unsigned one
// for a node of 2^31 primitives or more.
template <uint32_t Fixed>
[[gnu::always_inline]] inline Split evaluate_fixed(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                                                   const BuildOptions& opt) {
    Split s;
    if (evaluate_sweeps<Fixed, false>(bins, m, node_bounds, opt, s))
        evaluate_sweeps<Fixed, true>(bins, m, node_bounds, opt, s);
    return s;
}
}  // namespace detail

// Nodes of up to 64 primitives, almost all of the nodes evaluated, have 4,
// 8 or 16 bins (bins_for()), and those of up to 16 primitives (4 bins; up
// to 32 since 2026-12-05) were 4/5 of the evaluations of a 1M sphere: for
// these bin counts the sweeps have a fixed trip count. (The 4-bin case
// with partition_binned(): the sequential build took 0.97x as long on the
// 1M sphere and 0.95x on dragon_vrip_res2, medians of 8 alternated runs, 6%
// fewer instructions.)
[[gnu::always_inline]] inline Split evaluate(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                                             const BuildOptions& opt) {
    switch (m.bins) {
        case 4: return detail::evaluate_fixed<4>(bins, m, node_bounds, opt);
        case 8: return detail::evaluate_fixed<8>(bins, m, node_bounds, opt);
        case 16: return detail::evaluate_fixed<16>(bins, m, node_bounds, opt);
        default: return detail::evaluate_fixed<0>(bins, m, node_bounds, opt);
    }
}

}  // namespace canopy
