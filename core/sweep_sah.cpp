// canopy: the exact full-sweep SAH reference builder (see sweep_sah.h).
#include "sweep_sah.h"

#include "error.h"
#include "kernel.h"
#include "primitives.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <numeric>
#include <string>
#include <vector>

namespace canopy {

namespace {

struct SweepBuilder {
    const BuildOptions& opt;
    uint32_t n = 0;
    std::vector<PrimRef> refs;   // indexed by primitive id
    std::vector<Vec3> cent;      // centroid(refs[id]), as the binned build computes it
    std::array<std::vector<uint32_t>, 3> order;  // ids sorted by (centroid[axis], id), per node range
    std::vector<uint32_t> tmp;   // stable-partition scratch
    std::vector<uint8_t> right;  // side of each id at the current split
    std::vector<double> right_cost;  // suffix sweep: measure(right box) * right count
    Bvh bvh;

    explicit SweepBuilder(const BuildOptions& o) : opt(o) {}

    float c(uint32_t id, int axis) const { return cent[id][axis]; }

    Box range_bounds(uint32_t begin, uint32_t end) const {
        Box b;
        for (uint32_t i = begin; i < end; ++i) {
            const PrimRef& r = refs[order[0][i]];
            b.lo = glm::min(b.lo, r.lo);
            b.hi = glm::max(b.hi, r.hi);
        }
        return b;
    }

    bool axis_splittable(uint32_t begin, uint32_t end, int a) const {
        return c(order[a][begin], a) < c(order[a][end - 1], a);
    }

    struct Best {
        int axis = -1;
        uint32_t left = 0;  // primitives going left (a prefix of order[axis])
        double sum = 0.0;   // A_L n_L + A_R n_R (in the node's measure)
        double cost = 0.0;
        bool found() const { return axis >= 0; }
    };

    // Every split between distinct centroid coordinates on every axis.
    Best evaluate(uint32_t begin, uint32_t end, const Box& bounds) {
        Best best;
        const bool use_length = !(bounds.half_area() > 0.0);
        const double parent = area_measure(bounds, use_length);
        if (!(parent > 0.0)) return best;
        const uint32_t cnt = end - begin;
        for (int a = 0; a < 3; ++a) {
            if (!axis_splittable(begin, end, a)) continue;
            const uint32_t* ord = order[a].data() + begin;
            Box acc;
            for (uint32_t k = cnt - 1; k > 0; --k) {
                const PrimRef& r = refs[ord[k]];
                acc.lo = glm::min(acc.lo, r.lo);
                acc.hi = glm::max(acc.hi, r.hi);
                right_cost[k] = area_measure(acc, use_length) * double(cnt - k);
            }
            acc = Box{};
            for (uint32_t k = 1; k < cnt; ++k) {
                const PrimRef& r = refs[ord[k - 1]];
                acc.lo = glm::min(acc.lo, r.lo);
                acc.hi = glm::max(acc.hi, r.hi);
                // Only between distinct coordinates: a plane can separate them.
                if (!(c(ord[k - 1], a) < c(ord[k], a))) continue;
                const double sum = area_measure(acc, use_length) * double(k) + right_cost[k];
                if (!best.found() || sum < best.sum) {
                    best.axis = a;
                    best.left = k;
                    best.sum = sum;
                }
            }
        }
        if (best.found())
            best.cost = double(opt.traversal_cost) + double(opt.intersection_cost) * best.sum / parent;
        return best;
    }

    // The left child is order[axis][begin, begin + left); the other orders
    // are partitioned stably to the same sets (so they stay sorted).
    void split(uint32_t begin, uint32_t end, int axis, uint32_t left) {
        const uint32_t mid = begin + left;
        for (uint32_t i = begin; i < end; ++i) right[order[axis][i]] = i >= mid;
        for (int a = 0; a < 3; ++a) {
            if (a == axis) continue;
            uint32_t* ord = order[a].data();
            uint32_t l = begin, r = mid;
            for (uint32_t i = begin; i < end; ++i) {
                const uint32_t id = ord[i];
                if (right[id])
                    tmp[r++] = id;
                else
                    tmp[l++] = id;
            }
            std::copy(tmp.begin() + begin, tmp.begin() + end, ord + begin);
        }
    }

