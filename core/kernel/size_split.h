// canopy: the size split, offered to a node beside the planes when a few of
// its primitives are far larger than the rest.
#pragma once

#include "evaluate.h"
#include "task.h"

#include <algorithm>
#include <cstdint>
#include <limits>

namespace canopy {

// The size split. Binning orders primitives by where their centroids are. A
// node holding a few primitives far larger than the rest (a room's walls and
// light around a detailed object, as in the Cornell box scenes) is often best
// split by size instead: the large primitives in one child, all others in the
// other. Their centroids lie among the small ones', so no plane between bins
// separates them, at any bin count (CBcoil was 22% above the exact sweep at
// 32 bins, 15% at 256).
//
// A node is offered this split when it has at least kSizeSplitMinPrims
// primitives and its largest primitive box has at least a quarter of the
// node's half area (NodeTask::max_area, which the partitions carry down at no
// cost). One extra pass then sorts its primitives into three classes by area
// (at least half the node's, at least a quarter, smaller), and the two cuts
// between the classes are costed with the same SAH as the planes; the
// cheapest of the best plane and the cuts wins, the plane on a tie. On
// ordinary meshes the condition holds only in small nodes, where the pass is
// short. Like binning, the classes depend only on the primitives, so every
// scheduler makes the same choice.
inline constexpr uint32_t kSizeSplitMinPrims = 16;

struct SizeCuts {
    float half = 0.0f, quarter = 0.0f;  // float(A / 2), float(A / 4), at most the largest float

    static SizeCuts of(const Box& node) {
        const double a = node.half_area();
        const double top = double(std::numeric_limits<float>::max());
        SizeCuts c;
        if (!(a > 0.0)) return c;
        c.half = static_cast<float>(std::min(a / 2.0, top));
        c.quarter = static_cast<float>(std::min(a / 4.0, top));
        return c;
    }
    bool applies(const NodeTask& t) const {
        return t.size() >= kSizeSplitMinPrims && quarter > 0.0f && t.max_area >= quarter;
    }
    // 0: area >= half, 1: quarter <= area < half, 2: smaller.
    uint32_t size_class(float area) const { return uint32_t(area < half) + uint32_t(area < quarter); }
};

// Per size class: the box of the primitives and their count.
struct SizeBins {
    simd::Box4 box[3];
    uint32_t count[3] = {0, 0, 0};
    void merge(const SizeBins& o) {  // exact, order-independent
        for (int k = 0; k < 3; ++k) {
            box[k].grow(o.box[k]);
            count[k] += o.count[k];
        }
    }
};

// Sorts refs[b, e) into size classes, accumulating into `out`.
inline void bin_sizes(const PrimRef* refs, uint32_t b, uint32_t e, const SizeCuts& cuts, SizeBins& out) {
    for (uint32_t i = b; i < e; ++i) {
        const uint32_t k = cuts.size_class(refs[i].area);
        out.box[k].grow(simd::lo(refs[i]), simd::hi(refs[i]));
        ++out.count[k];
    }
}

// Replaces `best` by the cheaper cut between size classes, if one is cheaper
// (or `best` found no split). Cut c sends classes below c (the large
// primitives) right.
inline void consider_size_split(const SizeBins& sb, const SizeCuts& cuts, const Box& node_bounds,
                                const BuildOptions& opt, Split& best) {
    const double area = node_bounds.half_area();
    if (!(area > 0.0)) return;
    for (uint32_t c = 1; c < 3; ++c) {
        simd::Box4 left, right;
        uint32_t nl = 0, nr = 0;
        for (uint32_t k = 0; k < 3; ++k) {
            if (k < c) {
                right.grow(sb.box[k]);
                nr += sb.count[k];
            } else {
                left.grow(sb.box[k]);
                nl += sb.count[k];
            }
        }
        if (nl == 0 || nr == 0) continue;
        const double cost = double(opt.traversal_cost) +
                            double(opt.intersection_cost) *
                                (left.box().half_area() * nl + right.box().half_area() * nr) / area;
        // Taken only when cheaper beyond rounding: the planes' costs are
        // computed in scaled float, and a cut that forms the same two sets
        // as a plane must not win on rounding alone.
        if (best.found() && !(cost < best.cost * (1.0 - 0x1p-12))) continue;
        best = Split{};
        best.axis = Split::kSizeAxis;
        best.cost = cost;
        best.left_count = nl;
        best.size_cut = c == 1 ? cuts.half : cuts.quarter;
    }
}

}  // namespace canopy
