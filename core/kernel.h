// canopy: the node-task kernel of binned SAH, in four steps that can each be
// called alone: bin, evaluate, partition, emit. Every scheduler drives these
// same functions; nothing here knows about threads.
//
// The canonical partition order is the *stable* partition: the primitives
// going left keep their relative order, followed by those going right in
// their relative order. It is unique, so a parallel blocked partition
// (count per block, prefix sum, scatter) reproduces it bit for bit.
#pragma once

#include "geometry.h"
#include "options.h"
#include "primitives.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cstring>

namespace canopy {

// A node task: a range of the permutation and what its parent knew of it.
struct NodeTask {
    uint32_t begin = 0;
    uint32_t end = 0;
    Box bounds;   // union of the primitives' boxes
    Box cbounds;  // union of the primitives' centroids
    uint32_t depth = 0;
    // Where the node sits, for schedulers that place nodes by arithmetic
    // (see layout.h): the parent's begin, how many right turns lead here,
    // and whether this is a right child.
    uint32_t parent_begin = 0;
    uint8_t rights = 0;
    bool is_right = false;

    uint32_t size() const { return end - begin; }
};

// Counters of work skipped, summed over a build. Integers only, so the sums
// do not depend on the order workers add them.
struct SkipCounts {
    uint64_t axes_not_binned = 0;     // axes with (numerically) zero centroid extent
    uint64_t coincident_nodes = 0;    // all centroids equal: middle split / leaf, no evaluation
    uint64_t depth_cap_splits = 0;    // middle splits forced by the depth budget
    uint64_t single_leaves = 0;       // one-primitive nodes, no binning
    uint64_t inline_tasks = 0;        // node tasks run inline below the task cutoff
    uint64_t parallel_nodes = 0;      // nodes binned and partitioned by the whole team

    void add(const SkipCounts& o) {
        axes_not_binned += o.axes_not_binned;
        coincident_nodes += o.coincident_nodes;
        depth_cap_splits += o.depth_cap_splits;
        single_leaves += o.single_leaves;
        inline_tasks += o.inline_tasks;
        parallel_nodes += o.parallel_nodes;
    }
};

// Bins for a node of n primitives: min(bins, max(4, bit_ceil(n) / 2)), and at
// least 2. Small nodes, which are most nodes, use fewer bins: clearing and
// sweeping bins is the fixed cost of a node.
inline uint32_t bins_for(uint32_t n, uint32_t bins) {
    const uint32_t half = n >= 2 ? std::bit_ceil(n) / 2 : 1;
    return std::max(kMinBins, std::min(bins, std::max(4u, half)));
}

// Maps a centroid coordinate to its bin. The one mapping used by both bin()
// and partition(), so the partition agrees with the counts evaluated.
struct BinMapper {
    Vec3 origin{0.0f};
    Vec3 scale{0.0f};
    uint32_t bins = 0;
    std::array<bool, 3> valid{false, false, false};  // axis can be split

    // scale = 0.99 * bins / extent (Embree's safe scale): the largest
    // centroid falls inside the last bin. An axis is skipped when its extent
    // is zero, when the scale is not finite (a subnormal extent), or when the
    // largest centroid still maps to bin 0.
    static BinMapper make(const Box& cbounds, uint32_t bins) {
        BinMapper m;
        m.origin = cbounds.lo;
        m.bins = bins;
        for (int a = 0; a < 3; ++a) {
            const double ext = cbounds.extent(a);
            if (!(ext > 0.0)) continue;
            const double s = 0.99 * double(bins) / ext;
            const float sf = static_cast<float>(s);
            if (!std::isfinite(sf) || !(sf > 0.0f)) continue;
            m.scale[a] = sf;
            m.valid[a] = m.index(cbounds.hi[a], a) > 0;
            if (!m.valid[a]) m.scale[a] = 0.0f;
        }
        return m;
    }
    bool any_valid() const { return valid[0] || valid[1] || valid[2]; }

    uint32_t index(float c, int axis) const {
        float f = (c - origin[axis]) * scale[axis];
        f = std::min(std::max(f, 0.0f), float(bins - 1));
        return static_cast<uint32_t>(f);
    }
};

// Per-axis bins: the box of the primitives and their count.
struct BinSet {
    Box box[3][kMaxBins];
    uint32_t count[3][kMaxBins];

