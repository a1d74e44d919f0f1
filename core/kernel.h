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
#include <limits>

#include <emmintrin.h>

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

// SSE2 helpers. A PrimRef loads as two 4-lane vectors: (lo, id) and
// (hi, pad). Lane 3 is cleared before any arithmetic, so the id's bits are
// never used as a float (they would be subnormal and slow, and meaningless).
namespace simd {
inline __m128 xyz_mask() { return _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1)); }
inline __m128 lo(const PrimRef& r) { return _mm_and_ps(_mm_load_ps(&r.lo.x), xyz_mask()); }
inline __m128 hi(const PrimRef& r) { return _mm_and_ps(_mm_load_ps(&r.hi.x), xyz_mask()); }
// The centroid, lane for lane the same IEEE operations as centroid().
inline __m128 centroid(__m128 lo, __m128 hi) {
    const __m128 half = _mm_set1_ps(0.5f);
    return _mm_add_ps(_mm_add_ps(_mm_mul_ps(lo, half), _mm_mul_ps(hi, half)), _mm_setzero_ps());
}
inline __m128 vec(const Vec3& v) { return _mm_set_ps(0.0f, v.z, v.y, v.x); }
inline Vec3 vec3(__m128 v) {
    alignas(16) float f[4];
    _mm_store_ps(f, v);
    return {f[0], f[1], f[2]};
}
inline __m128 pos_inf() { return _mm_set1_ps(std::numeric_limits<float>::infinity()); }
inline __m128 neg_inf() { return _mm_set1_ps(-std::numeric_limits<float>::infinity()); }

// A box as two vectors, for accumulation in the hot loops.
struct Box4 {
    __m128 lo = pos_inf();
    __m128 hi = neg_inf();
    void grow(__m128 l, __m128 h) {
        lo = _mm_min_ps(lo, l);
        hi = _mm_max_ps(hi, h);
    }
    void grow(const Box4& b) { grow(b.lo, b.hi); }
    Box box() const { return Box{vec3(lo), vec3(hi)}; }
};

// Half area (or, with use_length, the sum of extents) of a box, in double.
inline double measure(const Box4& b, bool use_length) {
    const __m128d lxy = _mm_cvtps_pd(b.lo), hxy = _mm_cvtps_pd(b.hi);
    const __m128d lz = _mm_cvtps_pd(_mm_movehl_ps(b.lo, b.lo)), hz = _mm_cvtps_pd(_mm_movehl_ps(b.hi, b.hi));
    const __m128d dxy = _mm_sub_pd(hxy, lxy);
    const double dz = _mm_cvtsd_f64(_mm_sub_pd(hz, lz));
    const double dx = _mm_cvtsd_f64(dxy), dy = _mm_cvtsd_f64(_mm_unpackhi_pd(dxy, dxy));
    return use_length ? dx + dy + dz : dx * dy + dy * dz + dz * dx;
}
}  // namespace simd

// Maps a centroid to its bin on each axis. The one mapping used by both
// bin() and partition(), so the partition agrees with the counts evaluated.
struct BinMapper {
    Vec3 origin{0.0f};
    Vec3 scale{0.0f};  // 0 on axes that are not valid
    uint32_t bins = 0;
    std::array<bool, 3> valid{false, false, false};  // axis can be split
    __m128 origin4 = _mm_setzero_ps(), scale4 = _mm_setzero_ps(), last4 = _mm_setzero_ps();

    // scale = 0.99 * bins / extent (Embree's safe scale): the largest
    // centroid falls inside the last bin. An axis is skipped when its extent
    // is zero, when the scale is not finite (a subnormal extent), or when the
    // largest centroid still maps to bin 0.
    static BinMapper make(const Box& cbounds, uint32_t bins) {
        BinMapper m;
        m.origin = cbounds.lo;
        m.bins = bins;
        m.origin4 = simd::vec(m.origin);
        m.last4 = _mm_set1_ps(float(bins - 1));
        for (int a = 0; a < 3; ++a) {
            const double ext = cbounds.extent(a);
            if (!(ext > 0.0)) continue;
            const float sf = static_cast<float>(0.99 * double(bins) / ext);
            if (!std::isfinite(sf) || !(sf > 0.0f)) continue;
            m.scale[a] = sf;
            m.scale4 = simd::vec(m.scale);
            m.valid[a] = m.indices(simd::vec(cbounds.hi))[a] > 0;
            if (!m.valid[a]) m.scale[a] = 0.0f;
        }
        m.scale4 = simd::vec(m.scale);
        return m;
    }
    bool any_valid() const { return valid[0] || valid[1] || valid[2]; }
    int valid_count() const { return valid[0] + valid[1] + valid[2]; }

