// canopy: the node-task kernel of binned SAH, in four steps that can each be
// called alone, one header each under kernel/: bin (bin.h), evaluate
// (evaluate.h), partition (partition.h), emit (emit.h); and run_node(),
// below, the whole node task that drives them. Every scheduler drives these
// same functions; nothing here knows about threads.
//
// Beside the steps: the node task itself (task.h), the SIMD vocabulary
// (simd.h), the mapping of centroids to bins (bin_mapper.h), the bins
// (bins.h), the most common node binned and evaluated in registers
// (register_bins.h), the size split (size_split.h), the middle split
// (middle_split.h), small nodes split exactly (small_node.h), and the pieces
// of a partition a team runs on one big node (team_partition.h).
//
// The records live in one buffer; each node task owns a contiguous range of
// it, and a leaf writes its primitive ids straight to the permutation.
#pragma once

// The headers each piece uses, first, in one order: GCC's choices of what
// to inline depend a little on the order of the declarations it sees, and
// in this order the build compiles to the same machine code as when the
// pieces were one file (checked with objdump on 2026-12-07).
#include "geometry.h"
#include "options.h"
#include "primitives.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cassert>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <type_traits>
#include <vector>

#include <emmintrin.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

// The pieces, each after the ones it builds on.
#include "kernel/task.h"
#include "kernel/simd.h"
#include "kernel/bin_mapper.h"
#include "kernel/bins.h"
#include "kernel/bin.h"
#include "kernel/evaluate.h"
#include "kernel/register_bins.h"
#include "kernel/size_split.h"
#include "kernel/partition.h"
#include "kernel/team_partition.h"
#include "kernel/middle_split.h"
#include "kernel/emit.h"
#include "kernel/small_node.h"