    void clear(uint32_t bins) {
        for (int a = 0; a < 3; ++a) {
            std::fill_n(box[a], bins, Box{});
            std::fill_n(count[a], bins, 0u);
        }
    }
    // Exact merge (min/max and integer sums): order-independent.
    void merge(const BinSet& o, uint32_t bins) {
        for (int a = 0; a < 3; ++a)
            for (uint32_t b = 0; b < bins; ++b) {
                box[a][b].extend(o.box[a][b]);
                count[a][b] += o.count[a][b];
            }
    }
};

// Step 1: bin the centroids of ids[begin, end) on every valid axis, in one
// pass. Accumulates into `out` (clear it first).
inline void bin(const PrimRef* refs, const uint32_t* ids, uint32_t begin, uint32_t end,
                const BinMapper& m, BinSet& out) {
    for (uint32_t i = begin; i < end; ++i) {
        const PrimRef& r = refs[ids[i]];
        for (int a = 0; a < 3; ++a) {
            if (!m.valid[a]) continue;
            const uint32_t k = m.index(r.c[a], a);
            Box& b = out.box[a][k];
            b.lo = glm::min(b.lo, r.lo);
            b.hi = glm::max(b.hi, r.hi);
            out.count[a][k]++;
        }
    }
}

// The best split found by evaluate().
struct Split {
    int axis = -1;        // -1: no split exists
    uint32_t index = 0;   // bins [0, index) go left, [index, bins) right
    double cost = 0.0;    // C_t + C_i * (A_L n_L + A_R n_R) / A
    uint32_t left_count = 0;
    bool found() const { return axis >= 0; }
};

// The area measure of the SAH. When the node's box has zero half area (all
// primitives on a line), the half area cannot rank splits, and the sum of
// extents is used instead.
inline double area_measure(const Box& b, bool use_length) {
    if (b.is_empty()) return 0.0;
    return use_length ? b.extent(0) + b.extent(1) + b.extent(2) : b.half_area();
}

// Step 2: evaluate the bins-1 partitions on every valid axis by a prefix
// sweep (left areas) and a suffix sweep (right areas). Ties go to the lowest
// axis, then the lowest split index.
inline Split evaluate(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                      const BuildOptions& opt) {
    Split best;
    bool use_length = !(node_bounds.half_area() > 0.0);
    const double parent = area_measure(node_bounds, use_length);
    if (!(parent > 0.0)) return best;
    const uint32_t nb = m.bins;
    double right_cost[kMaxBins];
    for (int a = 0; a < 3; ++a) {
        if (!m.valid[a]) continue;
        Box acc;
        uint32_t n = 0;
        for (uint32_t b = nb - 1; b > 0; --b) {
            acc.extend(bins.box[a][b]);
            n += bins.count[a][b];
            right_cost[b] = n ? area_measure(acc, use_length) * double(n) : -1.0;
        }
        acc = Box{};
        n = 0;
        for (uint32_t s = 1; s < nb; ++s) {
            acc.extend(bins.box[a][s - 1]);
            n += bins.count[a][s - 1];
            if (n == 0 || right_cost[s] < 0.0) continue;
            const double cost = opt.traversal_cost +
                                opt.intersection_cost * (area_measure(acc, use_length) * double(n) +
                                                         right_cost[s]) / parent;
            if (!best.found() || cost < best.cost) {
                best.axis = a;
                best.index = s;
                best.cost = cost;
                best.left_count = n;
            }
        }
    }
    return best;
}

// What a partition (or a middle split) leaves: where the right child starts,
// and both children's bounds and centroid bounds, accumulated on the way.
struct PartitionResult {
    uint32_t mid = 0;
    Box left_bounds, left_cbounds, right_bounds, right_cbounds;

