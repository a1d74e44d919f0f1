// canopy: local tree rotations taken during the build.
//
// Binned SAH chooses each split greedily: a node's split is the cheapest by
// its children's boxes alone, and what the children's own splits make of
// them is not looked at. On a scene like the 1M stadium (a dense object in a
// huge sparse box) that leaves nodes near the root whose child would be
// better grouped with a grandchild: the SAH of canopy's tree was 2% above
// Embree's rtcBuildBVH, and a dozen rotations near the root (bench/rotations,
// docs/performance-log.md, 2026-12-07 night) brought it 1% below; the
// build takes six of them (31.73 against 32.02).
//
// A rotation in Kensler's sense ("Tree rotations for improving bounding
// volume hierarchies", 2008): at node N with children A and B, where B has
// children B0 and B1, A trades places with one of B's children (or B with
// one of A's). The boxes of N and of every node outside the three subtrees
// stay the same; only the node whose children change (B) gets another box,
// so the SAH falls by exactly the drop of that box's area.
//
// Taken during the build, at a node of at least BuildOptions::rotate_min
// primitives, after the node's own split: both children's splits are chosen
// (choose_ahead(), exactly as their own tasks would choose them), the four
// rotations are costed from the boxes that gives, and the best one is taken
// when it gains enough. Its three subtrees lie in record order T0 T1 T2; a
// rotation groups two of them under a new node Y. When the one left alone is
// T0 or T2 no record moves; when it is T1, it trades places with the
// cheaper of its neighbours (records and the permutation's slots, where the
// kept child's bin keys are). Each subtree keeps its records in order, so
// every subtree below splits as it would have. The chosen splits are carried
// to the children's tasks (CarriedSplits) and not chosen again, and Y's
// split, which is no plane, is carried as the range it is. The decision
// depends only on the node (never on the thread count or the scheduler), and
// run_node() and a team-parallel node (ParallelNode::look_ahead() and
// rotate()) both take it here, so every scheduler builds the same tree.
//
// Included by kernel.h after the steps it uses (plan(), binning_mapper(),
// bin_and_evaluate(), KernelContext), not on its own.
#pragma once

#include "../geometry.h"
#include "../options.h"
#include "bin_mapper.h"
#include "bins.h"
#include "emit.h"
#include "evaluate.h"
#include "partition.h"
#include "task.h"

#include <algorithm>
#include <cassert>
#include <cstdint>
#include <mutex>
#include <unordered_map>
#include <utility>

namespace canopy {

// A node's split, chosen before its task runs.
struct ChosenSplit {
    enum class Kind : uint8_t {
        Plane,  // a binned split (plane or size): m and s, as run_node() chooses it
        Range   // the records are in place: kids are the two children
    };
    Kind kind = Kind::Plane;
    bool bounds_known = false;  // Plane: part.acc holds the children's bounds (a split by keys)
    BinMapper m;
    Split s;
    PartitionResult part;
    NodeTask kids[2];