namespace canopy {

inline uint32_t ceil_log2(uint32_t n) { return n <= 1 ? 0 : 32 - std::countl_zero(n - 1); }

// What to do with a node before any binning.
enum class Plan { Leaf, Middle, Sah };

inline Plan plan(const NodeTask& t, const BuildOptions& opt, SkipCounts& skip) {
    const uint32_t n = t.size();
    if (n <= 1) {
        ++skip.single_leaves;
        return Plan::Leaf;
    }
    const uint32_t budget = opt.max_depth > t.depth ? opt.max_depth - t.depth : 0;
    if (budget <= ceil_log2(n)) {
        if (n <= opt.max_leaf) return Plan::Leaf;
        ++skip.depth_cap_splits;
        return Plan::Middle;
    }
    return Plan::Sah;
}

// The SAH verdict on a node that was binned and evaluated: leaf when the
// node fits in a leaf and no split is cheaper than intersecting everything.
inline bool sah_says_leaf(bool found, double cost, uint32_t n, const BuildOptions& opt) {
    if (n > opt.max_leaf) return false;
    return !found || cost >= double(opt.intersection_cost) * double(n);
}
inline bool sah_says_leaf(const Split& s, uint32_t n, const BuildOptions& opt) {
    return sah_says_leaf(s.found(), s.cost, n, opt);
}

// A node that fits in a leaf becomes one when no split is cheaper. Every
// split costs at least C_t + C_i * (sum of the primitives' own half areas) / A,
// because each side's box contains the boxes of its primitives
// (A_L n_L >= sum over the left primitives of their areas, and so on). When
// that lower bound already reaches the leaf's cost C_i * n, binning and
// evaluating would only confirm the leaf, so they are skipped: the tree is the
// same. The bound is taken with a relative margin of 2^-12, far above the
// rounding of the scaled float areas evaluate() compares (a few float ulps),
// and only for nodes whose area is not tiny against their squared extent
// (where those float areas are normal numbers); otherwise the node is
// evaluated as usual.
inline bool leaf_by_bound(const PrimRef* refs, const NodeTask& t, const BuildOptions& opt) {
    const double area = t.bounds.half_area();
    const double ext = std::max({t.bounds.extent(0), t.bounds.extent(1), t.bounds.extent(2)});
    if (!(area > ext * ext * 0x1p-40)) return false;
    // The records' stored areas (prim_area()): each within a float rounding
    // (2^-24, relative) of the box's exact half area, or below it (0 under
    // the smallest normal float, saturated at the largest), so the sum stays
    // a lower bound within the margin.
    double sum = 0.0;
    for (uint32_t i = t.begin; i < t.end; ++i) sum += double(refs[i].area);
    // C_t + C_i * (sum / A) * (1 - 2^-12) >= C_i * n, multiplied out by A > 0
    // (no division: its latency sat on the path to the node's next step).
    return double(opt.intersection_cost) * sum * (1.0 - 0x1p-12) >=
           (double(opt.intersection_cost) * double(t.size()) - double(opt.traversal_cost)) * area;
}

// From a node's sample binned into `sample`: m.only() the axis of its
// cheapest split, or `m` when it shows none (run_node() and a team's
// choose_axis() alike).
inline BinMapper mapper_from_sample(const BinSet& sample, const BinMapper& m, const Box& node_bounds,
                                    const BuildOptions& opt, SkipCounts& skip) {
    const Split guess = evaluate(sample, m, node_bounds, opt);
    if (!guess.found()) return m;
    ++skip.sampled_axes;
    return m.only(guess.axis);
}
// The mapping a node is binned with: `m` itself, or for a node that
// samples (samples_axis()) the one mapper_from_sample() gives.
inline BinMapper binning_mapper(const PrimRef* refs, const NodeTask& t, const BinMapper& m, BinSet& bins,
                                const BuildOptions& opt, SkipCounts& skip) {
    if (!samples_axis(m, t.size())) return m;
    bins.clear(m.bins);
    bin_sample(refs, t.begin, t.end, sample_step(t), m, bins);
    return mapper_from_sample(bins, m, t.bounds, opt, skip);
}

class TraceLog;
class CarriedSplits;

// Everything a node task needs besides its own range.
struct KernelContext {
    PrimRef* refs;           // the records, partitioned in place
    uint32_t* permutation;   // leaves write their ids here
    const BuildOptions* options;
    TraceLog* trace;         // null unless the build is traced (see trace.h)
    // Other threads work on the records too: a big node's lines may be in
    // other cores' caches (see prefetch_for_write()). Speed only.
    bool shared = false;
    // The splits chosen for tasks before they run (kernel/rotate.h); null:
    // no rotations.
    CarriedSplits* carry = nullptr;
};

// Writes a leaf's primitive ids to the permutation.
inline void write_leaf(const KernelContext& ctx, const NodeTask& t) {
    for (uint32_t i = t.begin; i < t.end; ++i) ctx.permutation[i] = ctx.refs[i].id;
}

// Steps 1 and 2 for a node that is binned (more than kExactMaxPrims
// primitives whose centroids are not all equal), with mapping `m` (from
// binning_mapper()): returns its cheapest split, by a plane or by size. A
// node of more than kBinBlock primitives, which is partitioned by its keys,
// leaves them in the permutation's slots of its range, which only its
// leaves write, later (run_node(), or its task after choose_ahead()).
[[gnu::always_inline]] inline Split bin_and_evaluate(const KernelContext& ctx, const NodeTask& t, const BinMapper& m,
                                                      BinSet& bins, SkipCounts& skip) {
    const BuildOptions& opt = *ctx.options;
    uint32_t* const keys = t.size() > kBinBlock ? ctx.permutation : nullptr;
    Split s;
#if CANOPY_REGISTER_BINS
    if (m.bins == 4 && !m.prescaled && t.size() <= kBinBlock) {
        s = bin_evaluate_4(ctx.refs, t.begin, t.end, m, bins, t.bounds, opt);
    } else
#endif
    {
        bins.clear(m.bins);
        bin(ctx.refs, t.begin, t.end, m, bins, keys);
        s = evaluate(bins, m, t.bounds, opt);
    }
    if (t.size() >= kSizeSplitMinPrims) {
        const SizeCuts cuts = SizeCuts::of(t.bounds);
        if (cuts.applies(t)) {
            SizeBins sizes;
            bin_sizes(ctx.refs, t.begin, t.end, cuts, sizes);
            consider_size_split(sizes, cuts, t.bounds, opt, s);
            skip.size_splits += s.by_size();
        }
    }
    return s;
}

}  // namespace canopy