    // The bin of a centroid on each axis: floor of (c - origin) * scale,
    // clamped to [0, bins - 1] before the conversion (so no out-of-range
    // float-to-int conversion can happen, even for an infinite product).
    std::array<int32_t, 4> indices(__m128 c) const {
        __m128 f = _mm_mul_ps(_mm_sub_ps(c, origin4), scale4);
        f = _mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), last4);
        alignas(16) std::array<int32_t, 4> k;
        _mm_store_si128(reinterpret_cast<__m128i*>(k.data()), _mm_cvttps_epi32(f));
        return k;
    }
    uint32_t index(const Vec3& c, int axis) const { return static_cast<uint32_t>(indices(simd::vec(c))[axis]); }
};

// Per-axis bins: the box of the primitives and their count.
struct BinSet {
    simd::Box4 box4[3][kMaxBins];
    uint32_t count[3][kMaxBins];

    Box box(int axis, uint32_t b) const { return box4[axis][b].box(); }
    void clear(uint32_t bins) {
        for (int a = 0; a < 3; ++a) {
            std::fill_n(box4[a], bins, simd::Box4{});
            std::fill_n(count[a], bins, 0u);
        }
    }
    // Exact merge (min/max and integer sums): order-independent.
    void merge(const BinSet& o, uint32_t bins) {
        for (int a = 0; a < 3; ++a)
            for (uint32_t b = 0; b < bins; ++b) {
                box4[a][b].grow(o.box4[a][b]);
                count[a][b] += o.count[a][b];
            }
    }
};