    void run() {
        for (int a = 0; a < 3; ++a) {
            order[a].resize(n);
            std::iota(order[a].begin(), order[a].end(), 0u);
            std::sort(order[a].begin(), order[a].end(), [&](uint32_t x, uint32_t y) {
                const float cx = c(x, a), cy = c(y, a);
                return cx < cy || (cx == cy && x < y);
            });
        }
        tmp.resize(n);
        right.assign(n, 0);
        right_cost.resize(n);
        bvh.permutation.resize(n);
        bvh.nodes.clear();
        bvh.nodes.reserve(n);
        bvh.nodes.emplace_back();

        struct Item {
            uint32_t begin, end, depth, node;
        };
        std::vector<Item> stack{{0, n, 0, 0}};
        while (!stack.empty()) {
            const Item it = stack.back();
            stack.pop_back();
            const uint32_t cnt = it.end - it.begin;
            const Box bounds = range_bounds(it.begin, it.end);
            bvh.nodes[it.node].set_box(bounds);

            // What to do: the binned build's plan() and sah_says_leaf().
            bool leaf = false;
            int axis = 0;
            uint32_t left = cnt / 2;  // the middle split of the axis-0 order
            const uint32_t budget = opt.max_depth > it.depth ? opt.max_depth - it.depth : 0;
            if (cnt <= 1) {
                leaf = true;
            } else if (budget <= ceil_log2(cnt)) {
                leaf = cnt <= opt.max_leaf;
            } else if (!axis_splittable(it.begin, it.end, 0) && !axis_splittable(it.begin, it.end, 1) &&
                       !axis_splittable(it.begin, it.end, 2)) {
                leaf = cnt <= opt.max_leaf;  // all centroids coincide
            } else {
                const Best b = evaluate(it.begin, it.end, bounds);
                if (cnt <= opt.max_leaf && (!b.found() || b.cost >= double(opt.intersection_cost) * double(cnt)))
                    leaf = true;
                else if (b.found()) {
                    axis = b.axis;
                    left = b.left;
                }
            }

            Node& node = bvh.nodes[it.node];
            if (leaf) {
                node.index = it.begin;
                node.count = cnt;
                std::copy(order[0].begin() + it.begin, order[0].begin() + it.end,
                          bvh.permutation.begin() + it.begin);
                continue;
            }
            const uint32_t first = static_cast<uint32_t>(bvh.nodes.size());
            node.index = first;
            node.count = 0;
            bvh.nodes.emplace_back();  // `node` is not used past this point
            bvh.nodes.emplace_back();
            split(it.begin, it.end, axis, left);
            const uint32_t mid = it.begin + left;
            stack.push_back({mid, it.end, it.depth + 1, first + 1});
            stack.push_back({it.begin, mid, it.depth + 1, first});
        }
    }
};

void check_depth(const BuildOptions& opt, size_t count) {
    const uint64_t leaves_needed = (uint64_t(count) + opt.max_leaf - 1) / opt.max_leaf;
    const uint32_t need = ceil_log2(static_cast<uint32_t>(leaves_needed));
    if (need > opt.max_depth)
        throw OptionError("max_depth " + std::to_string(opt.max_depth) + " is too small for " +
                          std::to_string(count) + " primitives in leaves of at most " +
                          std::to_string(opt.max_leaf) + " (needs " + std::to_string(need) + ")");
}

template <class Prepare, class Fail>
Bvh build_impl(size_t count, const BuildOptions& options, Prepare&& prepare, Fail&& fail) {
    options.check();
    if (count == 0) return {};
    check_depth(options, count);
    SweepBuilder b(options);
    b.n = static_cast<uint32_t>(count);
    b.refs.resize(count);
    const PrepareSummary s = prepare(b.refs.data());
    if (s.first_bad != PrepareSummary::kNone) fail(s.first_bad);
    b.cent.resize(count);
    for (size_t i = 0; i < count; ++i) b.cent[i] = centroid(b.refs[i]);
    b.run();
    return std::move(b.bvh);
}

}  // namespace

Bvh build_sweep_sah(const TriangleView& mesh, const BuildOptions& options) {
    check_triangle_input(mesh);
    const size_t count = mesh.triangle_count();
    return build_impl(
        count, options, [&](PrimRef* out) { return prepare_triangles(mesh, 0, count, out); },
        [&](size_t bad) { throw_bad_triangle(mesh, bad); });
}

Bvh build_sweep_sah(std::span<const Box> boxes, const BuildOptions& options) {
    check_box_input(boxes);
    return build_impl(
        boxes.size(), options, [&](PrimRef* out) { return prepare_boxes(boxes, 0, boxes.size(), out); },
        [&](size_t bad) { throw_bad_box(boxes, bad); });
}

}  // namespace canopy