// Rotations, which choose children's splits with the steps above.
#include "kernel/rotate.h"

namespace canopy {

// The whole node task, sequentially: returns false for a leaf (whose ids it
// wrote to the permutation), true when it wrote two child tasks to
// `children`. `bins` is per-worker scratch.
inline bool run_node(const KernelContext& ctx, const NodeTask& t, NodeTask children[2],
                     BinSet& bins, SkipCounts& skip) {
    // Each split emits straight from the partition's result, which the
    // partition writes in place (no PartitionResult assigned across the
    // branches: GCC copied it with 64-byte moves, which cannot forward from
    // the partition's 16-byte stores, and emit()'s 4-byte loads then stalled
    // on the copy; about a tenth of run_node()'s own samples).
    const auto split = [&](const PartitionResult& part) {
        emit(t, part, children);
        return true;
    };
    const BuildOptions& opt = *ctx.options;
    // A split by SAH of a node that may be big enough to rotate: middle
    // splits are not rotated, and the other SAH splits are of nodes smaller
    // than kRotateMinPrims (as in ParallelNode::looks_ahead()).
    const auto sah_split = [&](const PartitionResult& part) {
        emit(t, part, children);
        if (t.size() >= opt.rotate_min) [[unlikely]]  // and rotate_min != 0: rotate_children() checks
            rotate_children(ctx, t, children, bins, skip);
        return true;
    };
    const Plan p = plan(t, opt, skip);
    if (p == Plan::Middle) return split(middle_split(ctx.refs, t.begin, t.end));
    if (p != Plan::Sah) {
        write_leaf(ctx, t);
        return false;
    }
    if (t.carried) [[unlikely]] {
        run_chosen(ctx, t, children, bins, skip);
        return true;
    }
    if (t.size() <= opt.max_leaf && leaf_by_bound(ctx.refs, t, opt)) {
        ++skip.bound_leaves;
        write_leaf(ctx, t);
        return false;
    }
    if (t.size() <= kExactMaxPrims) {
        ++skip.exact_nodes;
        uint32_t left = 0;
        double cost = 0.0;
        const bool found = exact_split(ctx.refs + t.begin, t.size(), t.bounds, opt, left, cost);
        if (sah_says_leaf(found, cost, t.size(), opt)) {
            write_leaf(ctx, t);
            return false;
        }
        return found ? split(partition_by_mask(ctx.refs, t.begin, t.end, left))
                     : split(middle_split(ctx.refs, t.begin, t.end));
    }
    const BinMapper full = BinMapper::make(t.cbounds, bins_for(t.size(), opt.bins));
    if (!full.any_valid()) {
        ++skip.coincident_nodes;
        if (t.size() <= opt.max_leaf) {
            write_leaf(ctx, t);
            return false;
        }
        return split(middle_split(ctx.refs, t.begin, t.end));
    }
    skip.axes_not_binned += 3 - full.valid_count();
    assert(full.bins <= bins.max_bins());
    const BinMapper m = binning_mapper(ctx.refs, t, full, bins, opt, skip);
    const Split s = bin_and_evaluate(ctx, t, m, bins, skip);
    if (sah_says_leaf(s, t.size(), opt)) {
        write_leaf(ctx, t);
        return false;
    }
    if (!s.found()) return split(middle_split(ctx.refs, t.begin, t.end));
    if (s.by_size()) return sah_split(partition(ctx.refs, t.begin, t.end, m, s));
    static_assert(kBinBlock < kRotateMinPrims);
    if (t.size() <= kBinBlock) return split(partition_binned(ctx.refs, t.begin, t.end, s, bins));
    PartitionResult part = partition_by_keys(ctx.refs, t.begin, t.end, s, ctx.permutation, ctx.shared);
    bounds_from_bins(bins, m, t, s, part);
    return sah_split(part);
}

}  // namespace canopy