// Step 1: bin the centroids of refs[begin, end) on every valid axis, in one
// pass; axes that are not valid are not binned. Accumulates into `out`
// (clear it first).
inline void bin(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out) {
    int axes[3], na = 0;
    for (int a = 0; a < 3; ++a)
        if (m.valid[a]) axes[na++] = a;
    for (uint32_t i = begin; i < end; ++i) {
        const __m128 lo = simd::lo(refs[i]), hi = simd::hi(refs[i]);
        const auto k = m.indices(simd::centroid(lo, hi));
        for (int j = 0; j < na; ++j) {
            const int a = axes[j];
            out.box4[a][k[a]].grow(lo, hi);
            out.count[a][k[a]]++;
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

// Step 2: evaluate the bins-1 partitions on every valid axis by a suffix
// sweep (right areas) and a prefix sweep (left areas), in double. Ties go to
// the lowest axis, then the lowest split index.
inline Split evaluate(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                      const BuildOptions& opt) {
    Split best;
    const bool use_length = !(node_bounds.half_area() > 0.0);
    const double parent = area_measure(node_bounds, use_length);
    if (!(parent > 0.0)) return best;
    const uint32_t nb = m.bins;
    const double ct = opt.traversal_cost, ci_over_parent = opt.intersection_cost / parent;
    double right_cost[kMaxBins];
    for (int a = 0; a < 3; ++a) {
        if (!m.valid[a]) continue;
        simd::Box4 acc;
        uint32_t n = 0;
        for (uint32_t b = nb - 1; b > 0; --b) {
            acc.grow(bins.box4[a][b]);
            n += bins.count[a][b];
            right_cost[b] = n ? simd::measure(acc, use_length) * double(n) : -1.0;
        }
        acc = simd::Box4{};
        n = 0;
        for (uint32_t s = 1; s < nb; ++s) {
            acc.grow(bins.box4[a][s - 1]);
            n += bins.count[a][s - 1];
            if (n == 0 || right_cost[s] < 0.0) continue;
            const double cost = ct + ci_over_parent * (simd::measure(acc, use_length) * double(n) + right_cost[s]);
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

// Child bounds and centroid bounds, accumulated while partitioning.
struct ChildBounds4 {
    simd::Box4 bounds[2], cbounds[2];  // [0] left, [1] right
    void add(int side, __m128 lo, __m128 hi, __m128 c) {
        bounds[side].grow(lo, hi);
        cbounds[side].grow(c, c);
    }
    void into(PartitionResult& r) const {
        r.left_bounds = bounds[0].box();
        r.right_bounds = bounds[1].box();
        r.left_cbounds = cbounds[0].box();
        r.right_cbounds = cbounds[1].box();
    }
};

inline bool goes_left(const PrimRef& r, const BinMapper& m, const Split& s) {
    return uint32_t(m.indices(simd::centroid(simd::lo(r), simd::hi(r)))[s.axis]) < s.index;
}

// Step 3: the stable partition of refs[begin, end) around the split, with
// scratch[begin, end) as the one scratch array. Child bounds are
// accumulated in the same pass.
inline PartitionResult partition(PrimRef* refs, PrimRef* scratch, uint32_t begin, uint32_t end,
                                 const BinMapper& m, const Split& s) {
    ChildBounds4 acc;
    uint32_t nl = begin, nr = begin;
    for (uint32_t i = begin; i < end; ++i) {
        const PrimRef r = refs[i];
        const __m128 lo = simd::lo(r), hi = simd::hi(r), c = simd::centroid(lo, hi);
        const bool left = uint32_t(m.indices(c)[s.axis]) < s.index;
        refs[nl] = r;  // nl <= i: never overwrites an unread record
        scratch[nr] = r;
        nl += left;
        nr += !left;
        acc.add(!left, lo, hi, c);
    }
    std::memcpy(static_cast<void*>(refs + nl), scratch + begin, size_t(nr - begin) * sizeof(PrimRef));
    PartitionResult res;
    acc.into(res);
    res.mid = nl;
    return res;
}

// Blocked pieces of the same partition, for parallel schedulers. Any block
// size gives the same result (the stable partition is unique).
inline constexpr uint32_t kPartitionBlock = 16384;

// Counts the left-going primitives of refs[b, e) and accumulates the child
// bounds (res.mid holds the left count).
inline PartitionResult partition_count(const PrimRef* refs, uint32_t b, uint32_t e,
                                       const BinMapper& m, const Split& s) {
    ChildBounds4 acc;
    uint32_t nl = 0;
    for (uint32_t i = b; i < e; ++i) {
        const __m128 lo = simd::lo(refs[i]), hi = simd::hi(refs[i]), c = simd::centroid(lo, hi);
        const bool left = uint32_t(m.indices(c)[s.axis]) < s.index;
        nl += left;
        acc.add(!left, lo, hi, c);
    }
    PartitionResult res;
    acc.into(res);
    res.mid = nl;
    return res;
}

// Copies the records of refs[b, e) in order: left-going ones from left_out
// on, right-going ones from right_out on.
inline void partition_scatter(const PrimRef* refs, uint32_t b, uint32_t e, const BinMapper& m,
                              const Split& s, PrimRef* left_out, PrimRef* right_out) {
    for (uint32_t i = b; i < e; ++i) {
        const PrimRef& r = refs[i];
        if (goes_left(r, m, s))
            *left_out++ = r;
        else
            *right_out++ = r;
    }
}

// Bounds of refs[b, e) as one side of a middle split.
inline void grow_range(const PrimRef* refs, uint32_t b, uint32_t e, ChildBounds4& acc, int side) {
    for (uint32_t i = b; i < e; ++i) {
        const __m128 lo = simd::lo(refs[i]), hi = simd::hi(refs[i]);
        acc.add(side, lo, hi, simd::centroid(lo, hi));
    }
}

// The middle split: [begin, mid) and [mid, end) in their current order, for
// nodes with no SAH split and for the depth cap. Bounds by one pass.
inline PartitionResult middle_split(const PrimRef* refs, uint32_t begin, uint32_t end) {
    ChildBounds4 acc;
    const uint32_t mid = begin + (end - begin) / 2;
    grow_range(refs, begin, mid, acc, 0);
    grow_range(refs, mid, end, acc, 1);
    PartitionResult res;
    acc.into(res);
    res.mid = mid;
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
    PrimRef* refs;
    PrimRef* scratch;
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
        part = middle_split(ctx.refs, t.begin, t.end);
    } else {
        const BinMapper m = BinMapper::make(t.cbounds, bins_for(t.size(), opt.bins));
        if (!m.any_valid()) {
            ++skip.coincident_nodes;
            if (t.size() <= opt.max_leaf) return false;
            part = middle_split(ctx.refs, t.begin, t.end);
        } else {
            skip.axes_not_binned += 3 - (m.valid[0] + m.valid[1] + m.valid[2]);
            bins.clear(m.bins);
            bin(ctx.refs, t.begin, t.end, m, bins);
            const Split s = evaluate(bins, m, t.bounds, opt);
            if (sah_says_leaf(s, t.size(), opt)) return false;
            if (s.found())
                part = partition(ctx.refs, ctx.scratch, t.begin, t.end, m, s);
            else
                part = middle_split(ctx.refs, t.begin, t.end);
        }
    }
    emit(t, part, children);
    return true;
}

}  // namespace canopy