    void merge(const PartitionResult& o) {  // for blocked partitions
        left_bounds.extend(o.left_bounds);
        left_cbounds.extend(o.left_cbounds);
        right_bounds.extend(o.right_bounds);
        right_cbounds.extend(o.right_cbounds);
    }
};

inline bool goes_left(const PrimRef& r, const BinMapper& m, const Split& s) {
    return m.index(r.c[s.axis], s.axis) < s.index;
}

inline void grow(Box& bounds, Box& cbounds, const PrimRef& r) {
    bounds.lo = glm::min(bounds.lo, r.lo);
    bounds.hi = glm::max(bounds.hi, r.hi);
    cbounds.extend(r.c);
}

// Step 3: the stable partition of ids[begin, end) around the split, with
// scratch[begin, end) as the one scratch id array. Child bounds are
// accumulated in the same pass.
inline PartitionResult partition(const PrimRef* refs, uint32_t* ids, uint32_t* scratch,
                                 uint32_t begin, uint32_t end, const BinMapper& m,
                                 const Split& s) {
    PartitionResult res;
    uint32_t nl = begin, nr = begin;
    for (uint32_t i = begin; i < end; ++i) {
        const uint32_t id = ids[i];
        const PrimRef& r = refs[id];
        const bool left = goes_left(r, m, s);
        ids[nl] = id;  // nl <= i: never overwrites an unread id
        scratch[nr] = id;
        nl += left;
        nr += !left;
        if (left)
            grow(res.left_bounds, res.left_cbounds, r);
        else
            grow(res.right_bounds, res.right_cbounds, r);
    }
    std::memcpy(ids + nl, scratch + begin, size_t(nr - begin) * sizeof(uint32_t));
    res.mid = nl;
    return res;
}

// Blocked pieces of the same partition, for parallel schedulers. A block is
// a fixed-size range (kPartitionBlock, independent of the thread count).
inline constexpr uint32_t kPartitionBlock = 16384;

// Counts the left-going primitives of ids[b, e) and accumulates the child
// bounds (res.mid holds the left count).
inline PartitionResult partition_count(const PrimRef* refs, const uint32_t* ids, uint32_t b,
                                       uint32_t e, const BinMapper& m, const Split& s) {
    PartitionResult res;
    uint32_t nl = 0;
    for (uint32_t i = b; i < e; ++i) {
        const PrimRef& r = refs[ids[i]];
        if (goes_left(r, m, s)) {
            ++nl;
            grow(res.left_bounds, res.left_cbounds, r);
        } else {
            grow(res.right_bounds, res.right_cbounds, r);
        }
    }
    res.mid = nl;
    return res;
}

// Writes the ids of ids[b, e) in order: left-going ones from left_out on,
// right-going ones from right_out on.
inline void partition_scatter(const PrimRef* refs, const uint32_t* ids, uint32_t b, uint32_t e,
                              const BinMapper& m, const Split& s, uint32_t* left_out,
                              uint32_t* right_out) {
    for (uint32_t i = b; i < e; ++i) {
        const uint32_t id = ids[i];
        const bool left = goes_left(refs[id], m, s);
        *left_out = id;
        *right_out = id;
        left_out += left;
        right_out += !left;
    }
}

// The middle split: [begin, mid) and [mid, end) in their current order, for
// nodes with no SAH split and for the depth cap. Bounds by one pass.
inline PartitionResult middle_split(const PrimRef* refs, const uint32_t* ids, uint32_t begin,
                                    uint32_t end) {
    PartitionResult res;
    res.mid = begin + (end - begin) / 2;
    for (uint32_t i = begin; i < res.mid; ++i) grow(res.left_bounds, res.left_cbounds, refs[ids[i]]);
    for (uint32_t i = res.mid; i < end; ++i) grow(res.right_bounds, res.right_cbounds, refs[ids[i]]);
    return res;
}

// Step 4: the two child tasks of a split node.
inline void emit(const NodeTask& t, const PartitionResult& p, NodeTask out[2]) {
    out[0].begin = t.begin;
    out[0].end = p.mid;
    out[0].bounds = p.left_bounds;
    out[0].cbounds = p.left_cbounds;
    out[1].begin = p.mid;
    out[1].end = t.end;
    out[1].bounds = p.right_bounds;
    out[1].cbounds = p.right_cbounds;
    for (int k = 0; k < 2; ++k) {
        out[k].depth = t.depth + 1;
        out[k].parent_begin = t.begin;
        out[k].is_right = k == 1;
        out[k].rights = static_cast<uint8_t>(t.rights + k);
    }
}

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
inline bool sah_says_leaf(const Split& s, uint32_t n, const BuildOptions& opt) {
    if (n > opt.max_leaf) return false;
    return !s.found() || s.cost >= double(opt.intersection_cost) * double(n);
}

// Everything a node task needs besides its own range.
struct KernelContext {
    const PrimRef* refs;
    uint32_t* ids;
    uint32_t* scratch;
    const BuildOptions* options;
};

// The whole node task, sequentially: returns false for a leaf, true when it
// wrote two child tasks to `children`. `bins` is per-worker scratch.
inline bool run_node(const KernelContext& ctx, const NodeTask& t, NodeTask children[2],
                     BinSet& bins, SkipCounts& skip) {
    const BuildOptions& opt = *ctx.options;
    const Plan p = plan(t, opt, skip);
    if (p == Plan::Leaf) return false;
    PartitionResult part;
    if (p == Plan::Middle) {
        part = middle_split(ctx.refs, ctx.ids, t.begin, t.end);
    } else {
        const BinMapper m = BinMapper::make(t.cbounds, bins_for(t.size(), opt.bins));
        if (!m.any_valid()) {
            ++skip.coincident_nodes;
            if (t.size() <= opt.max_leaf) return false;
            part = middle_split(ctx.refs, ctx.ids, t.begin, t.end);
        } else {
            skip.axes_not_binned += 3 - (m.valid[0] + m.valid[1] + m.valid[2]);
            bins.clear(m.bins);
            bin(ctx.refs, ctx.ids, t.begin, t.end, m, bins);
            const Split s = evaluate(bins, m, t.bounds, opt);
            if (sah_says_leaf(s, t.size(), opt)) return false;
            if (s.found())
                part = partition(ctx.refs, ctx.ids, ctx.scratch, t.begin, t.end, m, s);
            else
                part = middle_split(ctx.refs, ctx.ids, t.begin, t.end);
        }
    }
    emit(t, part, children);
    return true;
}

}  // namespace canopy
