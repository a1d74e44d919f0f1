// What the kernel's test files (tests/kernel/) share: hand-made primitive
// records, their bounds as the kernel computes them, and thin adapters over
// the mapping, binning and partition APIs.
#pragma once

#include "core/geometry.h"
#include "core/kernel.h"
#include "core/options.h"
#include "core/primitives.h"
#include "../test_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <random>
#include <vector>

using canopy::BinMapper;
using canopy::BinSet;
using canopy::Box;
using canopy::BuildOptions;
using canopy::NodeTask;
using canopy::PartitionResult;
using canopy::Plan;
using canopy::PrimRef;
using canopy::SkipCounts;
using canopy::Split;
using canopy::Vec3;

namespace canopy::kernel_test {
inline constexpr float kInf = std::numeric_limits<float>::infinity();

// A record's area as prepare stores it, after its box was set or changed.
inline void refresh_area(PrimRef& r) { r.area = canopy::prim_area(r.lo, r.hi); }

inline PrimRef make_ref(Vec3 lo, Vec3 hi, uint32_t id) {
    PrimRef r;
    std::memset(static_cast<void*>(&r), 0, sizeof r);
    r.lo = lo;
    r.hi = hi;
    r.id = id;
    refresh_area(r);
    return r;
}

// A cube of half size h around c.
inline PrimRef cube(Vec3 c, float h, uint32_t id) { return make_ref(c - Vec3(h), c + Vec3(h), id); }

using test_util::uniform;

inline std::vector<PrimRef> random_refs(uint32_t n, uint32_t seed, float extent = 100.0f, float size = 2.0f) {
    std::mt19937 rng(seed);
    std::vector<PrimRef> refs;
    refs.reserve(n);
    for (uint32_t i = 0; i < n; ++i) {
        Vec3 lo(0.0f), hi(0.0f);
        for (int a = 0; a < 3; ++a) {
            lo[a] = uniform(rng, 0.0f, extent);
            hi[a] = lo[a] + uniform(rng, 0.0f, size);
        }
        refs.push_back(make_ref(lo, hi, i));
    }
    return refs;
}

struct Bounds {
    Box bounds, cbounds;
    float max_area = 0.0f;
};

inline Bounds bounds_of(const PrimRef* refs, uint32_t begin, uint32_t end) {
    Bounds b;
    for (uint32_t i = begin; i < end; ++i) {
        b.bounds.extend(refs[i].lo);
        b.bounds.extend(refs[i].hi);
        b.cbounds.extend(canopy::centroid(refs[i]));
        b.max_area = std::max(b.max_area, refs[i].area);
    }
    return b;
}

// The child bounds a partition reported (boxes, centroid boxes, largest
// areas) are those of refs[begin, p.mid) and refs[p.mid, end).
inline void expect_child_bounds(const PartitionResult& p, const PrimRef* refs, uint32_t begin, uint32_t end) {
    const Bounds l = bounds_of(refs, begin, p.mid);
    const Bounds r = bounds_of(refs, p.mid, end);
    EXPECT_EQ(p.left_bounds(), l.bounds);
    EXPECT_EQ(p.left_cbounds(), l.cbounds);
    EXPECT_EQ(p.left_max_area(), l.max_area);
    EXPECT_EQ(p.right_bounds(), r.bounds);
    EXPECT_EQ(p.right_cbounds(), r.cbounds);
    EXPECT_EQ(p.right_max_area(), r.max_area);
}

inline NodeTask task_of(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, uint32_t depth = 0) {
    NodeTask t;
    t.begin = begin;
    t.end = end;
    const Bounds b = bounds_of(refs.data(), begin, end);
    t.bounds = b.bounds;
    t.cbounds = b.cbounds;
    t.depth = depth;
    return t;
}

inline bool same_records(const std::vector<PrimRef>& a, const std::vector<PrimRef>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(PrimRef)) == 0;
}

// Thin adapters over the kernel's mapping API.
inline uint32_t bin_index(const BinMapper& m, const Vec3& c, int axis) { return m.index(c, axis); }
inline uint32_t bin_index(const BinMapper& m, float c, int axis) { return m.index(Vec3(c), axis); }
inline Box bin_box(const BinSet& b, int axis, uint32_t k) { return b.box(axis, k); }
// The partition predicate, from the scalar centroid() and the mapping.
inline bool left_of(const PrimRef& r, const BinMapper& m, const Split& s) {
    return bin_index(m, canopy::centroid(r), s.axis) < s.index;
}

inline std::unique_ptr<BinSet> binned(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end,
                               const BinMapper& m) {
    auto bins = std::make_unique<BinSet>();
    bins->clear(canopy::kMaxBins);
    canopy::bin(refs.data(), begin, end, m, *bins);
    return bins;
}

// Calls f(split) for every plane split of the mapping: each valid axis, each
// split index 1 .. bins - 1 (left_count not set).
template <class F>
inline void for_each_plane_split(const BinMapper& m, F&& f) {
    for (int axis = 0; axis < 3; ++axis) {
        if (!m.valid[axis]) continue;
        for (uint32_t k = 1; k < m.bins; ++k) {
            Split s;
            s.axis = axis;
            s.index = k;
            f(s);
        }
    }
}

// `size` random records (seeded by rng_seed) in one of the variants that
// test evaluations' corner cases (by `variant`): small or large extents,
// every record flat on y, the record after `first` a copy of it, or
// mirror images (equal costs on two axes).
inline std::vector<PrimRef> varied_refs(uint32_t size, uint32_t rng_seed, uint32_t variant, uint32_t first) {
    std::vector<PrimRef> refs = random_refs(size, rng_seed, variant % 2 ? 10.0f : 1e-3f, 1.0f);
    if (variant % 4 == 1)
        for (auto& r : refs) {
            r.hi.y = r.lo.y = -2.0f;
            refresh_area(r);
        }
    if (variant % 6 == 2) refs[first + 1] = make_ref(refs[first].lo, refs[first].hi, first + 1);
    if (variant % 8 == 3)
        for (uint32_t i = 0; i < size; ++i) refs[i] = cube(Vec3(float(i), float(i), 0.0f), 0.25f, i);
    return refs;
}

// n overlapping boxes of random sizes in a small region, sometimes flat on
// one axis, at scales from tiny to huge: a small node for property tests.
inline std::vector<PrimRef> random_small_node(std::mt19937& rng, uint32_t n) {
    const float scale = std::ldexp(1.0f, int(rng() % 200) - 100);
    std::vector<PrimRef> refs = random_refs(n, rng(), 4.0f * scale, uniform(rng, 0.5f, 8.0f) * scale);
    if (rng() % 4 == 0)
        for (PrimRef& r : refs) {
            r.hi.z = r.lo.z = 0.0f;
            refresh_area(r);
        }
    return refs;
}

// The records and a permutation, as a build owns them.
struct Buffers {
    std::vector<PrimRef> a;
    std::vector<uint32_t> perm;
    BuildOptions opt;
    explicit Buffers(const std::vector<PrimRef>& refs) : a(refs), perm(refs.size(), ~0u) {}
    canopy::KernelContext ctx() { return {a.data(), perm.data(), &opt, nullptr}; }
};

}  // namespace canopy::kernel_test

using namespace canopy::kernel_test;