    bool knows_children() const { return kind == Kind::Range || bounds_known; }
    Box child_box(int k) const { return kind == Kind::Range ? kids[k].bounds : part.acc.bounds[k].box(); }
};

// The splits chosen for tasks not yet run, by their range (no two live
// tasks have the same range). Written and read by whichever threads run the
// parent and the child; a child task is made after its parent wrote its
// entry. Few entries: two or three per node of at least rotate_min.
class CarriedSplits {
public:
    CarriedSplits() = default;
    // Moved with its build's state, between builds only (not the mutex).
    CarriedSplits(CarriedSplits&& o) noexcept : map_(std::move(o.map_)) {}
    CarriedSplits& operator=(CarriedSplits&& o) noexcept {
        map_ = std::move(o.map_);
        return *this;
    }
    void put(const NodeTask& t, const ChosenSplit& c) {
        const std::lock_guard<std::mutex> lock(mutex_);
        map_.insert_or_assign(key(t), c);
    }
    ChosenSplit get(const NodeTask& t) const {
        const std::lock_guard<std::mutex> lock(mutex_);
        const auto it = map_.find(key(t));
        assert(it != map_.end());
        return it->second;
    }
    ChosenSplit take(const NodeTask& t) {
        const std::lock_guard<std::mutex> lock(mutex_);
        const auto it = map_.find(key(t));
        assert(it != map_.end());
        const ChosenSplit c = it->second;
        map_.erase(it);
        return c;
    }
    void drop(const NodeTask& t) {
        const std::lock_guard<std::mutex> lock(mutex_);
        map_.erase(key(t));
    }
    size_t size() const {
        const std::lock_guard<std::mutex> lock(mutex_);
        return map_.size();
    }
    void clear() {
        const std::lock_guard<std::mutex> lock(mutex_);
        map_.clear();
    }

private:
    static uint64_t key(const NodeTask& t) { return uint64_t(t.begin) << 32 | t.end; }
    mutable std::mutex mutex_;
    std::unordered_map<uint64_t, ChosenSplit> map_;
};

// Splits t as chosen: a plane split partitions its records (by the keys its
// binning left, or by size), a range is where it is. Writes the two child
// tasks (a range's with what is carried to them).
inline void split_as_chosen(const KernelContext& ctx, const NodeTask& t, const ChosenSplit& c, NodeTask out[2]) {
    if (c.kind == ChosenSplit::Kind::Range) {
        out[0] = c.kids[0];
        out[1] = c.kids[1];
        link(t, out);
        return;
    }
    if (c.s.by_size()) return emit(t, partition(ctx.refs, t.begin, t.end, c.m, c.s), out);
    PartitionResult part = partition_by_keys(ctx.refs, t.begin, t.end, c.s, ctx.permutation, ctx.shared);
    part.acc = c.part.acc;  // from the bins, as run_node() takes them
    emit(t, part, out);
}

// Whether node t's children are costed for a rotation.
inline bool rotates(const KernelContext& ctx, const NodeTask& t) {
    const uint32_t min = ctx.options->rotate_min;
    return ctx.carry != nullptr && min != 0 && t.size() >= min;
}

// Chooses child task c's split as its own task would (steps 1 and 2 of
// run_node()), for a node that its task would bin and split by a plane or
// by size: more than kBinBlock primitives and max_leaf, within the depth
// budget, centroids not all equal, a split found. Otherwise returns false
// and counts nothing (its task will). A task whose split was chosen already
// returns that.
inline bool choose_ahead(const KernelContext& ctx, const NodeTask& c, BinSet& bins, SkipCounts& skip,
                         ChosenSplit& out) {
    if (c.carried) {
        out = ctx.carry->get(c);
        return true;
    }
    const BuildOptions& opt = *ctx.options;
    SkipCounts mine;
    if (c.size() <= std::max(opt.max_leaf, kBinBlock) || plan(c, opt, mine) != Plan::Sah) return false;
    const BinMapper full = BinMapper::make(c.cbounds, bins_for(c.size(), opt.bins));
    if (!full.any_valid()) return false;
    mine.axes_not_binned += 3 - full.valid_count();
    out = ChosenSplit{};
    out.m = binning_mapper(ctx.refs, c, full, bins, opt, mine);
    out.s = bin_and_evaluate(ctx, c, out.m, bins, mine);
    if (!out.s.found()) return false;  // a middle split: its task will find it again
    if (!out.s.by_size()) {
        out.part.mid = c.begin + out.s.left_count;
        bounds_from_bins(bins, out.m, c, out.s, out.part);
        out.bounds_known = true;
    }
    skip.add(mine);
    return true;
}

// A rotation is taken when it lowers the area of the node it changes by
// more than this fraction of the area of the node it is taken at: smaller
// gains (the 1M sphere's three rotations at nodes of 65,536 primitives or
// more lowered its SAH by 0.04% all together) are not worth moving records.
inline constexpr double kRotateMinGain = 0x1p-4;

// Exchanges the adjacent ranges [a, b) and [b, c) of the records and of the
// permutation's slots (where the bin keys of a carried child are).
inline void exchange_ranges(const KernelContext& ctx, uint32_t a, uint32_t b, uint32_t c) {
    std::rotate(ctx.refs + a, ctx.refs + b, ctx.refs + c);
    std::rotate(ctx.permutation + a, ctx.permutation + b, ctx.permutation + c);
}

// Whether a rotation at t keeps the tree within the depth cap: it moves two
// subtrees one level down, whose tasks must still split by SAH (plan()).
inline bool rotation_room(const BuildOptions& opt, const NodeTask& t) {
    return opt.max_depth > t.depth + 2 + ceil_log2(t.size());
}

// After node t split into children ch (written by emit() or
// split_as_chosen()), whose splits were chosen into c where has[k] (by
// choose_ahead()): either carries the chosen splits to the children's
// tasks, or takes the best rotation and rewrites ch.
inline void rotate_chosen(const KernelContext& ctx, const NodeTask& t, NodeTask ch[2], const ChosenSplit c[2],
                          const bool has[2], SkipCounts& skip) {
    // Rotation (p, j): child p's child j trades places with child 1 - p;
    // child p's box becomes that of child 1 - p and p's child 1 - j.
    double best = kRotateMinGain * t.bounds.half_area();
    int p = -1, j = 0;
    for (int q = 0; q < 2; ++q) {
        if (!has[q] || !c[q].knows_children()) continue;
        const double now = ch[q].bounds.half_area();
        for (int i = 0; i < 2; ++i) {
            Box y = ch[1 - q].bounds;
            y.extend(c[q].child_box(1 - i));
            const double gain = now - y.half_area();
            if (gain > best) best = gain, p = q, j = i;
        }
    }
    if (p < 0) {
        for (int k = 0; k < 2; ++k)
            if (has[k] && !ch[k].carried) {
                ctx.carry->put(ch[k], c[k]);
                ch[k].carried = true;
            }
        return;
    }
    ++skip.rotations;
    const int keep = 1 - p;
    NodeTask g[2];
    if (ch[p].carried) ctx.carry->drop(ch[p]);
    split_as_chosen(ctx, ch[p], c[p], g);
    if (ch[keep].carried) ctx.carry->drop(ch[keep]);
    NodeTask r[3] = {ch[keep], g[0], g[1]};
    int kept = 0, lone = 1 + j;
    if (p == 0) {
        r[0] = g[0], r[1] = g[1], r[2] = ch[keep];
        kept = 2, lone = j;
    }
    if (lone == 1) {  // the cheaper neighbour trades places with it
        const int o = r[0].size() <= r[2].size() ? 0 : 2;
        const int lo = std::min(o, 1), hi = std::max(o, 1);
        exchange_ranges(ctx, r[lo].begin, r[hi].begin, r[hi].end);
        std::swap(r[lo], r[hi]);
        if (kept == o) kept = 1;
        lone = o;
        uint32_t at = t.begin;
        for (NodeTask& x : r) {
            const uint32_t n = x.size();
            x.begin = at;
            x.end = at += n;
        }
    }
    r[kept].carried = has[keep];
    if (has[keep]) ctx.carry->put(r[kept], c[keep]);
    ChosenSplit yc;
    yc.kind = ChosenSplit::Kind::Range;
    yc.kids[0] = r[lone == 0 ? 1 : 0];
    yc.kids[1] = r[lone == 0 ? 2 : 1];
    NodeTask y = yc.kids[0];
    y.end = yc.kids[1].end;
    y.bounds.extend(yc.kids[1].bounds);
    y.cbounds.extend(yc.kids[1].cbounds);
    y.max_area = std::max(y.max_area, yc.kids[1].max_area);
    y.carried = true;
    ctx.carry->put(y, yc);
    ch[0] = lone == 0 ? r[0] : y;
    ch[1] = lone == 0 ? y : r[2];
    link(t, ch);
}

// At a node that rotates (rotates(), checked here), chooses the splits of
// t's children ch and takes what rotate_chosen() decides (run_node(); a
// team runs the same steps, see ParallelNode).
[[gnu::noinline, gnu::cold]] inline void rotate_children(const KernelContext& ctx, const NodeTask& t, NodeTask ch[2],
                                                         BinSet& bins, SkipCounts& skip) {
    if (!rotates(ctx, t) || !rotation_room(*ctx.options, t)) return;
    ChosenSplit c[2];
    bool has[2];
    for (int k = 0; k < 2; ++k) has[k] = choose_ahead(ctx, ch[k], bins, skip, c[k]);
    rotate_chosen(ctx, t, ch, c, has, skip);
}

// run_node() of a task whose split was chosen before it ran.
[[gnu::noinline, gnu::cold]] inline void run_chosen(const KernelContext& ctx, const NodeTask& t, NodeTask children[2],
                                                    BinSet& bins, SkipCounts& skip) {
    split_as_chosen(ctx, t, ctx.carry->take(t), children);
    rotate_children(ctx, t, children, bins, skip);
}

}  // namespace canopy
