// Tests of the node-task kernel (core/kernel.h), one step at a time, on
// hand-made primitive records.
#include "core/geometry.h"
#include "core/kernel.h"
#include "core/options.h"
#include "core/primitives.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <numeric>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
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

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// A record's area as prepare stores it, after its box was set or changed.
void refresh_area(PrimRef& r) { r.area = canopy::prim_area(r.lo, r.hi); }

PrimRef make_ref(Vec3 lo, Vec3 hi, uint32_t id) {
    PrimRef r;
    std::memset(static_cast<void*>(&r), 0, sizeof r);
    r.lo = lo;
    r.hi = hi;
    r.id = id;
    refresh_area(r);
    return r;
}

// A cube of half size h around c.
PrimRef cube(Vec3 c, float h, uint32_t id) { return make_ref(c - Vec3(h), c + Vec3(h), id); }

float uniform(std::mt19937& rng, float lo, float hi) {
    const float u = float(rng() >> 8) * 0x1p-24f;
    return lo + (hi - lo) * u;
}

std::vector<PrimRef> random_refs(uint32_t n, uint32_t seed, float extent = 100.0f, float size = 2.0f) {
    std::mt19937 rng(seed);
    std::vector<PrimRef> refs;
    refs.reserve(n);
    for (uint32_t i = 0; i < n; ++i) {
        Vec3 lo, hi;
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

Bounds bounds_of(const PrimRef* refs, uint32_t begin, uint32_t end) {
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
void expect_child_bounds(const PartitionResult& p, const PrimRef* refs, uint32_t begin, uint32_t end) {
    const Bounds l = bounds_of(refs, begin, p.mid);
    const Bounds r = bounds_of(refs, p.mid, end);
    EXPECT_EQ(p.left_bounds(), l.bounds);
    EXPECT_EQ(p.left_cbounds(), l.cbounds);
    EXPECT_EQ(p.left_max_area(), l.max_area);
    EXPECT_EQ(p.right_bounds(), r.bounds);
    EXPECT_EQ(p.right_cbounds(), r.cbounds);
    EXPECT_EQ(p.right_max_area(), r.max_area);
}

NodeTask task_of(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, uint32_t depth = 0) {
    NodeTask t;
    t.begin = begin;
    t.end = end;
    const Bounds b = bounds_of(refs.data(), begin, end);
    t.bounds = b.bounds;
    t.cbounds = b.cbounds;
    t.depth = depth;
    return t;
}

bool same_records(const std::vector<PrimRef>& a, const std::vector<PrimRef>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(PrimRef)) == 0;
}

// Thin adapters over the kernel's mapping API.
uint32_t bin_index(const BinMapper& m, const Vec3& c, int axis) { return m.index(c, axis); }
uint32_t bin_index(const BinMapper& m, float c, int axis) { return m.index(Vec3(c), axis); }
Box bin_box(const BinSet& b, int axis, uint32_t k) { return b.box(axis, k); }
// The partition predicate, from the scalar centroid() and the mapping.
bool left_of(const PrimRef& r, const BinMapper& m, const Split& s) {
    return bin_index(m, canopy::centroid(r), s.axis) < s.index;
}

std::unique_ptr<BinSet> binned(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end,
                               const BinMapper& m) {
    auto bins = std::make_unique<BinSet>();
    bins->clear(canopy::kMaxBins);
    canopy::bin(refs.data(), begin, end, m, *bins);
    return bins;
}

// Calls f(split) for every plane split of the mapping: each valid axis, each
// split index 1 .. bins - 1 (left_count not set).
template <class F>
void for_each_plane_split(const BinMapper& m, F&& f) {
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

}  // namespace

// ---------------------------------------------------------------- bins_for

TEST(KernelBinsFor, RuleValues) {
    struct Row {
        uint32_t n, b16, b256, b2;
    };
    // min(bins, 4) up to 32, else min(bins, bit_ceil(n) / 4), at least 2;
    // from 2^16 on, min(256, 2 * bins); from 2^19 on, min(256, 4 * bins).
    const Row rows[] = {
        {1, 4, 4, 2},     {2, 4, 4, 2},     {3, 4, 4, 2},     {4, 4, 4, 2},
        {8, 4, 4, 2},     {16, 4, 4, 2},    {17, 4, 4, 2},    {32, 4, 4, 2},
        {33, 16, 16, 2},  {64, 16, 16, 2},  {65, 16, 32, 2},  {128, 16, 32, 2},
        {129, 16, 64, 2}, {1000, 16, 256, 2}, {65535, 16, 256, 2}, {65536, 32, 256, 4},
        {(1u << 19) - 1, 32, 256, 4}, {1u << 19, 64, 256, 8}, {1u << 20, 64, 256, 8},
    };
    for (const Row& r : rows) {
        EXPECT_EQ(canopy::bins_for(r.n, 16), r.b16) << "n=" << r.n;
        EXPECT_EQ(canopy::bins_for(r.n, 256), r.b256) << "n=" << r.n;
        EXPECT_EQ(canopy::bins_for(r.n, 2), r.b2) << "n=" << r.n;
    }
    // Other configured bin counts.
    EXPECT_EQ(canopy::bins_for(1000, 3), 3u);
    EXPECT_EQ(canopy::bins_for(5, 3), 3u);
    EXPECT_EQ(canopy::bins_for(257, 100), 100u);
    EXPECT_EQ(canopy::bins_for(256, 100), 64u);
    EXPECT_EQ(canopy::bins_for(1u << 20, 256), 256u);
    EXPECT_EQ(canopy::bins_for(1u << 31, 256), 256u);
    EXPECT_EQ(canopy::bins_for(canopy::kWideBinsMin, 100), 200u);
    EXPECT_EQ(canopy::bins_for(canopy::kWideBinsMin, 129), 256u);
    EXPECT_EQ(canopy::bins_for(canopy::kWidestBinsMin, 32), 128u);
    EXPECT_EQ(canopy::bins_for(canopy::kWidestBinsMin, 64), 256u);
    EXPECT_EQ(canopy::bins_for(canopy::kWidestBinsMin - 1, 64), 128u);
}

// Regression test for a fixed bug: kMaxPrimitives allows counts up to
// 0xFFFFFFFE, but bins_for() computes std::bit_ceil(n) in uint32_t, which is
// undefined for n > 2^31 (the result 2^32 is not representable). On x86 the
// shift wraps and the root of such a build gets 4 bins instead of `bins`.
TEST(KernelBinsFor, CountsAbove2To31) {
    volatile uint32_t big = 0x80000001u;  // volatile: keep it a run-time value
    EXPECT_EQ(canopy::bins_for(big, 256), 256u);
    big = 0xFFFFFFFEu;
    EXPECT_EQ(canopy::bins_for(big, 16), 64u);  // four times, as every node of 2^19 or more
}

TEST(KernelSimd, SelectTakesEachLaneFromTheMasksChoice) {
    namespace simd = canopy::simd;
    const __m128 a = _mm_set_ps(4.0f, 3.0f, 2.0f, 1.0f), b = _mm_set_ps(-4.0f, -3.0f, -2.0f, -1.0f);
    const __m128 mask = _mm_cmpgt_ps(_mm_set_ps(1.0f, 0.0f, 1.0f, 0.0f), _mm_setzero_ps());  // lanes 1 and 3
    alignas(16) float f[4];
    _mm_store_ps(f, simd::select(mask, a, b));
    EXPECT_EQ(f[0], -1.0f);
    EXPECT_EQ(f[1], 2.0f);
    EXPECT_EQ(f[2], -3.0f);
    EXPECT_EQ(f[3], 4.0f);
    alignas(16) int32_t k[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(k),
                    simd::select(_mm_castps_si128(mask), _mm_set_epi32(40, 30, 20, 10), _mm_set_epi32(-4, -3, -2, -1)));
    EXPECT_EQ(k[0], -1);
    EXPECT_EQ(k[1], 20);
    EXPECT_EQ(k[2], -3);
    EXPECT_EQ(k[3], 40);
}

// ---------------------------------------------------------------- BinMapper

TEST(KernelBinMapper, ZeroExtentAxisIsNotValid) {
    const Box cb{Vec3(0, 1, 2), Vec3(4, 1, 2)};
    const BinMapper m = BinMapper::make(cb, 16);
    EXPECT_TRUE(m.valid[0]);
    EXPECT_FALSE(m.valid[1]);
    EXPECT_FALSE(m.valid[2]);
    EXPECT_TRUE(m.any_valid());
    EXPECT_EQ(m.scale[1], 0.0f);
    EXPECT_EQ(m.scale[2], 0.0f);
    EXPECT_EQ(m.bins, 16u);
    EXPECT_EQ(m.origin, cb.lo);

    const BinMapper p = BinMapper::make(Box{Vec3(3, -1, 7), Vec3(3, -1, 7)}, 16);
    EXPECT_FALSE(p.any_valid());
    for (int a = 0; a < 3; ++a) EXPECT_EQ(p.scale[a], 0.0f);
}

TEST(KernelBinMapper, SubnormalExtentsAreBinnedExactly) {
    const float dm = std::numeric_limits<float>::denorm_min();
    // bins / extent overflows float for these extents: the mapper rescales
    // the offset by a power of two first, so the axis is still binned, with
    // a finite scale, the lowest centroid in bin 0 and the highest in the
    // last bin, and nothing out of range.
    for (const float e : {dm, 2 * dm, 1000 * dm, 1e-42f, 1e-39f}) {
        ASSERT_TRUE(std::fpclassify(e) == FP_SUBNORMAL) << e;
        for (uint32_t bins : {2u, 3u, 16u, 256u}) {
            const BinMapper m = BinMapper::make(Box{Vec3(0, 0, 0), Vec3(e, 1, 0)}, bins);
            EXPECT_TRUE(m.valid[0]) << e << " bins " << bins;
            EXPECT_TRUE(m.valid[1]);
            EXPECT_FALSE(m.valid[2]);
            for (int a = 0; a < 3; ++a) {
                EXPECT_TRUE(std::isfinite(m.scale[a])) << e << " axis " << a;
                EXPECT_TRUE(std::isfinite(m.prescale[a])) << e << " axis " << a;
            }
            EXPECT_EQ(m.prescale[1], 1.0f);  // ordinary extents keep the plain mapping
            EXPECT_EQ(bin_index(m, 0.0f, 0), 0u);
            EXPECT_EQ(bin_index(m, e, 0), bins - 1) << e << " bins " << bins;
            // Monotone over every representable value in [0, e] (up to 1000 steps).
            uint32_t prev = 0;
            for (float x = 0.0f; x <= e; x = std::nextafter(x, 1.0f)) {
                const uint32_t k = bin_index(m, x, 0);
                EXPECT_GE(k, prev);
                EXPECT_LT(k, bins);
                prev = k;
                if (x > 1000 * dm) break;
            }
        }
        // A subnormal extent around zero: both halves are reached.
        const BinMapper s = BinMapper::make(Box{Vec3(-e, 0, 0), Vec3(e, 0, 0)}, 16);
        EXPECT_TRUE(s.valid[0]) << e;
        EXPECT_FALSE(s.valid[1]);
        EXPECT_EQ(bin_index(s, -e, 0), 0u);
        EXPECT_EQ(bin_index(s, e, 0), 15u);
    }
}

TEST(KernelBinMapper, MinInBinZeroMaxInLastBin) {
    std::mt19937 rng(99);
    for (uint32_t bins : {2u, 3u, 4u, 8u, 16u, 32u, 64u}) {
        for (int rep = 0; rep < 200; ++rep) {
            Box cb;
            for (int a = 0; a < 3; ++a) {
                const float offset = uniform(rng, -1000.0f, 1000.0f);
                const float ext = std::ldexp(uniform(rng, 1.0f, 2.0f), int(rng() % 60) - 30);
                cb.lo[a] = offset;
                cb.hi[a] = offset + ext;
            }
            const BinMapper m = BinMapper::make(cb, bins);
            for (int a = 0; a < 3; ++a) {
                if (!(cb.hi[a] > cb.lo[a])) continue;
                ASSERT_TRUE(m.valid[a]);
                EXPECT_EQ(bin_index(m, cb.lo[a], a), 0u);
                EXPECT_EQ(bin_index(m, cb.hi[a], a), bins - 1) << "bins " << bins << " lo " << cb.lo[a]
                                                         << " hi " << cb.hi[a];
                // Monotone in between.
                uint32_t prev = 0;
                for (int k = 0; k <= 64; ++k) {
                    const float c = cb.lo[a] + (cb.hi[a] - cb.lo[a]) * (float(k) / 64.0f);
                    const uint32_t i = bin_index(m, std::min(c, cb.hi[a]), a);
                    EXPECT_GE(i, prev);
                    EXPECT_LT(i, bins);
                    prev = i;
                }
            }
        }
    }
    // The whole float range on one axis.
    const BinMapper w = BinMapper::make(Box{Vec3(-FLT_MAX, 0, 0), Vec3(FLT_MAX, 1, 1)}, 16);
    EXPECT_TRUE(w.valid[0]);
    EXPECT_TRUE(std::isfinite(w.scale[0]));
    EXPECT_EQ(bin_index(w, -FLT_MAX, 0), 0u);
    EXPECT_EQ(bin_index(w, FLT_MAX, 0), 15u);
}

// Regression test for a fixed bug: the kernel promised that with the safe
// scale 0.99 * bins / extent "the largest centroid falls inside the last bin",
// but that holds only while 0.01 * bins < 1. For bins >= 100 (the option
// allows up to 256) the largest centroid lands in bin floor(0.99 * bins):
// bin 253 of 256, so bins 254 and 255 are never used.
TEST(KernelBinMapper, MaxInLastBinForLargeBinCounts) {
    for (uint32_t bins : {128u, 200u, 256u}) {
        const Box cb{Vec3(0, 0, 0), Vec3(1, 10, 1000)};
        const BinMapper m = BinMapper::make(cb, bins);
        for (int a = 0; a < 3; ++a) {
            ASSERT_TRUE(m.valid[a]);
            EXPECT_EQ(bin_index(m, cb.lo[a], a), 0u);
            EXPECT_EQ(bin_index(m, cb.hi[a], a), bins - 1) << "bins " << bins << " axis " << a;
        }
    }
}

TEST(KernelBinMapper, IndexClampsOutsideValues) {
    const BinMapper m = BinMapper::make(Box{Vec3(10, 10, 10), Vec3(20, 30, 40)}, 8);
    ASSERT_TRUE(m.valid[0] && m.valid[1] && m.valid[2]);
    for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(bin_index(m, 9.0f, a), 0u);
        EXPECT_EQ(bin_index(m, -1e30f, a), 0u);
        EXPECT_EQ(bin_index(m, -FLT_MAX, a), 0u);
        EXPECT_EQ(bin_index(m, -kInf, a), 0u);
        EXPECT_EQ(bin_index(m, 100.0f, a), 7u);
        EXPECT_EQ(bin_index(m, 1e30f, a), 7u);
        EXPECT_EQ(bin_index(m, FLT_MAX, a), 7u);
        EXPECT_EQ(bin_index(m, kInf, a), 7u);
    }
    // Hand values: (15 - 10) * 8 / 10 = 4 -> bin 4; (14.9 - 10) * 8 / 10 = 3.92 -> bin 3.
    EXPECT_EQ(bin_index(m, 15.0f, 0), 4u);
    EXPECT_EQ(bin_index(m, 14.9f, 0), 3u);
}

// make() maps the three axes at once unless an extent is in (0, 2^-64);
// make_general() is the per-axis reference. Both must give the same mapping,
// field for field, on ordinary, zero, huge and near-threshold extents.
TEST(KernelBinMapper, FastMakeMatchesTheGeneralOne) {
    auto same = [](const Box& cb, uint32_t bins) {
        const BinMapper f = BinMapper::make(cb, bins), g = BinMapper::make_general(cb, bins);
        for (int a = 0; a < 3; ++a) {
            EXPECT_EQ(f.valid[a], g.valid[a]) << "axis " << a << " bins " << bins;
            EXPECT_EQ(std::bit_cast<uint32_t>(f.scale[a]), std::bit_cast<uint32_t>(g.scale[a])) << "axis " << a;
            EXPECT_EQ(std::bit_cast<uint32_t>(f.prescale[a]), std::bit_cast<uint32_t>(g.prescale[a])) << "axis " << a;
            EXPECT_EQ(std::bit_cast<uint32_t>(f.origin[a]), std::bit_cast<uint32_t>(g.origin[a])) << "axis " << a;
        }
        alignas(16) float s4[4], p4[4], o4[4], l4[4];
        alignas(16) float gs4[4], gp4[4], go4[4], gl4[4];
        _mm_store_ps(s4, f.scale4), _mm_store_ps(p4, f.prescale4), _mm_store_ps(o4, f.origin4), _mm_store_ps(l4, f.last4);
        _mm_store_ps(gs4, g.scale4), _mm_store_ps(gp4, g.prescale4), _mm_store_ps(go4, g.origin4), _mm_store_ps(gl4, g.last4);
        EXPECT_EQ(std::memcmp(s4, gs4, 16), 0);
        EXPECT_EQ(std::memcmp(p4, gp4, 16), 0);
        EXPECT_EQ(std::memcmp(o4, go4, 16), 0);
        EXPECT_EQ(std::memcmp(l4, gl4, 16), 0);
        EXPECT_EQ(f.bins, g.bins);
        EXPECT_EQ(f.prescaled, g.prescaled);
        // prescaled says whether some prescale is not 1 (bin() then keeps
        // the multiplication by it).
        EXPECT_EQ(g.prescaled, g.prescale[0] != 1.0f || g.prescale[1] != 1.0f || g.prescale[2] != 1.0f);
    };
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::uniform_int_distribution<int> ex(-140, 127);
    const float edge[] = {0.0f, 1e-30f, 0x1p-64f, 0x1.000002p-64f, 0x1.fffffep-65f, FLT_MIN, 1e-20f,
                          1.0f, 3.0f, 1e20f, FLT_MAX / 2, FLT_MAX};
    for (uint32_t bins : {2u, 4u, 7u, 32u, 256u}) {
        for (int i = 0; i < 2000; ++i) {
            Vec3 lo, hi;
            for (int a = 0; a < 3; ++a) {
                const float base = std::ldexp(u(rng), ex(rng));
                const float size = (i % 3 == 0) ? edge[rng() % std::size(edge)] : std::ldexp(std::abs(u(rng)), ex(rng));
                lo[a] = base;
                hi[a] = std::isfinite(base + size) ? base + size : base;
            }
            same(Box{lo, hi}, bins);
        }
        same(Box{Vec3(-FLT_MAX), Vec3(FLT_MAX)}, bins);
        same(Box{Vec3(0), Vec3(0)}, bins);
        same(Box{Vec3(1, 2, 3), Vec3(1, 2, 3 + 0x1p-22f)}, bins);
    }
}

// ---------------------------------------------------------------- bin

TEST(KernelBin, EightPrimitivesAlongX) {
    // Boxes [i, i + 0.5] x [0, 1] x [0, 1]: centroids x = i + 0.25, y = z = 0.5.
    std::vector<PrimRef> refs;
    for (uint32_t i = 0; i < 8; ++i) refs.push_back(make_ref(Vec3(float(i), 0, 0), Vec3(i + 0.5f, 1, 1), i));
    const Bounds b = bounds_of(refs.data(), 0, 8);
    EXPECT_EQ(b.cbounds.lo, Vec3(0.25f, 0.5f, 0.5f));
    EXPECT_EQ(b.cbounds.hi, Vec3(7.25f, 0.5f, 0.5f));
    const BinMapper m = BinMapper::make(b.cbounds, 4);
    ASSERT_TRUE(m.valid[0]);
    ASSERT_FALSE(m.valid[1]);
    ASSERT_FALSE(m.valid[2]);
    // scale = 0.99 * 4 / 7: bins of primitives 0..7 are 0 0 1 1 2 2 3 3.
    for (uint32_t i = 0; i < 8; ++i) EXPECT_EQ(bin_index(m, canopy::centroid(refs[i]).x, 0), i / 2) << i;

    auto bins = std::make_unique<BinSet>();
    bins->clear(4);
    canopy::bin(refs.data(), 0, 8, m, *bins);
    uint32_t total = 0;
    for (uint32_t k = 0; k < 4; ++k) {
        EXPECT_EQ(bins->count(0, k), 2u) << k;
        total += bins->count(0, k);
        const Box expected{Vec3(2.0f * k, 0, 0), Vec3(2.0f * k + 1.5f, 1, 1)};
        EXPECT_EQ(bin_box(*bins, 0, k), expected) << k;
    }
    EXPECT_EQ(total, 8u);
    // Invalid axes are not touched.
    for (int a = 1; a < 3; ++a)
        for (uint32_t k = 0; k < 4; ++k) {
            EXPECT_EQ(bins->count(a, k), 0u);
            EXPECT_TRUE(bin_box(*bins, a, k).is_empty());
        }

    // A sub-range: primitives 3..6 only.
    bins->clear(4);
    canopy::bin(refs.data(), 3, 7, m, *bins);
    EXPECT_EQ(bins->count(0, 0), 0u);
    EXPECT_EQ(bins->count(0, 1), 1u);
    EXPECT_EQ(bins->count(0, 2), 2u);
    EXPECT_EQ(bins->count(0, 3), 1u);
    EXPECT_TRUE(bin_box(*bins, 0, 0).is_empty());
    EXPECT_EQ(bin_box(*bins, 0, 1), (Box{Vec3(3, 0, 0), Vec3(3.5f, 1, 1)}));
    EXPECT_EQ(bin_box(*bins, 0, 3), (Box{Vec3(6, 0, 0), Vec3(6.5f, 1, 1)}));
}

TEST(KernelBin, CountsAndBoxesMatchTheMapping) {
    // The whole range takes bin()'s two-set path, [0, 123) the one-set path
    // and [123, n) the two-set path with an odd count; at unit scale and
    // at 2^-80, where every extent is below 2^-64 and the mapping prescales
    // (bin()'s other loops). Each case also with the records sorted by
    // their three bin indices, so that runs of neighbours share all their
    // bins (the two-set path adds such runs of two and four as one).
    constexpr uint32_t n = 500;
    static_assert(n - 123 >= canopy::kTwoBinSetsMin && 123 < canopy::kTwoBinSetsMin && (n - 123) % 2 == 1);
    const std::pair<float, uint32_t> cases[] = {{1.0f, 2}, {1.0f, 7}, {1.0f, 16}, {1.0f, 256},
                                                {0x1p-80f, 2}, {0x1p-80f, 7}, {0x1p-80f, 16}, {0x1p-80f, 256}};
    for (const auto& [unit, nb] : cases)
    for (const bool sorted : {false, true}) {
        std::vector<PrimRef> refs = random_refs(n, 5, 100.0f * unit, 2.0f * unit);
        const Bounds b = bounds_of(refs.data(), 0, n);
        const BinMapper m = BinMapper::make(b.cbounds, nb);
        if (sorted) {
            const auto key = [&](const PrimRef& r) {
                const Vec3 c = canopy::centroid(r);
                return std::array<uint32_t, 3>{bin_index(m, c, 0), bin_index(m, c, 1), bin_index(m, c, 2)};
            };
            // (std::sort: libstdc++'s stable_sort takes a buffer from plain
            // operator new, not aligned for the 32-byte PrimRef.)
            std::sort(refs.begin(), refs.end(), [&](const PrimRef& x, const PrimRef& y) {
                return std::pair(key(x), x.id) < std::pair(key(y), y.id);
            });
            uint32_t runs = 0;
            for (uint32_t i = 1; i < n; ++i) runs += key(refs[i]) != key(refs[i - 1]);
            if (nb == 2) {
                ASSERT_LE(runs, 7u) << "eight runs of equal bins";
            }
        }
        ASSERT_TRUE(m.valid[0] && m.valid[1] && m.valid[2]);
        ASSERT_EQ(m.prescaled, unit != 1.0f);
        const auto bins = binned(refs, 0, n, m);
        for (int a = 0; a < 3; ++a) {
            uint32_t total = 0;
            for (uint32_t k = 0; k < nb; ++k) {
                Box expected;
                uint32_t count = 0;
                for (const PrimRef& r : refs)
                    if (bin_index(m, canopy::centroid(r)[a], a) == k) {
                        expected.extend(r.lo);
                        expected.extend(r.hi);
                        ++count;
                    }
                EXPECT_EQ(bins->count(a, k), count) << "axis " << a << " bin " << k;
                EXPECT_EQ(bin_box(*bins, a, k), expected) << "axis " << a << " bin " << k;
                total += bins->count(a, k);
            }
            EXPECT_EQ(total, n) << "axis " << a;
        }
        // Binning two halves separately and merging gives the same bins.
        auto lo = std::make_unique<BinSet>(), hi = std::make_unique<BinSet>();
        lo->clear(nb);
        hi->clear(nb);
        canopy::bin(refs.data(), 0, 123, m, *lo);
        canopy::bin(refs.data(), 123, n, m, *hi);
        hi->merge(*lo, nb);
        for (int a = 0; a < 3; ++a)
            for (uint32_t k = 0; k < nb; ++k) {
                EXPECT_EQ(hi->count(a, k), bins->count(a, k));
                EXPECT_EQ(bin_box(*hi, a, k), bin_box(*bins, a, k));
            }
    }
}

TEST(KernelBin, FlatNodesBinOnlyTheirValidAxes) {
    // Centroids flat on one or two axes: bin() takes its two-set path for
    // such nodes from kTwoBinSetsFlatMin records (alternate_updates()), and
    // its one-set path below that; the valid axes' bins match the mapping,
    // the flat axes' bins are left empty (not binned). Odd counts, and the
    // records also sorted along the valid axes (runs of shared bins).
    constexpr uint32_t n = canopy::kTwoBinSetsFlatMin + 77;
    static_assert(n % 2 == 1 && canopy::kTwoBinSetsFlatMin > canopy::kTwoBinSetsMin);
    for (const int flat_count : {1, 2})
    for (const uint32_t size : {n, canopy::kTwoBinSetsFlatMin - 1})
    for (const bool sorted : {false, true}) {
        std::vector<PrimRef> refs = random_refs(size, 11 + flat_count, 100.0f, 2.0f);
        for (PrimRef& r : refs)
            for (int a = 3 - flat_count; a < 3; ++a) r.lo[a] = r.hi[a] = 3.0f;
        if (sorted)
            std::sort(refs.begin(), refs.end(), [](const PrimRef& x, const PrimRef& y) {
                return std::pair(x.lo.x + x.hi.x, x.id) < std::pair(y.lo.x + y.hi.x, y.id);
            });
        const Bounds b = bounds_of(refs.data(), 0, size);
        const BinMapper m = BinMapper::make(b.cbounds, 32);
        ASSERT_EQ(m.valid_count(), 3 - flat_count);
        ASSERT_EQ(canopy::detail::two_bin_sets(m, 0, size), size >= canopy::kTwoBinSetsFlatMin);
        const auto bins = binned(refs, 0, size, m);
        for (int a = 0; a < 3; ++a)
            for (uint32_t k = 0; k < m.bins; ++k) {
                Box expected;
                uint32_t count = 0;
                if (m.valid[a])
                    for (const PrimRef& r : refs)
                        if (bin_index(m, canopy::centroid(r)[a], a) == k) {
                            expected.extend(r.lo);
                            expected.extend(r.hi);
                            ++count;
                        }
                EXPECT_EQ(bins->count(a, k), count) << "axis " << a << " bin " << k << " flat " << flat_count;
                EXPECT_EQ(bin_box(*bins, a, k), expected) << "axis " << a << " bin " << k << " flat " << flat_count;
            }
    }
}

// ---------------------------------------------------------------- evaluate

namespace {

// Moves coordinate 0 of every vector to `axis` (a cyclic rotation).
Vec3 rot(Vec3 v, int axis) {
    Vec3 r;
    for (int a = 0; a < 3; ++a) r[(a + axis) % 3] = v[a];
    return r;
}

}  // namespace

TEST(KernelEvaluate, TwoClustersFarApart) {
    // Unit cubes at x = 0, 15 (cluster A) and 85, 100 (cluster B); with 8
    // bins over [0, 100] they fall in bins 0, 1, 6, 7, so the splits 2..6
    // all separate A from B at the same cost; the lowest index (2) wins. The
    // other two coordinates interleave A and B, so no other axis can
    // separate them.
    for (int axis = 0; axis < 3; ++axis) {
        const std::vector<PrimRef> refs = {
            cube(rot(Vec3(0, 0, 2), axis), 0.5f, 0), cube(rot(Vec3(15, 3, 0), axis), 0.5f, 1),
            cube(rot(Vec3(85, 1, 3), axis), 0.5f, 2), cube(rot(Vec3(100, 2, 1), axis), 0.5f, 3)};
        const NodeTask t = task_of(refs, 0, 4);
        const BinMapper m = BinMapper::make(t.cbounds, 8);
        ASSERT_TRUE(m.valid[0] && m.valid[1] && m.valid[2]);
        const auto bins = binned(refs, 0, 4, m);
        BuildOptions opt;
        const Split s = canopy::evaluate(*bins, m, t.bounds, opt);
        ASSERT_TRUE(s.found());
        EXPECT_EQ(s.axis, axis);
        EXPECT_EQ(s.index, 2u);
        EXPECT_EQ(s.left_count, 2u);
        // Half areas: A = 16*4 + 4*3 + 3*16 = 124, B = 16*2 + 2*3 + 3*16 = 86,
        // node = 101*4 + 4*4 + 4*101 = 824.
        EXPECT_NEAR(s.cost, 1.0 + (124.0 * 2 + 86.0 * 2) / 824.0, 1e-6);

        // Costs enter as C_t + C_i * (...).
        opt.traversal_cost = 0.5f;
        opt.intersection_cost = 3.0f;
        const Split c = canopy::evaluate(*bins, m, t.bounds, opt);
        EXPECT_EQ(c.axis, axis);
        EXPECT_EQ(c.index, 2u);
        EXPECT_NEAR(c.cost, 0.5 + 3.0 * (124.0 * 2 + 86.0 * 2) / 824.0, 1e-6);
    }
}

TEST(KernelEvaluate, TiesGoToLowestAxisThenLowestIndex) {
    // Cubes on the diagonal at t = 0, 10, 20, 30: every axis sees the same
    // boxes. With 8 bins the centroids fall in bins 0, 2, 5, 7 and the splits
    // 3, 4, 5 tie as the best ({0, 10} | {20, 30}).
    std::vector<PrimRef> refs;
    for (uint32_t i = 0; i < 4; ++i) refs.push_back(cube(Vec3(10.0f * i), 0.5f, i));
    NodeTask t = task_of(refs, 0, 4);
    BinMapper m = BinMapper::make(t.cbounds, 8);
    auto bins = binned(refs, 0, 4, m);
    Split s = canopy::evaluate(*bins, m, t.bounds, BuildOptions{});
    ASSERT_TRUE(s.found());
    EXPECT_EQ(s.axis, 0);
    EXPECT_EQ(s.index, 3u);
    EXPECT_EQ(s.left_count, 2u);
    EXPECT_NEAR(s.cost, 1.0 + (363.0 * 2 + 363.0 * 2) / 2883.0, 1e-6);

    // The same on y and z only (x flat): y wins the tie.
    refs.clear();
    for (uint32_t i = 0; i < 4; ++i) refs.push_back(cube(Vec3(0.0f, 10.0f * i, 10.0f * i), 0.5f, i));
    t = task_of(refs, 0, 4);
    m = BinMapper::make(t.cbounds, 8);
    ASSERT_FALSE(m.valid[0]);
    bins = binned(refs, 0, 4, m);
    s = canopy::evaluate(*bins, m, t.bounds, BuildOptions{});
    ASSERT_TRUE(s.found());
    EXPECT_EQ(s.axis, 1);
    EXPECT_EQ(s.index, 3u);
}

namespace {

// `size` random records (seeded by rng_seed) in one of the variants that
// test evaluations' corner cases (by `variant`): small or large extents,
// every record flat on y, the record after `first` a copy of it, or
// mirror images (equal costs on two axes).
std::vector<PrimRef> varied_refs(uint32_t size, uint32_t rng_seed, uint32_t variant, uint32_t first) {
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

}  // namespace

TEST(KernelEvaluate, FourBinSweepsMatchTheGeneralOnes) {
    // evaluate() runs nodes of 4 bins through unrolled sweeps; they must pick
    // what the general sweeps pick, cost included, on nodes with empty bins,
    // flat axes, coincident centroids and ties.
    const BuildOptions opt;
    uint32_t found = 0;
    for (uint32_t seed = 0; seed < 400; ++seed) {
        const uint32_t n = 2 + seed % 15;
        const std::vector<PrimRef> refs = varied_refs(n, 7000 + seed, seed, 0);
        const NodeTask t = task_of(refs, 0, n);
        const BinMapper m = BinMapper::make(t.cbounds, 4);
        if (!m.any_valid()) continue;
        const auto bins = binned(refs, 0, n, m);
        const Split a = canopy::detail::evaluate_fixed<4>(*bins, m, t.bounds, opt);
        const Split b = canopy::detail::evaluate_fixed<0>(*bins, m, t.bounds, opt);
        ASSERT_EQ(a.axis, b.axis) << seed;
        EXPECT_EQ(a.index, b.index) << seed;
        EXPECT_EQ(a.left_count, b.left_count) << seed;
        EXPECT_EQ(a.cost, b.cost) << seed;
        const Split c = canopy::evaluate(*bins, m, t.bounds, opt);
        EXPECT_EQ(c.axis, a.axis);
        EXPECT_EQ(c.cost, a.cost);
        found += a.found();
    }
    EXPECT_GT(found, 300u);
}

TEST(KernelEvaluate, RegisterBinsMatchBinAndEvaluate) {
    // Nodes of 4 bins are binned and evaluated in registers where AVX-512 is
    // compiled in (bin_evaluate_4()); the split, its cost and the index rows
    // partition_binned() reads must be those of bin() and evaluate(), on
    // nodes with empty bins, flat axes, coincident centroids, mirror-image
    // ties, lines (length measure) and 5 to 64 records (more than 16 have 4
    // bins when the build asks for 4).
#if CANOPY_REGISTER_BINS
    BuildOptions opt;
    uint32_t found = 0, compared = 0;
    for (uint32_t seed = 0; seed < 1200; ++seed) {
        const uint32_t n = 5 + (seed % 3 == 2 ? seed % 60 : seed % 12);
        std::vector<PrimRef> refs = varied_refs(n + 3, 9100 + seed, seed, 3);
        if (seed % 10 == 5)  // points on a line: zero area, the length measure
            for (uint32_t i = 0; i < refs.size(); ++i)
                refs[i] = make_ref(Vec3(float(i % 5), 0, 0), Vec3(float(i % 5), 0, 0), i);
        opt.traversal_cost = seed % 3 == 0 ? 1.0f : 0.25f;
        const NodeTask t = task_of(refs, 3, 3 + n);
        const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(n, n <= 16 ? 32 : 4));
        ASSERT_EQ(m.bins, 4u) << n;
        if (!m.any_valid() || m.prescaled) continue;
        const auto expect_bins = binned(refs, 3, 3 + n, m);
        const Split a = canopy::evaluate(*expect_bins, m, t.bounds, opt);
        BinSet regs(32);
        const Split b = canopy::bin_evaluate_4(refs.data(), 3, 3 + n, m, regs, t.bounds, opt);
        ASSERT_EQ(a.axis, b.axis) << seed;
        EXPECT_EQ(a.index, b.index) << seed;
        EXPECT_EQ(a.left_count, b.left_count) << seed;
        EXPECT_EQ(a.cost, b.cost) << seed;
        for (uint32_t i = 0; i < n; ++i)
            for (int k = 0; k < 3; ++k) ASSERT_EQ(regs.index[i][k], expect_bins->index[i][k]) << seed;
        found += a.found();
        ++compared;
    }
    EXPECT_GT(compared, 1000u);
    EXPECT_GT(found, 800u);
#else
    GTEST_SKIP() << "built without AVX-512: nodes of 4 bins take bin() and evaluate()";
#endif
}

TEST(KernelEvaluate, NoSplitWhenNothingIsValid) {
    // Coincident centroids: no axis is valid.
    std::vector<PrimRef> refs;
    for (uint32_t i = 0; i < 6; ++i) refs.push_back(cube(Vec3(1, 2, 3), 0.5f * (i + 1), i));
    const NodeTask t = task_of(refs, 0, 6);
    const BinMapper m = BinMapper::make(t.cbounds, 16);
    ASSERT_FALSE(m.any_valid());
    const auto bins = binned(refs, 0, 6, m);
    const Split s = canopy::evaluate(*bins, m, t.bounds, BuildOptions{});
    EXPECT_FALSE(s.found());
    EXPECT_EQ(s.axis, -1);

    // A valid mapper but an empty node box (zero area measure).
    std::vector<PrimRef> two = {cube(Vec3(0, 0, 0), 0.5f, 0), cube(Vec3(5, 0, 0), 0.5f, 1)};
    const NodeTask u = task_of(two, 0, 2);
    const BinMapper mu = BinMapper::make(u.cbounds, 4);
    ASSERT_TRUE(mu.valid[0]);
    const auto bu = binned(two, 0, 2, mu);
    EXPECT_FALSE(canopy::evaluate(*bu, mu, Box::empty(), BuildOptions{}).found());
}

TEST(KernelEvaluate, CollinearPrimitivesUseLength) {
    // Points on the x axis: the node has zero half area, so splits are
    // ranked by the sum of extents. {0, 1} | {9, 10} is the clear best.
    std::vector<PrimRef> refs;
    for (float x : {0.0f, 1.0f, 9.0f, 10.0f}) refs.push_back(make_ref(Vec3(x, 0, 0), Vec3(x, 0, 0), 0));
    const NodeTask t = task_of(refs, 0, 4);
    ASSERT_EQ(t.bounds.half_area(), 0.0);
    const BinMapper m = BinMapper::make(t.cbounds, 4);
    const auto bins = binned(refs, 0, 4, m);
    const Split s = canopy::evaluate(*bins, m, t.bounds, BuildOptions{});
    ASSERT_TRUE(s.found());
    EXPECT_EQ(s.axis, 0);
    EXPECT_EQ(s.left_count, 2u);
    EXPECT_NEAR(s.cost, 1.0 + (1.0 * 2 + 1.0 * 2) / 10.0, 1e-6);
}

// ---------------------------------------------------------------- partition

namespace {

// A split on `axis` at bin `index`, with left_count counted by hand from
// the scalar centroid() and the mapping (partition() relies on it).
Split make_split(const std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, const BinMapper& m, int axis,
                 uint32_t index) {
    Split s;
    s.axis = axis;
    s.index = index;
    for (uint32_t i = begin; i < end; ++i) s.left_count += left_of(refs[i], m, s);
    return s;
}

// The canonical partition written out plainly: mid = begin + the number of
// records going left; the k-th record of [begin, mid) going right swaps with
// the k-th record of [mid, end) going left.
template <class Pred>
std::vector<PrimRef> reference_partition(std::vector<PrimRef> refs, uint32_t begin, uint32_t end, Pred goes_left) {
    uint32_t mid = begin;
    for (uint32_t i = begin; i < end; ++i) mid += goes_left(refs[i]);
    std::vector<uint32_t> right_in_left, left_in_right;
    for (uint32_t i = begin; i < mid; ++i)
        if (!goes_left(refs[i])) right_in_left.push_back(i);
    for (uint32_t i = mid; i < end; ++i)
        if (goes_left(refs[i])) left_in_right.push_back(i);
    EXPECT_EQ(right_in_left.size(), left_in_right.size());
    for (size_t k = 0; k < right_in_left.size(); ++k) std::swap(refs[right_in_left[k]], refs[left_in_right[k]]);
    return refs;
}

}  // namespace

TEST(KernelPartition, SwapsTheMisplacedPairsInOrder) {
    const uint32_t n = 300;
    const std::vector<PrimRef> input = random_refs(n, 11);
    // Ranges of one block, of several, and not aligned to 64.
    for (auto [begin, end] : {std::pair<uint32_t, uint32_t>{17, 271}, {0, 64}, {3, 50}, {64, 300}, {1, 129}}) {
        const NodeTask t = task_of(input, begin, end);
        for (uint32_t nb : {4u, 16u}) {
            const BinMapper m = BinMapper::make(t.cbounds, nb);
            for (int axis = 0; axis < 3; ++axis) {
                ASSERT_TRUE(m.valid[axis]);
                for (uint32_t idx = 1; idx < nb; ++idx) {
                    const Split s = make_split(input, begin, end, m, axis, idx);
                    std::vector<PrimRef> refs = input;
                    const PartitionResult p = canopy::partition(refs.data(), begin, end, m, s);
                    const auto pred = [&](const PrimRef& r) { return left_of(r, m, s); };
                    const std::vector<PrimRef> expected = reference_partition(input, begin, end, pred);
                    EXPECT_EQ(p.mid, begin + s.left_count);
                    // The predicate agrees with the kernel's own.
                    for (const PrimRef& r : input) ASSERT_EQ(canopy::goes_left(r, m, s), pred(r));
                    // Bit for bit, outside the range too (nothing written there).
                    ASSERT_TRUE(same_records(refs, expected))
                        << "range " << begin << ".." << end << " axis " << axis << " index " << idx;
                    for (uint32_t i = begin; i < end; ++i) EXPECT_EQ(pred(refs[i]), i < p.mid) << i;
                    expect_child_bounds(p, refs.data(), begin, end);
                }
            }
        }
    }
}

TEST(KernelPartition, ThresholdSideTestMatchesTheBinIndex) {
    // split_threshold(): the smallest float whose bin index on the axis is
    // at least k; the side test by threshold equals the one by index, for
    // centroids around every threshold and random ones, over boxes of
    // ordinary, tiny (prescaled), huge and far-from-origin extents.
    const Box boxes[] = {
        {Vec3(0, 0, 0), Vec3(1, 2, 3)},
        {Vec3(-5, 7, 1e6f), Vec3(3, 7.5f, 1e6f + 1)},
        {Vec3(1e-30f, -2e-30f, 0), Vec3(4e-30f, 1e-30f, 1e-38f)},
        {Vec3(-3e38f, -1e38f, 0), Vec3(3e38f, 1e38f, 3e38f)},
        {Vec3(0.1f, 0.2f, 0.3f), Vec3(0.1f + 1e-6f, 0.2f + 1e-5f, 0.3f + 1e-4f)},
    };
    std::mt19937 rng(5);
    const auto below = [](float f) { return std::nextafter(f, -FLT_MAX); };
    const auto above = [](float f) { return std::nextafter(f, FLT_MAX); };
    int checked = 0;
    for (const Box& box : boxes) {
        for (uint32_t nb : {2u, 4u, 16u, 32u, 256u}) {
            const BinMapper m = BinMapper::make(box, nb);
            for_each_plane_split(m, [&](const Split& s) {
                const int axis = s.axis;
                const uint32_t k = s.index;
                const float t = canopy::split_threshold(m, axis, k);
                Vec3 at = box.lo;
                at[axis] = t;
                Vec3 before = box.lo;
                before[axis] = below(t);
                EXPECT_GE(bin_index(m, at, axis), k) << "axis " << axis << " k " << k;
                EXPECT_LT(bin_index(m, before, axis), k) << "axis " << axis << " k " << k;
                const canopy::SideTest by_threshold(m, s);
                const canopy::SideIndexTest<> by_index(m, s);
                std::uniform_real_distribution<float> u(0.0f, 1.0f);
                for (int i = 0; i < 40; ++i) {
                    Vec3 c = box.lo;
                    const float f = u(rng);
                    c[axis] = i < 6 ? std::array<float, 6>{below(below(t)), below(t), t, above(t), above(above(t)),
                                                           box.hi[axis]}[i]
                                    : box.lo[axis] * (1.0f - f) + box.hi[axis] * f;
                    const __m128 c4 = canopy::simd::vec(c);
                    ASSERT_EQ(by_threshold.left(c4, c4), by_index.left(c4, c4))
                        << "axis " << axis << " k " << k << " c " << c[axis] << " t " << t;
                    if (!m.prescaled) {  // what partition() uses then
                        const canopy::SideIndexTest<false> plain(m, s);
                        ASSERT_EQ(plain.left(c4, c4), by_index.left(c4, c4)) << "axis " << axis << " k " << k;
                    }
                    ++checked;
                }
            });
        }
    }
    EXPECT_GT(checked, 10000);
}

TEST(KernelPartition, BlockMaskMatchesTheRecordTest) {
    // left_mask() of a whole block (with AVX2, eight records at a time from
    // the split axis's lanes, see there) equals the record-by-record test,
    // for the threshold test and both index tests, at unit scale and at
    // 2^-80 (prescaled mapping), for every plane split of 4 and 32 bins.
    int checked = 0;
    for (const float unit : {1.0f, 0x1p-80f}) {
        const std::vector<PrimRef> refs = random_refs(3 * canopy::kSideBlock, 23, 100.0f * unit, 2.0f * unit);
        const Bounds b = bounds_of(refs.data(), 0, uint32_t(refs.size()));
        for (const uint32_t nb : {4u, 32u}) {
            const BinMapper m = BinMapper::make(b.cbounds, nb);
            ASSERT_EQ(m.prescaled, unit != 1.0f);
            for_each_plane_split(m, [&](const Split& s) {
                const auto one_by_one = [&](const PrimRef* r, const auto& side) {
                    uint64_t mask = 0;
                    for (uint32_t k = 0; k < canopy::kSideBlock; ++k)
                        mask |= uint64_t(left_of(r[k], m, s)) << k;
                    EXPECT_EQ(canopy::left_mask(r, canopy::kSideBlock, side), mask)
                        << "axis " << s.axis << " index " << s.index << " unit " << unit;
                    ++checked;
                };
                for (uint32_t at = 0; at + canopy::kSideBlock <= refs.size(); at += canopy::kSideBlock) {
                    one_by_one(refs.data() + at, canopy::SideTest(m, s));
                    one_by_one(refs.data() + at, canopy::SideIndexTest<>(m, s));
                    if (!m.prescaled) one_by_one(refs.data() + at, canopy::SideIndexTest<false>(m, s));
                }
            });
        }
    }
    EXPECT_GT(checked, 500);
}

TEST(KernelPartition, HandMadeOrder) {
    // Centroids x: 5 0 9 1 8 2 (ids 0..5); with 2 bins over [0, 9] the ones
    // below 4.5 go left: ids 1, 3, 5, so mid = 3. In [0, 3), ids 0 and 2 go
    // right; in [3, 6), ids 3 and 5 go left: 0 swaps with 3, 2 with 5.
    std::vector<PrimRef> refs;
    const float xs[] = {5, 0, 9, 1, 8, 2};
    for (uint32_t i = 0; i < 6; ++i) refs.push_back(make_ref(Vec3(xs[i], 0, 0), Vec3(xs[i], 1, 1), i));
    const NodeTask t = task_of(refs, 0, 6);
    const BinMapper m = BinMapper::make(t.cbounds, 2);
    const Split s = make_split(refs, 0, 6, m, 0, 1);
    EXPECT_EQ(s.left_count, 3u);
    const PartitionResult p = canopy::partition(refs.data(), 0, 6, m, s);
    EXPECT_EQ(p.mid, 3u);
    const uint32_t expected_ids[] = {3, 1, 5, 0, 4, 2};
    for (uint32_t i = 0; i < 6; ++i) EXPECT_EQ(refs[i].id, expected_ids[i]) << i;
    EXPECT_EQ(p.left_bounds(), (Box{Vec3(0, 0, 0), Vec3(2, 1, 1)}));
    EXPECT_EQ(p.right_bounds(), (Box{Vec3(5, 0, 0), Vec3(9, 1, 1)}));
    EXPECT_EQ(p.left_cbounds(), (Box{Vec3(0, 0.5f, 0.5f), Vec3(2, 0.5f, 0.5f)}));
    EXPECT_EQ(p.right_cbounds(), (Box{Vec3(5, 0.5f, 0.5f), Vec3(9, 0.5f, 0.5f)}));
}

TEST(KernelPartition, EvaluatedSplitPartitionsAsCounted) {
    // The split evaluate() returns carries the left count partition() uses.
    const std::vector<PrimRef> input = random_refs(1000, 12);
    const NodeTask t = task_of(input, 0, 1000);
    for (uint32_t nb : {2u, 16u, 256u}) {
        const BinMapper m = BinMapper::make(t.cbounds, nb);
        const auto bins = binned(input, 0, 1000, m);
        const Split s = canopy::evaluate(*bins, m, t.bounds, BuildOptions{});
        ASSERT_TRUE(s.found());
        EXPECT_EQ(s.left_count, make_split(input, 0, 1000, m, s.axis, s.index).left_count);
        uint32_t from_bins = 0;
        for (uint32_t k = 0; k < s.index; ++k) from_bins += bins->count(s.axis, k);
        EXPECT_EQ(s.left_count, from_bins);
        std::vector<PrimRef> refs = input;
        const PartitionResult p = canopy::partition(refs.data(), 0, 1000, m, s);
        EXPECT_EQ(p.mid, s.left_count);
        for (uint32_t i = 0; i < 1000; ++i) EXPECT_EQ(left_of(refs[i], m, s), i < p.mid) << i;
    }
}

TEST(KernelPartition, BinnedSidesMatchPartition) {
    // partition_binned() reads the sides from the indices bin() left behind;
    // it must leave the records and report the bounds as partition() does.
    // Nodes of 1 to 64 records; some with a flat axis, some with neighbours
    // sharing centroids; every valid axis and split index of several bin
    // counts, not only the evaluated one.
    uint32_t splits = 0;
    for (uint32_t n = 1; n <= canopy::kBinBlock; ++n) {
        std::vector<PrimRef> input = random_refs(n, 100 + n, 10.0f, 1.0f);
        if (n % 3 == 0)
            for (auto& r : input) {
                r.hi.z = r.lo.z = 4.0f;
                refresh_area(r);
            }
        if (n % 5 == 0)
            for (uint32_t i = 1; i < n; i += 2) input[i] = make_ref(input[i - 1].lo, input[i - 1].hi, input[i].id);
        const NodeTask t = task_of(input, 0, n);
        for (uint32_t nb : {2u, 4u, 7u, 32u}) {
            const BinMapper m = BinMapper::make(t.cbounds, nb);
            for_each_plane_split(m, [&](Split s) {
                for (const auto& r : input) s.left_count += left_of(r, m, s);
                std::vector<PrimRef> a = input, b = input;
                const auto bins = binned(a, 0, n, m);
                const PartitionResult pa = canopy::partition_binned(a.data(), 0, n, s, *bins);
                const PartitionResult pb = canopy::partition(b.data(), 0, n, m, s);
                ASSERT_TRUE(same_records(a, b)) << n << " " << nb << " " << s.axis << " " << s.index;
                EXPECT_EQ(pa.mid, pb.mid);
                expect_child_bounds(pa, a.data(), 0, n);
                ++splits;
            });
        }
    }
    EXPECT_GT(splits, 3000u);
}

namespace {

// A block size of the order the team-parallel node uses.
constexpr uint32_t kBlock = 16384;

// Both children's bounds, centroid bounds and largest areas equal.
void expect_same_children(const PartitionResult& got, const PartitionResult& want) {
    EXPECT_EQ(got.left_bounds(), want.left_bounds());
    EXPECT_EQ(got.left_cbounds(), want.left_cbounds());
    EXPECT_EQ(got.left_max_area(), want.left_max_area());
    EXPECT_EQ(got.right_bounds(), want.right_bounds());
    EXPECT_EQ(got.right_cbounds(), want.right_cbounds());
    EXPECT_EQ(got.right_max_area(), want.right_max_area());
}

// The partition as a team-parallel node runs it, on `refs`: mark_sides() on
// consecutive `ranges` (starting at multiples of 64 from the first), in a
// shuffled order; plan_swaps() with `per_piece`; the pieces swapped in a
// shuffled order. Returns the merged bounds, mid = the node's mid.
PartitionResult blocked_partition(std::vector<PrimRef>& refs,
                                  const std::vector<std::pair<uint32_t, uint32_t>>& ranges, const BinMapper& m,
                                  const Split& s, uint32_t per_piece, uint32_t seed = 1) {
    const uint32_t begin = ranges.front().first, end = ranges.back().second;
    std::vector<uint64_t> sides((end - begin + 63) / 64, 0x5555555555555555u);  // garbage: all overwritten
    std::vector<size_t> order(ranges.size());
    std::iota(order.begin(), order.end(), size_t(0));
    std::mt19937 rng(seed);
    std::shuffle(order.begin(), order.end(), rng);
    PartitionResult merged;
    for (size_t k : order) {
        EXPECT_EQ((ranges[k].first - begin) % 64, 0u);
        merged.merge(canopy::mark_sides(refs.data(), ranges[k].first, ranges[k].second, begin, m, s, sides.data()));
    }
    uint32_t right_in_left = 0;  // records to swap out of the left part
    for (uint32_t i = begin; i < begin + s.left_count; ++i) right_in_left += !canopy::goes_left(refs[i], m, s);
    std::vector<canopy::SwapPiece> pieces;
    canopy::plan_swaps(sides.data(), begin, begin + s.left_count, per_piece, pieces);
    uint32_t pairs = 0;
    for (const auto& p : pieces) {
        EXPECT_GT(p.count, 0u);
        EXPECT_LE(p.count, per_piece);
        pairs += p.count;
    }
    std::shuffle(pieces.begin(), pieces.end(), rng);
    for (const auto& p : pieces) canopy::swap_misplaced(refs.data(), sides.data(), begin, p);
    // Every misplaced pair was in some piece: afterwards all sides are right.
    uint32_t misplaced = 0;
    for (uint32_t i = begin; i < begin + s.left_count; ++i) misplaced += !canopy::goes_left(refs[i], m, s);
    EXPECT_EQ(misplaced, 0u);
    EXPECT_EQ(pairs, right_in_left);
    merged.mid = begin + s.left_count;
    return merged;
}

}  // namespace

TEST(KernelPartition, BlockedMatchesPartitionBitForBit) {
    struct Case {
        uint32_t n, begin, end;
        std::vector<uint32_t> blocks;  // cycled; multiples of 64
        uint32_t per_piece;
    };
    const uint32_t big = 2 * kBlock + 123;
    const Case cases[] = {
        {400, 0, 400, {64, 128, 192}, 1},
        {400, 33, 377, {64}, 5},
        {400, 10, 12, {64}, 1},
        {400, 50, 350, {1024}, 1000},
        {big, 0, big, {kBlock}, 4096},
        {big, 1000, big - 7, {kBlock, 64, kBlock / 2}, 1000},
        {big, 3, big, {kBlock}, 1u << 30},
    };
    for (const Case& c : cases) {
        const std::vector<PrimRef> input = random_refs(c.n, 21 + c.begin);
        const NodeTask t = task_of(input, c.begin, c.end);
        const BinMapper m = BinMapper::make(t.cbounds, 16);
        for (int axis = 0; axis < 3; ++axis) {
            if (!m.valid[axis]) continue;
            for (uint32_t idx : {1u, 5u, 8u, 15u}) {
                const Split s = make_split(input, c.begin, c.end, m, axis, idx);
                // Reference: partition().
                std::vector<PrimRef> ref = input;
                const PartitionResult p = canopy::partition(ref.data(), c.begin, c.end, m, s);

                std::vector<std::pair<uint32_t, uint32_t>> ranges;
                for (uint32_t b = c.begin, k = 0; b < c.end; ++k) {
                    const uint32_t e = std::min(c.end, b + c.blocks[k % c.blocks.size()]);
                    ranges.push_back({b, e});
                    b = e;
                }
                std::vector<PrimRef> out = input;
                const PartitionResult merged = blocked_partition(out, ranges, m, s, c.per_piece, idx);
                EXPECT_EQ(merged.mid, p.mid);
                ASSERT_TRUE(same_records(out, ref)) << "n " << c.n << " axis " << axis << " index " << idx;
                expect_same_children(merged, p);
            }
        }
    }
}

namespace {

// The two-ended partition as a team of two runs it: both halves (in the
// order given; they touch disjoint records), then their leftovers paired.
PartitionResult halves_partition(std::vector<PrimRef>& refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                 const Split& s, bool back_first, uint32_t& leftovers) {
    canopy::HalfLeftovers front, back;
    PartitionResult r0, r1;
    if (back_first) r1 = canopy::partition_half<1>(refs.data(), begin, end, m, s, back);
    r0 = canopy::partition_half<0>(refs.data(), begin, end, m, s, front);
    if (!back_first) r1 = canopy::partition_half<1>(refs.data(), begin, end, m, s, back);
    EXPECT_EQ(front.count, back.count);
    leftovers = front.count;
    canopy::swap_leftovers(refs.data(), front, back);
    r0.merge(r1);
    r0.mid = begin + s.left_count;
    return r0;
}

}  // namespace

TEST(KernelPartition, HalvesMatchPartitionBitForBit) {
    // Shuffled records (few leftovers), records sorted along the split axis
    // either way (every misplaced record of one half's parts is a leftover:
    // ascending has none misplaced, descending all), and sizes from a
    // handful of records to several blocks.
    const uint32_t big = 2 * kBlock + 123;
    uint32_t cases_with_leftovers = 0, cases_without = 0;
    for (const uint32_t n : {7u, 70u, 400u, big}) {
        for (const int order : {0, 1, 2}) {
            std::vector<PrimRef> input = random_refs(n, 41 + n);
            if (order) {
                const bool up = order == 1;
                std::sort(input.begin(), input.end(), [up](const PrimRef& a, const PrimRef& b) {
                    const float ca = a.lo.x + a.hi.x, cb = b.lo.x + b.hi.x;
                    return up ? ca < cb : ca > cb;
                });
            }
            for (const auto& [begin, end] : {std::pair{0u, n}, std::pair{n / 7, n - n / 5}}) {
                if (end - begin < 2) continue;
                const NodeTask t = task_of(input, begin, end);
                const BinMapper m = BinMapper::make(t.cbounds, 16);
                for (int axis = 0; axis < 3; ++axis) {
                    if (!m.valid[axis]) continue;
                    for (uint32_t idx : {1u, 5u, 8u, 15u}) {
                        const Split s = make_split(input, begin, end, m, axis, idx);
                        if (s.left_count == 0 || s.left_count == end - begin) continue;
                        std::vector<PrimRef> ref = input;
                        const PartitionResult p = canopy::partition(ref.data(), begin, end, m, s);
                        for (const bool back_first : {false, true}) {
                            std::vector<PrimRef> out = input;
                            uint32_t leftovers = 0;
                            const PartitionResult h = halves_partition(out, begin, end, m, s, back_first, leftovers);
                            (leftovers ? cases_with_leftovers : cases_without)++;
                            ASSERT_TRUE(same_records(out, ref))
                                << "n " << n << " order " << order << " axis " << axis << " index " << idx;
                            EXPECT_EQ(h.mid, p.mid);
                            expect_same_children(h, p);
                        }
                    }
                }
            }
        }
    }
    // Both the pairing inside the halves and across them were exercised.
    EXPECT_GT(cases_with_leftovers, 10u);
    EXPECT_GT(cases_without, 10u);
}

TEST(KernelPartition, KeyedSidesMatchPartition) {
    // bin() with keys writes each record's three bin indices beside it (and
    // nothing else); partition_by_keys(), mark_sides() and partition_half()
    // given those keys move the records as partition() does from the
    // centroids; bounds_from_bins() then gives the children's boxes and
    // largest areas bit for bit as partition() grows them, and centroid
    // bounds that hold the children's centroids, within the child's box and
    // the node's centroid bounds, and on the split axis within the child's
    // bins. Ranges taking bin()'s one-set path, its two-set path and several
    // blocks, unaligned to 64; records shuffled and in order along x; some
    // with a flat axis (index 0 there); 2 to 256 bins.
    uint32_t splits = 0;
    for (const uint32_t n : {70u, 300u, 1000u, 5000u}) {
        for (int order = 0; order < 3; ++order) {
            std::vector<PrimRef> input = random_refs(n, 300 + n + uint32_t(order), 10.0f, 1.0f);
            if (order == 1)
                std::sort(input.begin(), input.end(),
                          [](const PrimRef& a, const PrimRef& b) { return a.lo.x + a.hi.x < b.lo.x + b.hi.x; });
            if (order == 2)
                for (auto& r : input) {
                    r.hi.y = r.lo.y = -2.0f;
                    refresh_area(r);
                }
            const uint32_t begin = n / 9, end = n - n / 11;
            const NodeTask t = task_of(input, begin, end);
            for (const uint32_t nb : {2u, 16u, 256u}) {
                const BinMapper m = BinMapper::make(t.cbounds, nb);
                std::vector<uint32_t> keys(n, 0xDEADBEEFu);
                const auto plain = binned(input, begin, end, m);
                auto keyed = std::make_unique<BinSet>();
                keyed->clear(m.bins);
                canopy::bin(input.data(), begin, end, m, *keyed, keys.data());
                for (int a = 0; a < 3; ++a)
                    for (uint32_t b = 0; b < m.bins; ++b) {
                        ASSERT_EQ(keyed->count(a, b), plain->count(a, b));
                        ASSERT_EQ(keyed->box(a, b), plain->box(a, b));
                    }
                for (uint32_t i = 0; i < n; ++i) {
                    if (i < begin || i >= end) {
                        ASSERT_EQ(keys[i], 0xDEADBEEFu) << i;
                        continue;
                    }
                    const std::array<int32_t, 4> k = m.indices(canopy::simd::centroid(canopy::simd::lo(input[i]),
                                                                                     canopy::simd::hi(input[i])));
                    ASSERT_EQ(keys[i], uint32_t(k[0]) | uint32_t(k[1]) << 8 | uint32_t(k[2]) << 16) << i;
                }
                for_each_plane_split(m, [&](Split s) {
                    if (s.index % 5 != 1 && s.index + 1 != m.bins) return;  // a sample of the indices
                    for (uint32_t i = begin; i < end; ++i) s.left_count += left_of(input[i], m, s);
                    if (s.left_count == 0 || s.left_count == end - begin) return;
                    std::vector<PrimRef> want = input, got = input;
                    const PartitionResult p = canopy::partition(want.data(), begin, end, m, s);
                    PartitionResult q = canopy::partition_by_keys(got.data(), begin, end, s, keys.data());
                    ASSERT_TRUE(same_records(got, want)) << n << " " << nb << " " << s.axis << " " << s.index;
                    EXPECT_EQ(q.mid, p.mid);
                    canopy::bounds_from_bins(*keyed, m, t, s, q);
                    EXPECT_EQ(q.left_bounds(), p.left_bounds());
                    EXPECT_EQ(q.right_bounds(), p.right_bounds());
                    EXPECT_EQ(q.left_max_area(), p.left_max_area());
                    EXPECT_EQ(q.right_max_area(), p.right_max_area());
                    const double width = 1.0 / double(m.scale[s.axis]);
                    for (int side = 0; side < 2; ++side) {
                        const Box got_c = side ? q.right_cbounds() : q.left_cbounds();
                        const Box true_c = side ? p.right_cbounds() : p.left_cbounds();
                        const Box box = side ? p.right_bounds() : p.left_bounds();
                        for (int a = 0; a < 3; ++a) {
                            EXPECT_LE(got_c.lo[a], true_c.lo[a]);
                            EXPECT_GE(got_c.hi[a], true_c.hi[a]);
                            EXPECT_GE(got_c.lo[a], std::max(box.lo[a], t.cbounds.lo[a]));
                            EXPECT_LE(got_c.hi[a], std::min(box.hi[a], t.cbounds.hi[a]));
                        }
                        // On the split axis, within a bin of the centroids.
                        EXPECT_LE(double(true_c.lo[s.axis]) - double(got_c.lo[s.axis]), width * 1.01);
                        EXPECT_LE(double(got_c.hi[s.axis]) - double(true_c.hi[s.axis]), width * 1.01);
                    }
                    // Both halves of the two-ended partition, then the leftovers.
                    got = input;
                    canopy::HalfLeftovers front, back;
                    canopy::partition_half<0>(got.data(), begin, end, m, s, front, keys.data());
                    canopy::partition_half<1>(got.data(), begin, end, m, s, back, keys.data());
                    canopy::swap_leftovers(got.data(), front, back);
                    ASSERT_TRUE(same_records(got, want));
                    // The sides marked by chunks.
                    std::vector<uint64_t> sides((end - begin + 63) / 64), plain_sides(sides.size());
                    canopy::mark_sides(input.data(), begin, end, begin, m, s, sides.data(), keys.data());
                    canopy::mark_sides(input.data(), begin, end, begin, m, s, plain_sides.data());
                    EXPECT_EQ(sides, plain_sides);
                    ++splits;
                });
            }
        }
    }
    EXPECT_GT(splits, 200u);
}

TEST(KernelPartition, PlanSwapsCutsByRank) {
    // 130 records, mid = 70: sides by hand. Going right in [0, 70): 2, 3, 65,
    // 69; going left in [70, 130): 70, 100, 127, 129.
    std::vector<uint64_t> sides(3, 0);
    const auto set = [&](uint32_t i) { sides[i / 64] |= uint64_t(1) << (i % 64); };
    for (uint32_t i = 0; i < 70; ++i)
        if (i != 2 && i != 3 && i != 65 && i != 69) set(i);
    for (uint32_t i : {70u, 100u, 127u, 129u}) set(i);
    std::vector<canopy::SwapPiece> pieces;
    canopy::plan_swaps(sides.data(), 0, 70, 3, pieces);
    ASSERT_EQ(pieces.size(), 2u);
    EXPECT_EQ(pieces[0].left_at, 2u);
    EXPECT_EQ(pieces[0].right_at, 70u);
    EXPECT_EQ(pieces[0].count, 3u);
    EXPECT_EQ(pieces[1].left_at, 69u);
    EXPECT_EQ(pieces[1].right_at, 129u);
    EXPECT_EQ(pieces[1].count, 1u);
    // Offset node start: the same bits describe records 1000..1129.
    canopy::plan_swaps(sides.data(), 1000, 1070, 2, pieces);
    ASSERT_EQ(pieces.size(), 2u);
    EXPECT_EQ(pieces[1].left_at, 1065u);
    EXPECT_EQ(pieces[1].right_at, 1127u);
    EXPECT_EQ(canopy::next_side(sides.data(), 1000, 1066, false), 1069u);
    EXPECT_EQ(canopy::next_side(sides.data(), 1000, 1101, true), 1127u);
    // Nothing misplaced: no pieces.
    std::fill(sides.begin(), sides.end(), 0);
    for (uint32_t i = 0; i < 70; ++i) set(i);
    canopy::plan_swaps(sides.data(), 0, 70, 3, pieces);
    EXPECT_TRUE(pieces.empty());
}

TEST(KernelPartition, MiddleSplitKeepsOrderAndHalves) {
    const std::vector<PrimRef> refs = random_refs(41, 3);
    const std::vector<PrimRef> before = refs;
    for (auto [b, e] : {std::pair<uint32_t, uint32_t>{0, 41}, {3, 4}, {3, 5}, {10, 31}, {0, 2}}) {
        const PartitionResult p = canopy::middle_split(refs.data(), b, e);
        EXPECT_EQ(p.mid, b + (e - b) / 2);
        EXPECT_TRUE(same_records(refs, before));
        expect_child_bounds(p, refs.data(), b, e);
    }
}

// ---------------------------------------------------------------- emit

TEST(KernelEmit, ChildTasks) {
    NodeTask t;
    t.begin = 10;
    t.end = 30;
    t.depth = 3;
    t.rights = 2;
    t.is_right = true;
    t.parent_begin = 4;
    PartitionResult p;
    p.mid = 17;
    const auto box4 = canopy::simd::Box4::of;
    p.acc.bounds[0] = box4(Box{Vec3(0, 0, 0), Vec3(1, 1, 1)});
    p.acc.cbounds[0] = box4(Box{Vec3(0.5f), Vec3(0.5f)});
    p.acc.bounds[1] = box4(Box{Vec3(2, 0, 0), Vec3(4, 1, 1)});
    p.acc.cbounds[1] = box4(Box{Vec3(2.5f, 0.5f, 0.5f), Vec3(3.5f, 0.5f, 0.5f)});
    NodeTask c[2];
    canopy::emit(t, p, c);

    EXPECT_EQ(c[0].begin, 10u);
    EXPECT_EQ(c[0].end, 17u);
    EXPECT_EQ(c[1].begin, 17u);
    EXPECT_EQ(c[1].end, 30u);
    EXPECT_EQ(c[0].size() + c[1].size(), t.size());
    EXPECT_EQ(c[0].bounds, p.left_bounds());
    EXPECT_EQ(c[0].cbounds, p.left_cbounds());
    EXPECT_EQ(c[1].bounds, p.right_bounds());
    EXPECT_EQ(c[1].cbounds, p.right_cbounds());
    for (int k = 0; k < 2; ++k) {
        EXPECT_EQ(c[k].depth, 4u);
        EXPECT_EQ(c[k].parent_begin, 10u);
    }
    EXPECT_EQ(c[0].rights, 2);  // the left child keeps the parent's rights
    EXPECT_EQ(c[1].rights, 3);
    EXPECT_FALSE(c[0].is_right);
    EXPECT_TRUE(c[1].is_right);
}

// ---------------------------------------------------------------- plan

TEST(KernelPlan, Rules) {
    BuildOptions opt;
    opt.max_leaf = 4;
    opt.max_depth = 10;
    auto task = [](uint32_t n, uint32_t depth) {
        NodeTask t;
        t.begin = 100;
        t.end = 100 + n;
        t.depth = depth;
        return t;
    };
    SkipCounts skip;
    // n <= 1: leaf, whatever the depth.
    EXPECT_EQ(canopy::plan(task(1, 0), opt, skip), Plan::Leaf);
    EXPECT_EQ(canopy::plan(task(0, 0), opt, skip), Plan::Leaf);
    EXPECT_EQ(canopy::plan(task(1, 10), opt, skip), Plan::Leaf);
    EXPECT_EQ(skip.single_leaves, 3u);
    EXPECT_EQ(skip.depth_cap_splits, 0u);

    // Enough budget: SAH. depth 6 -> budget 4; ceil_log2(8) = 3.
    EXPECT_EQ(canopy::plan(task(8, 6), opt, skip), Plan::Sah);
    EXPECT_EQ(canopy::plan(task(2, 0), opt, skip), Plan::Sah);
    EXPECT_EQ(canopy::plan(task(4, 6), opt, skip), Plan::Sah);  // ceil_log2(4) = 2 < 4
    EXPECT_EQ(skip.depth_cap_splits, 0u);

    // budget 4 <= ceil_log2(n) for n in 9..16 (= 4) and above.
    EXPECT_EQ(canopy::plan(task(9, 6), opt, skip), Plan::Middle);
    EXPECT_EQ(canopy::plan(task(16, 6), opt, skip), Plan::Middle);
    EXPECT_EQ(canopy::plan(task(17, 6), opt, skip), Plan::Middle);
    EXPECT_EQ(skip.depth_cap_splits, 3u);

    // Budget exhausted but the node fits in a leaf: leaf.
    EXPECT_EQ(canopy::plan(task(3, 9), opt, skip), Plan::Leaf);   // budget 1 <= 2
    EXPECT_EQ(canopy::plan(task(4, 10), opt, skip), Plan::Leaf);  // budget 0
    EXPECT_EQ(canopy::plan(task(2, 10), opt, skip), Plan::Leaf);
    EXPECT_EQ(canopy::plan(task(4, 12), opt, skip), Plan::Leaf);  // beyond max_depth
    EXPECT_EQ(canopy::plan(task(5, 9), opt, skip), Plan::Middle); // budget 1 <= 3, 5 > max_leaf
    EXPECT_EQ(skip.depth_cap_splits, 4u);
    EXPECT_EQ(skip.single_leaves, 3u);

    // The boundary exactly: budget == ceil_log2(n) is capped, budget - 1 is not.
    EXPECT_EQ(canopy::plan(task(32, 5), opt, skip), Plan::Middle);  // 5 <= 5
    EXPECT_EQ(canopy::plan(task(32, 4), opt, skip), Plan::Sah);     // 6 > 5

    EXPECT_EQ(canopy::ceil_log2(0), 0u);
    EXPECT_EQ(canopy::ceil_log2(1), 0u);
    EXPECT_EQ(canopy::ceil_log2(2), 1u);
    EXPECT_EQ(canopy::ceil_log2(3), 2u);
    EXPECT_EQ(canopy::ceil_log2(4), 2u);
    EXPECT_EQ(canopy::ceil_log2(5), 3u);
    EXPECT_EQ(canopy::ceil_log2(1u << 31), 31u);
    EXPECT_EQ(canopy::ceil_log2((1u << 31) + 1), 32u);
    EXPECT_EQ(canopy::ceil_log2(0xFFFFFFFFu), 32u);
}

TEST(KernelPlan, SahSaysLeaf) {
    BuildOptions opt;
    opt.max_leaf = 4;
    Split none;
    EXPECT_TRUE(canopy::sah_says_leaf(none, 4, opt));
    EXPECT_FALSE(canopy::sah_says_leaf(none, 5, opt));  // too big for a leaf: must split
    Split s;
    s.axis = 0;
    s.cost = 3.0;
    EXPECT_TRUE(canopy::sah_says_leaf(s, 3, opt));   // 3 >= 1 * 3
    EXPECT_FALSE(canopy::sah_says_leaf(s, 4, opt));  // 3 < 4
    EXPECT_FALSE(canopy::sah_says_leaf(s, 9, opt));
}

// ---------------------------------------------------------------- run_node

namespace {

// The records and a permutation, as a build owns them.
struct Buffers {
    std::vector<PrimRef> a;
    std::vector<uint32_t> perm;
    BuildOptions opt;
    explicit Buffers(const std::vector<PrimRef>& refs) : a(refs), perm(refs.size(), ~0u) {}
    canopy::KernelContext ctx() { return {a.data(), perm.data(), &opt, nullptr}; }
};

}  // namespace

TEST(KernelRunNode, CoincidentCentroids) {
    // Nested cubes around one point: all centroids coincide.
    std::vector<PrimRef> refs;
    for (uint32_t i = 0; i < 10; ++i) refs.push_back(cube(Vec3(1, 2, 3), float(i + 1), i));
    Buffers buf(refs);
    buf.opt.max_leaf = 4;
    const canopy::KernelContext ctx = buf.ctx();
    auto bins = std::make_unique<BinSet>();

    // n = 10 > max_leaf: a middle split, records left in place.
    SkipCounts skip;
    NodeTask children[2];
    ASSERT_TRUE(canopy::run_node(ctx, task_of(refs, 0, 10), children, *bins, skip));
    EXPECT_EQ(skip.coincident_nodes, 1u);
    EXPECT_EQ(skip.depth_cap_splits, 0u);
    EXPECT_TRUE(same_records(buf.a, refs));
    EXPECT_EQ(children[0].begin, 0u);
    EXPECT_EQ(children[0].end, 5u);
    EXPECT_EQ(children[1].begin, 5u);
    EXPECT_EQ(children[1].end, 10u);
    EXPECT_EQ(children[0].bounds, (Box{Vec3(1, 2, 3) - Vec3(5), Vec3(1, 2, 3) + Vec3(5)}));
    EXPECT_EQ(children[1].bounds, (Box{Vec3(1, 2, 3) - Vec3(10), Vec3(1, 2, 3) + Vec3(10)}));
    EXPECT_EQ(children[0].cbounds, (Box{Vec3(1, 2, 3), Vec3(1, 2, 3)}));
    EXPECT_EQ(children[0].depth, 1u);
    EXPECT_EQ(children[1].rights, 1);
    for (uint32_t v : buf.perm) EXPECT_EQ(v, ~0u);  // no leaf yet

    // n = 4 (kExactMaxPrims): costed exactly, not binned. The cubes of half
    // sizes 3, 4, 5 and 6 split as {3, 4} | {5, 6}: 1 + (2 * 16 + 2 * 36) / 36
    // = 3.89 below the leaf's 4, although no plane separates any of them.
    SkipCounts skip2;
    ASSERT_TRUE(canopy::run_node(ctx, task_of(refs, 2, 6), children, *bins, skip2));
    EXPECT_EQ(skip2.exact_nodes, 1u);
    EXPECT_EQ(skip2.coincident_nodes, 0u);
    EXPECT_TRUE(same_records(buf.a, refs));  // the two smaller ones were first already
    EXPECT_EQ(children[0].begin, 2u);
    EXPECT_EQ(children[0].end, 4u);
    EXPECT_EQ(children[1].end, 6u);
    EXPECT_EQ(children[1].bounds, (Box{Vec3(1, 2, 3) - Vec3(6), Vec3(1, 2, 3) + Vec3(6)}));
    for (uint32_t v : buf.perm) EXPECT_EQ(v, ~0u);

    // n = 5 <= max_leaf: too many to cost exactly, coincident: a leaf, which
    // writes its ids.
    buf.opt.max_leaf = 8;
    SkipCounts skip2b;
    EXPECT_FALSE(canopy::run_node(ctx, task_of(refs, 2, 7), children, *bins, skip2b));
    EXPECT_EQ(skip2b.coincident_nodes, 1u);
    EXPECT_EQ(skip2b.single_leaves, 0u);
    EXPECT_TRUE(same_records(buf.a, refs));
    for (uint32_t i = 0; i < 10; ++i) EXPECT_EQ(buf.perm[i], i >= 2 && i < 7 ? i : ~0u) << i;
    buf.opt.max_leaf = 4;

    // n = 1: a leaf without looking at the centroids.
    SkipCounts skip3;
    EXPECT_FALSE(canopy::run_node(ctx, task_of(refs, 7, 8), children, *bins, skip3));
    EXPECT_EQ(skip3.single_leaves, 1u);
    EXPECT_EQ(skip3.coincident_nodes, 0u);
    EXPECT_EQ(buf.perm[7], 7u);

    // A leaf writes the ids the records carry, wherever they are.
    for (uint32_t i = 0; i < 10; ++i) buf.a[i].id = 100 + i;
    SkipCounts skip4;
    EXPECT_FALSE(canopy::run_node(ctx, task_of(refs, 8, 10), children, *bins, skip4));
    EXPECT_EQ(buf.perm[8], 108u);
    EXPECT_EQ(buf.perm[9], 109u);
}

TEST(KernelRunNode, BigNodesBinTheAxisTheSampleChooses) {
    // A node of kSampleMin records or more: its sample (every
    // sample_step()-th record from its first) binned on all axes and
    // evaluated gives the axis; all its records binned on that axis alone
    // (bin_one_axis(), with keys) and evaluated give the split; run_node()
    // partitions by it. Ranges with an odd tail (not a multiple of 16 or 4)
    // whose steps are 4, 8 and 32, and a big one whose large primitives
    // keep it at 4 (sample_step(t)), in sorted and random order; the
    // sample's axis must differ from the axis of the best split over all
    // axes in at least one case, or the test shows nothing the plain
    // binning would not.
    bool differs = false;
    std::vector<uint32_t> steps;
    for (const auto& [n, size] : {std::pair(canopy::kSampleMin * 3 + 37, 30.0f), std::pair(9000u + 37, 2.0f),
                                 std::pair(33000u + 5, 2.0f), std::pair(33000u + 5, 30.0f)})
    for (const uint64_t seed : {3u, 4u, 5u, 6u, 7u, 8u, 9u, 10u})
    for (const bool sorted : {false, true}) {
        const uint32_t lo = 5, hi = lo + n;
        std::vector<PrimRef> input = random_refs(hi + 3, seed, 100.0f, size);
        if (sorted)
            std::sort(input.begin() + lo, input.begin() + hi, [](const PrimRef& x, const PrimRef& y) {
                return std::pair(x.lo.y + x.hi.y, x.id) < std::pair(y.lo.y + y.hi.y, y.id);
            });
        Buffers buf(input);
        const canopy::KernelContext ctx = buf.ctx();
        auto bins = std::make_unique<BinSet>();
        SkipCounts skip;
        NodeTask t = task_of(input, lo, hi, 1);
        t.max_area = bounds_of(input.data(), lo, hi).max_area;
        const uint32_t step = canopy::sample_step(t);
        if (seed == 3 && !sorted) steps.push_back(step);
        NodeTask children[2];
        ASSERT_TRUE(canopy::run_node(ctx, t, children, *bins, skip));
        EXPECT_EQ(skip.sampled_axes, 1u);

        const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(n, buf.opt.bins));
        ASSERT_TRUE(canopy::samples_axis(m, n));
        // The sample by hand, through the plain bin().
        std::vector<PrimRef> sample;
        for (uint32_t i = lo; i < hi; i += step) sample.push_back(input[i]);
        const auto sb = binned(sample, 0, uint32_t(sample.size()), m);
        const Split guess = canopy::evaluate(*sb, m, t.bounds, buf.opt);
        ASSERT_TRUE(guess.found());
        const auto all = binned(input, lo, hi, m);
        differs = differs || canopy::evaluate(*all, m, t.bounds, buf.opt).axis != guess.axis;
        // All records on the sample's axis.
        const BinMapper one = m.only(guess.axis);
        ASSERT_EQ(one.valid_count(), 1);
        std::vector<uint32_t> keys(input.size(), 0xDEADBEEFu);
        auto b = std::make_unique<BinSet>();
        b->clear(one.bins);
        canopy::bin(input.data(), lo, hi, one, *b, keys.data());
        for (uint32_t k = 0; k < one.bins; ++k) {
            Box expected;
            uint32_t count = 0;
            for (uint32_t i = lo; i < hi; ++i)
                if (bin_index(m, canopy::centroid(input[i])[guess.axis], guess.axis) == k) {
                    expected.extend(input[i].lo);
                    expected.extend(input[i].hi);
                    ++count;
                }
            ASSERT_EQ(b->count(guess.axis, k), count) << "bin " << k;
            ASSERT_EQ(bin_box(*b, guess.axis, k), expected) << "bin " << k;
        }
        for (uint32_t i = 0; i < input.size(); ++i) {
            const uint32_t want = i < lo || i >= hi ? 0xDEADBEEFu
                                                     : bin_index(m, canopy::centroid(input[i]), guess.axis)
                                                           << (8 * guess.axis);
            ASSERT_EQ(keys[i], want) << "record " << i;
        }
        const Split s = canopy::evaluate(*b, one, t.bounds, buf.opt);
        ASSERT_TRUE(s.found());
        EXPECT_EQ(s.axis, guess.axis);
        std::vector<PrimRef> expected = input;
        PartitionResult p = canopy::partition_by_keys(expected.data(), lo, hi, s, keys.data());
        canopy::bounds_from_bins(*b, one, t, s, p);
        EXPECT_TRUE(same_records(buf.a, expected));
        EXPECT_EQ(children[0].end, p.mid);
        EXPECT_EQ(children[0].bounds, p.left_bounds());
        EXPECT_EQ(children[1].bounds, p.right_bounds());
        EXPECT_EQ(children[1].cbounds, p.right_cbounds());
    }
    EXPECT_TRUE(differs) << "no case where the sample chose another axis than all records would";
    EXPECT_EQ(steps, (std::vector<uint32_t>{4, 8, 32, 4}));
}

TEST(KernelRunNode, SampleStepKeepsTheSampleBig) {
    // Every fourth record below 8,192; then the step doubles while the
    // sample keeps kSampleTarget records, up to kSampleMaxStep; a step
    // always divides the 64-record chunks of a team's node. A node whose
    // largest primitive has 1/kSampleLargePrim of its half area or more
    // samples every fourth record at any size.
    NodeTask t;
    t.begin = 0;
    t.end = 100000;
    t.bounds = canopy::Box{Vec3(0.0f), Vec3(1.0f)};  // half area 3
    t.max_area = 3.0f / 32.0f;
    EXPECT_EQ(canopy::sample_step(t), 4u);
    t.max_area = std::nextafter(3.0f / 32.0f, 0.0f);
    EXPECT_EQ(canopy::sample_step(t), 32u);
    t.max_area = 0.0f;
    EXPECT_EQ(canopy::sample_step(t), 32u);
    t.end = 9000;
    EXPECT_EQ(canopy::sample_step(t), 8u);
    EXPECT_EQ(canopy::sample_step(canopy::kSampleMin), 4u);
    EXPECT_EQ(canopy::sample_step(8191), 4u);
    EXPECT_EQ(canopy::sample_step(8192), 8u);
    EXPECT_EQ(canopy::sample_step(16383), 8u);
    EXPECT_EQ(canopy::sample_step(16384), 16u);
    EXPECT_EQ(canopy::sample_step(32768), 32u);
    EXPECT_EQ(canopy::sample_step(~0u), 32u);
    for (uint32_t n = canopy::kSampleMin; n < (1u << 22); n += n / 7 + 1) {
        const uint32_t s = canopy::sample_step(n);
        EXPECT_EQ(64 % s, 0u) << n;
        if (s > canopy::kSampleStep) {
            EXPECT_GE(n / s, canopy::kSampleTarget) << n;
        }
        if (s < canopy::kSampleMaxStep) {
            EXPECT_LT(n / (2 * s), canopy::kSampleTarget) << n;
        }
    }
}

TEST(KernelRunNode, SahSplitMatchesTheSteps) {
    const std::vector<PrimRef> input = random_refs(200, 77);
    {
        Buffers buf(input);
        const canopy::KernelContext ctx = buf.ctx();
        auto bins = std::make_unique<BinSet>();
        SkipCounts skip;
        NodeTask t = task_of(input, 20, 180, 2);
        t.rights = 1;
        NodeTask children[2];
        ASSERT_TRUE(canopy::run_node(ctx, t, children, *bins, skip));

        // The same by hand: a node of more than kBinBlock records is
        // partitioned by its keys and its children's bounds come from the bins.
        static_assert(180 - 20 > canopy::kBinBlock);
        const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(t.size(), buf.opt.bins));
        std::vector<uint32_t> keys(200);
        auto b = std::make_unique<BinSet>();
        b->clear(m.bins);
        canopy::bin(input.data(), 20, 180, m, *b, keys.data());
        const Split s = canopy::evaluate(*b, m, t.bounds, buf.opt);
        ASSERT_TRUE(s.found());
        std::vector<PrimRef> expected = input;
        PartitionResult p = canopy::partition_by_keys(expected.data(), 20, 180, s, keys.data());
        canopy::bounds_from_bins(*b, m, t, s, p);
        EXPECT_TRUE(same_records(buf.a, expected));
        EXPECT_FALSE(same_records(buf.a, input));
        EXPECT_EQ(children[0].end, p.mid);
        EXPECT_EQ(children[0].begin, 20u);
        EXPECT_EQ(children[1].end, 180u);
        EXPECT_EQ(children[0].bounds, p.left_bounds());
        EXPECT_EQ(children[1].cbounds, p.right_cbounds());
        // The plain partition moves the same records and grows the same boxes.
        std::vector<PrimRef> plain = input;
        const PartitionResult q = canopy::partition(plain.data(), 20, 180, m, s);
        EXPECT_TRUE(same_records(plain, expected));
        EXPECT_EQ(children[0].bounds, q.left_bounds());
        EXPECT_EQ(children[1].bounds, q.right_bounds());
        EXPECT_EQ(children[0].depth, 3u);
        EXPECT_EQ(children[0].rights, 1);
        EXPECT_EQ(children[1].rights, 2);
        EXPECT_EQ(children[1].parent_begin, 20u);
        EXPECT_EQ(skip.coincident_nodes, 0u);
        EXPECT_EQ(skip.axes_not_binned, 0u);
    }

    // Depth budget exhausted: a middle split, counted, records in place.
    Buffers buf(input);
    const canopy::KernelContext ctx = buf.ctx();
    auto bins = std::make_unique<BinSet>();
    SkipCounts skip;
    NodeTask children[2];
    const NodeTask deep = task_of(input, 0, 200, buf.opt.max_depth - 3);  // budget 3 <= ceil_log2(200)
    ASSERT_TRUE(canopy::run_node(ctx, deep, children, *bins, skip));
    EXPECT_EQ(skip.depth_cap_splits, 1u);
    EXPECT_EQ(children[0].end, 100u);
    EXPECT_TRUE(same_records(buf.a, input));
}

// ---------------------------------------------------------------- size split

namespace {

// A record as prepare writes it: the area set.
PrimRef prepared(Vec3 lo, Vec3 hi, uint32_t id) {
    PrimRef r = make_ref(lo, hi, id);
    r.area = canopy::prim_area(lo, hi);
    return r;
}

// random_refs() with a few boxes many times larger.
std::vector<PrimRef> sized_refs(uint32_t n, uint32_t seed) {
    std::vector<PrimRef> refs = random_refs(n, seed);
    std::mt19937 rng(seed);
    for (PrimRef& r : refs) {
        if (rng() % 8 == 0) r.hi = r.hi + Vec3(uniform(rng, 10.0f, 60.0f));
        refresh_area(r);
    }
    return refs;
}

float max_area(const std::vector<PrimRef>& refs, uint32_t b, uint32_t e) {
    float m = 0.0f;
    for (uint32_t i = b; i < e; ++i) m = std::max(m, refs[i].area);
    return m;
}

// A room: four large wall boxes around 40 small cubes; node box [-1, 1]^3.
std::vector<PrimRef> room_refs() {
    std::vector<PrimRef> refs;
    std::mt19937 rng(5);
    for (uint32_t i = 0; i < 40; ++i)
        refs.push_back(prepared(Vec3(uniform(rng, -0.3f, 0.3f), uniform(rng, -0.3f, 0.3f), uniform(rng, -0.3f, 0.3f)),
                                Vec3(0.0f), i));
    for (PrimRef& r : refs) {
        r.hi = r.lo + Vec3(0.02f);
        refresh_area(r);
    }
    // Walls interleaved with the small ones: floor, ceiling, left, right.
    const Box walls[] = {{Vec3(-1, -1, -1), Vec3(1, -1, 1)},
                         {Vec3(-1, 1, -1), Vec3(1, 1, 1)},
                         {Vec3(-1, -1, -1), Vec3(-1, 1, 1)},
                         {Vec3(1, -1, -1), Vec3(1, 1, 1)}};
    for (uint32_t k = 0; k < 4; ++k)
        refs.insert(refs.begin() + 10 * k + 3, prepared(walls[k].lo, walls[k].hi, 100 + k));
    return refs;
}

}  // namespace

TEST(KernelSizeSplit, PrimArea) {
    EXPECT_EQ(canopy::prim_area(Vec3(0, 0, 0), Vec3(1, 2, 3)), 11.0f);  // 1*2 + 2*3 + 3*1
    EXPECT_EQ(canopy::prim_area(Vec3(0, 0, 5), Vec3(2, 3, 5)), 6.0f);   // flat: one face
    EXPECT_EQ(canopy::prim_area(Vec3(1, 2, 3), Vec3(1, 2, 3)), 0.0f);   // a point
    EXPECT_EQ(canopy::prim_area(Vec3(0, 0, 0), Vec3(5, 0, 0)), 0.0f);   // a segment
    // Saturated, not infinite; never subnormal.
    EXPECT_EQ(canopy::prim_area(Vec3(-FLT_MAX), Vec3(FLT_MAX)), FLT_MAX);
    EXPECT_EQ(canopy::prim_area(Vec3(0), Vec3(1e-20f)), 0.0f);  // 3e-40 is below FLT_MIN
    const float e = 1e-18f;
    EXPECT_EQ(canopy::prim_area(Vec3(0), Vec3(e)), float(3.0 * double(e) * double(e)));  // normal: kept
}

TEST(KernelSizeSplit, ClassesAndWhenOffered) {
    const canopy::SizeCuts c = canopy::SizeCuts::of(Box{Vec3(0), Vec3(2)});  // half area 12
    EXPECT_EQ(c.half, 6.0f);
    EXPECT_EQ(c.quarter, 3.0f);
    EXPECT_EQ(c.size_class(12.0f), 0u);
    EXPECT_EQ(c.size_class(6.0f), 0u);
    EXPECT_EQ(c.size_class(5.99f), 1u);
    EXPECT_EQ(c.size_class(3.0f), 1u);
    EXPECT_EQ(c.size_class(2.99f), 2u);
    EXPECT_EQ(c.size_class(0.0f), 2u);
    NodeTask t;
    t.begin = 0;
    t.end = canopy::kSizeSplitMinPrims;
    t.max_area = 3.0f;
    EXPECT_TRUE(c.applies(t));
    t.max_area = 2.99f;
    EXPECT_FALSE(c.applies(t));  // nothing large
    t.max_area = 3.0f;
    t.end = canopy::kSizeSplitMinPrims - 1;
    EXPECT_FALSE(c.applies(t));  // too few primitives
    // A node of zero area is never offered the size split.
    const canopy::SizeCuts flat = canopy::SizeCuts::of(Box{Vec3(0), Vec3(0, 0, 7)});
    EXPECT_EQ(flat.quarter, 0.0f);
    t.end = 100;
    t.max_area = 0.0f;
    EXPECT_FALSE(flat.applies(t));
    // A huge node saturates its cuts at the largest float.
    const canopy::SizeCuts huge = canopy::SizeCuts::of(Box{Vec3(-FLT_MAX), Vec3(FLT_MAX)});
    EXPECT_EQ(huge.half, FLT_MAX);
    EXPECT_EQ(huge.quarter, FLT_MAX);
}

TEST(KernelSizeSplit, RoomIsSplitBySize) {
    const std::vector<PrimRef> refs = room_refs();
    const uint32_t n = uint32_t(refs.size());
    Buffers buf(refs);
    const canopy::KernelContext ctx = buf.ctx();
    auto bins = std::make_unique<BinSet>();
    SkipCounts skip;
    NodeTask t = task_of(refs, 0, n);
    t.max_area = max_area(refs, 0, n);
    ASSERT_EQ(t.bounds, (Box{Vec3(-1), Vec3(1)}));

    // By hand: the best plane, then the cuts.
    const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(n, buf.opt.bins));
    const auto b = binned(refs, 0, n, m);
    const Split plane = canopy::evaluate(*b, m, t.bounds, buf.opt);
    ASSERT_TRUE(plane.found());
    const canopy::SizeCuts cuts = canopy::SizeCuts::of(t.bounds);
    ASSERT_TRUE(cuts.applies(t));
    canopy::SizeBins sizes;
    canopy::bin_sizes(refs.data(), 0, n, cuts, sizes);
    EXPECT_EQ(sizes.count[0], 0u);
    EXPECT_EQ(sizes.count[1], 4u);  // walls: area 4 of 12
    EXPECT_EQ(sizes.count[2], 40u);
    Split s = plane;
    canopy::consider_size_split(sizes, cuts, t.bounds, buf.opt, s);
    ASSERT_TRUE(s.by_size());
    EXPECT_EQ(s.size_cut, cuts.quarter);
    EXPECT_EQ(s.left_count, 40u);
    EXPECT_LT(s.cost, plane.cost);
    // cost = 1 + (A(small) * 40 + A(walls) * 4) / A(node)
    Box small, walls;
    for (const PrimRef& r : refs) (r.id >= 100 ? walls : small).extend(Box{r.lo, r.hi});
    EXPECT_NEAR(s.cost, 1.0 + (small.half_area() * 40 + walls.half_area() * 4) / 12.0, 1e-9);

    // run_node takes it: the small ones left, the walls right, by the
    // canonical pair swaps.
    NodeTask children[2];
    ASSERT_TRUE(canopy::run_node(ctx, t, children, *bins, skip));
    EXPECT_EQ(skip.size_splits, 1u);
    EXPECT_EQ(children[0].size(), 40u);
    EXPECT_EQ(children[1].size(), 4u);
    EXPECT_TRUE(same_records(buf.a, reference_partition(refs, 0, n, [&](const PrimRef& r) { return r.area < s.size_cut; })));
    for (uint32_t i = 0; i < 44; ++i) EXPECT_EQ(buf.a[i].id < 100u, i < 40) << i;
    EXPECT_EQ(children[0].bounds, small);
    EXPECT_EQ(children[1].bounds, walls);
    EXPECT_EQ(children[0].max_area, max_area(buf.a, 0, 40));
    EXPECT_EQ(children[1].max_area, 4.0f);

    // Without the areas (max_area 0) the same node gets the plane.
    NodeTask plain = t;
    plain.max_area = 0.0f;
    SkipCounts skip2;
    Buffers buf2(refs);
    ASSERT_TRUE(canopy::run_node(buf2.ctx(), plain, children, *bins, skip2));
    EXPECT_EQ(skip2.size_splits, 0u);
    EXPECT_EQ(children[0].size(), plane.left_count);
}

TEST(KernelSizeSplit, APlaneThatMakesTheSameSetsWins) {
    // Small cubes at x in [0, 1], large slabs at x in [15, 20]: the plane
    // between them and the cut between the size classes form the same two
    // sets; the plane is kept (the cut must be cheaper beyond rounding).
    std::vector<PrimRef> refs;
    for (uint32_t i = 0; i < 20; ++i) refs.push_back(prepared(Vec3(0.05f * i, 1, 1), Vec3(0.05f * i + 0.01f, 1.01f, 1.01f), i));
    for (uint32_t i = 0; i < 4; ++i) refs.push_back(prepared(Vec3(15 + i, 0, 0), Vec3(20, 10, 10), 20 + i));
    NodeTask t = task_of(refs, 0, 24);
    t.max_area = max_area(refs, 0, 24);
    const canopy::SizeCuts cuts = canopy::SizeCuts::of(t.bounds);
    ASSERT_TRUE(cuts.applies(t));
    const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(24, 32));
    const auto b = binned(refs, 0, 24, m);
    Split s = canopy::evaluate(*b, m, t.bounds, BuildOptions{});
    ASSERT_EQ(s.axis, 0);
    ASSERT_EQ(s.left_count, 20u);
    // The same two sets: the costs agree up to rounding.
    Box small, large;
    for (const PrimRef& r : refs) (r.id >= 20 ? large : small).extend(Box{r.lo, r.hi});
    const double cut_cost = 1.0 + (small.half_area() * 20 + large.half_area() * 4) / t.bounds.half_area();
    EXPECT_NEAR(s.cost, cut_cost, 1e-6 * cut_cost);
    canopy::SizeBins sizes;
    canopy::bin_sizes(refs.data(), 0, 24, cuts, sizes);
    EXPECT_EQ(sizes.count[2], 20u);
    canopy::consider_size_split(sizes, cuts, t.bounds, BuildOptions{}, s);
    EXPECT_EQ(s.axis, 0);
}

TEST(KernelSizeSplit, PartitionByAreaSwapsTheMisplacedPairs) {
    const uint32_t n = 2 * kBlock + 77, begin = 5, end = n - 9;
    const std::vector<PrimRef> input = sized_refs(n, 31);
    const NodeTask t = task_of(input, begin, end);
    const BinMapper m = BinMapper::make(t.cbounds, 16);
    for (const float cut : {1.0f, 100.0f, 2000.0f}) {
        Split s;
        s.axis = Split::kSizeAxis;
        s.size_cut = cut;
        for (uint32_t i = begin; i < end; ++i) s.left_count += input[i].area < cut;
        ASSERT_GT(s.left_count, 0u);
        ASSERT_LT(s.left_count, end - begin);
        std::vector<PrimRef> refs = input;
        const PartitionResult p = canopy::partition(refs.data(), begin, end, m, s);
        const std::vector<PrimRef> expected =
            reference_partition(input, begin, end, [&](const PrimRef& r) { return r.area < cut; });
        EXPECT_EQ(p.mid, begin + s.left_count);
        ASSERT_TRUE(same_records(refs, expected));
        for (const PrimRef& r : input) ASSERT_EQ(canopy::goes_left(r, m, s), r.area < cut);
        expect_child_bounds(p, refs.data(), begin, end);
        EXPECT_EQ(p.left_max_area(), max_area(refs, begin, p.mid));
        EXPECT_EQ(p.right_max_area(), max_area(refs, p.mid, end));

        // Blocked, as the parallel node does it: the same records and bounds.
        std::vector<std::pair<uint32_t, uint32_t>> ranges;
        for (uint32_t b0 = begin; b0 < end; b0 += kBlock) ranges.push_back({b0, std::min(end, b0 + kBlock)});
        std::vector<PrimRef> out = input;
        const PartitionResult merged = blocked_partition(out, ranges, m, s, 777);
        EXPECT_EQ(merged.mid, p.mid);
        EXPECT_TRUE(same_records(out, refs));
        EXPECT_EQ(merged.left_bounds(), p.left_bounds());
        EXPECT_EQ(merged.right_cbounds(), p.right_cbounds());
        EXPECT_EQ(merged.left_max_area(), p.left_max_area());
        EXPECT_EQ(merged.right_max_area(), p.right_max_area());

        // By halves, as a team of two does it: the same again.
        std::vector<PrimRef> halves = input;
        uint32_t leftovers = 0;
        const PartitionResult h = halves_partition(halves, begin, end, m, s, false, leftovers);
        EXPECT_TRUE(same_records(halves, refs));
        expect_same_children(h, p);
    }
}

TEST(KernelSizeSplit, ChildrenCarryTheirLargestArea) {
    // Plane partitions, blocked marks and middle splits all report each
    // side's largest record area (what SizeCuts::applies reads).
    const std::vector<PrimRef> input = sized_refs(500, 41);
    const NodeTask t = task_of(input, 0, 500);
    const BinMapper m = BinMapper::make(t.cbounds, 16);
    const Split s = make_split(input, 0, 500, m, 1, 7);
    std::vector<PrimRef> refs = input;
    const PartitionResult p = canopy::partition(refs.data(), 0, 500, m, s);
    EXPECT_EQ(p.left_max_area(), max_area(refs, 0, p.mid));
    EXPECT_EQ(p.right_max_area(), max_area(refs, p.mid, 500));
    EXPECT_GT(p.left_max_area(), 0.0f);
    std::vector<PrimRef> out = input;
    const PartitionResult c = blocked_partition(out, {{0, 192}, {192, 500}}, m, s, 10);
    EXPECT_EQ(c.left_max_area(), p.left_max_area());
    EXPECT_EQ(c.right_max_area(), p.right_max_area());
    const PartitionResult mid = canopy::middle_split(input.data(), 0, 500);
    EXPECT_EQ(mid.left_max_area(), max_area(input, 0, 250));
    EXPECT_EQ(mid.right_max_area(), max_area(input, 250, 500));
    NodeTask kids[2];
    canopy::emit(t, p, kids);
    EXPECT_EQ(kids[0].max_area, p.left_max_area());
    EXPECT_EQ(kids[1].max_area, p.right_max_area());
}

// ---------------------------------------------------------------- leaf_by_bound

// The full verdict on a node that fits in a leaf: bin, evaluate, decide.
bool evaluated_leaf(const std::vector<PrimRef>& refs, const NodeTask& t, const BuildOptions& opt) {
    const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(t.size(), opt.bins));
    if (!m.any_valid()) return true;  // coincident centroids: a leaf (n <= max_leaf)
    const auto b = binned(refs, t.begin, t.end, m);
    return canopy::sah_says_leaf(canopy::evaluate(*b, m, t.bounds, opt), t.size(), opt);
}

TEST(KernelLeafByBound, HandMadeCases) {
    BuildOptions opt;  // C_t = C_i = 1, max_leaf 4
    // Two triangles of one quad: each box is the quad's box, so every split
    // costs at least 1 + 2 = 3 >= 2: a leaf without binning.
    const std::vector<PrimRef> quad = {make_ref(Vec3(0, 0, 0), Vec3(1, 1, 0), 0),
                                       make_ref(Vec3(0, 0, 0), Vec3(1, 1, 0), 1)};
    EXPECT_TRUE(canopy::leaf_by_bound(quad.data(), task_of(quad, 0, 2), opt));
    EXPECT_TRUE(evaluated_leaf(quad, task_of(quad, 0, 2), opt));

    // Two small cubes far apart: the bound (1 + tiny) is far below 2, and the
    // evaluation splits them.
    const std::vector<PrimRef> apart = {cube(Vec3(0), 0.1f, 0), cube(Vec3(10), 0.1f, 1)};
    EXPECT_FALSE(canopy::leaf_by_bound(apart.data(), task_of(apart, 0, 2), opt));
    EXPECT_FALSE(evaluated_leaf(apart, task_of(apart, 0, 2), opt));

    // A flat node (zero half area) is never decided by the bound.
    const std::vector<PrimRef> line = {make_ref(Vec3(0, 0, 0), Vec3(1, 0, 0), 0),
                                       make_ref(Vec3(0, 0, 0), Vec3(1, 0, 0), 1)};
    EXPECT_FALSE(canopy::leaf_by_bound(line.data(), task_of(line, 0, 2), opt));

    // run_node counts the skip and writes the leaf.
    Buffers buf(quad);
    auto bins = std::make_unique<BinSet>();
    SkipCounts skip;
    NodeTask children[2];
    EXPECT_FALSE(canopy::run_node(buf.ctx(), task_of(quad, 0, 2), children, *bins, skip));
    EXPECT_EQ(skip.bound_leaves, 1u);
    EXPECT_EQ(buf.perm, (std::vector<uint32_t>{0, 1}));
}

namespace {
// n overlapping boxes of random sizes in a small region, sometimes flat on
// one axis, at scales from tiny to huge: a small node for property tests.
std::vector<PrimRef> random_small_node(std::mt19937& rng, uint32_t n) {
    const float scale = std::ldexp(1.0f, int(rng() % 200) - 100);
    std::vector<PrimRef> refs = random_refs(n, rng(), 4.0f * scale, uniform(rng, 0.5f, 8.0f) * scale);
    if (rng() % 4 == 0)
        for (PrimRef& r : refs) {
            r.hi.z = r.lo.z = 0.0f;
            refresh_area(r);
        }
    return refs;
}
}  // namespace

// Property: whenever the bound says leaf, binning and evaluating say leaf
// too (so skipping them cannot change the tree), for random small nodes,
// costs and bin counts. Both verdicts must occur, or the test proves nothing.
TEST(KernelLeafByBound, NeverContradictsTheEvaluation) {
    std::mt19937 rng(2024);
    uint32_t bound_leaves = 0, evaluated_only = 0;
    for (int trial = 0; trial < 20000; ++trial) {
        BuildOptions opt;
        opt.max_leaf = 2 + rng() % 7;
        opt.bins = 2u << (rng() % 7);
        opt.traversal_cost = uniform(rng, 0.1f, 3.0f);
        opt.intersection_cost = uniform(rng, 0.1f, 3.0f);
        const uint32_t n = 2 + rng() % (opt.max_leaf - 1);
        const std::vector<PrimRef> refs = random_small_node(rng, n);
        const NodeTask t = task_of(refs, 0, n);
        const bool evaluated = evaluated_leaf(refs, t, opt);
        if (canopy::leaf_by_bound(refs.data(), t, opt)) {
            ++bound_leaves;
            EXPECT_TRUE(evaluated) << "trial " << trial;
            // Nor does it contradict the exact costing of small nodes.
            uint32_t left = 0;
            double cost = 0.0;
            if (n <= canopy::kExactMaxPrims && canopy::exact_split(refs.data(), n, t.bounds, opt, left, cost)) {
                EXPECT_GE(cost, double(opt.intersection_cost) * n) << "trial " << trial;
            }
        } else if (evaluated) {
            ++evaluated_only;
        }
    }
    EXPECT_GT(bound_leaves, 1000u);
    EXPECT_GT(evaluated_only, 100u);
}

// ------------------------------------------------------------ exact_split
namespace {
// The SAH of splitting refs[0, n) into the set `mask` and the rest, in
// double from the boxes (costs 1 whatever the options, for ranking).
double partition_sah(const std::vector<PrimRef>& refs, uint32_t mask) {
    Box side[2];
    uint32_t count[2] = {0, 0};
    for (uint32_t i = 0; i < refs.size(); ++i) {
        const int k = (mask >> i) & 1 ? 0 : 1;
        side[k].extend(refs[i].lo);
        side[k].extend(refs[i].hi);
        ++count[k];
    }
    return side[0].half_area() * count[0] + side[1].half_area() * count[1];
}
}  // namespace

TEST(KernelExactSplit, WallsAndObjectsBetweenThem) {
    // Two walls and two small cubes between them, whose centroids interleave
    // with the walls' on every axis: no plane between bins puts the walls
    // together. The bins' best split takes one wall off (1 + (102 + 3 * 202)
    // / 300 = 3.36); the exact costing pairs the walls and the cubes.
    const std::vector<PrimRef> refs = {make_ref(Vec3(0, 0, 0), Vec3(10, 10, 0.1f), 0), cube(Vec3(4, 4, 5), 0.1f, 1),
                                       make_ref(Vec3(0, 0, 9.9f), Vec3(10, 10, 10), 2), cube(Vec3(6, 6, 5), 0.1f, 3)};
    BuildOptions opt;  // C_t = C_i = 1, max_leaf 4: the leaf costs 4
    const NodeTask t = task_of(refs, 0, 4);
    const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(4, opt.bins));
    ASSERT_TRUE(m.any_valid());
    const Split by_bins = canopy::evaluate(*binned(refs, 0, 4, m), m, t.bounds, opt);
    ASSERT_TRUE(by_bins.found());
    EXPECT_NEAR(by_bins.cost, 3.36, 1e-5);

    uint32_t left = 0;
    double cost = 0.0;
    ASSERT_TRUE(canopy::exact_split(refs.data(), 4, t.bounds, opt, left, cost));
    EXPECT_EQ(left, 0b0101u);  // the walls (records 0 and 2)
    EXPECT_LT(cost, 3.04);  // 1 + (2 * 300 + 2 * 5.72) / 300 = 3.038
    EXPECT_NEAR(cost, 1.0 + partition_sah(refs, 0b0101) / t.bounds.half_area(), 1e-5);

    // run_node splits it by that mask: the walls first, then the cubes, each
    // in their order, with their bounds.
    Buffers buf(refs);
    auto bins = std::make_unique<BinSet>();
    SkipCounts skip;
    NodeTask children[2];
    ASSERT_TRUE(canopy::run_node(buf.ctx(), t, children, *bins, skip));
    EXPECT_EQ(skip.exact_nodes, 1u);
    ASSERT_EQ(buf.a.size(), 4u);
    EXPECT_EQ(buf.a[0].id, 0u);
    EXPECT_EQ(buf.a[1].id, 2u);
    EXPECT_EQ(buf.a[2].id, 1u);
    EXPECT_EQ(buf.a[3].id, 3u);
    EXPECT_EQ(children[0].end, 2u);
    EXPECT_EQ(children[1].begin, 2u);
    const PartitionResult p = canopy::partition_by_mask(std::vector<PrimRef>(refs).data(), 0, 4, left);
    EXPECT_EQ(p.mid, 2u);
    expect_child_bounds(p, buf.a.data(), 0, 4);
    EXPECT_EQ(children[0].bounds, bounds_of(buf.a.data(), 0, 2).bounds);
    EXPECT_EQ(children[1].cbounds, bounds_of(buf.a.data(), 2, 4).cbounds);
}

// Property, over random small nodes (flat ones, scales from tiny to huge,
// any costs and bin counts): the exact choice is the cheapest partition (its
// cost against a double-precision brute force over every partition), it
// finds a split whenever the bins do, and never costs more than the bins'
// split: a partition both see gets the same float cost from both, bit for
// bit. Cheaper than the bins must occur, or the test proves little.
TEST(KernelExactSplit, CheapestAndNeverWorseThanTheBins) {
    std::mt19937 rng(4242);
    uint32_t cheaper = 0, equal = 0;
    for (int trial = 0; trial < 20000; ++trial) {
        BuildOptions opt;
        opt.bins = 2u << (rng() % 7);
        opt.traversal_cost = uniform(rng, 0.1f, 3.0f);
        opt.intersection_cost = uniform(rng, 0.1f, 3.0f);
        const uint32_t n = 2 + rng() % (canopy::kExactMaxPrims - 1);
        const std::vector<PrimRef> refs = random_small_node(rng, n);
        const NodeTask t = task_of(refs, 0, n);
        uint32_t left = 0;
        double cost = 0.0;
        const bool found = canopy::exact_split(refs.data(), n, t.bounds, opt, left, cost);
        const BinMapper m = BinMapper::make(t.cbounds, canopy::bins_for(n, opt.bins));
        const Split by_bins = m.any_valid() ? canopy::evaluate(*binned(refs, 0, n, m), m, t.bounds, opt) : Split{};
        if (by_bins.found()) {
            ASSERT_TRUE(found) << trial;
        }
        if (!found) continue;
        ASSERT_TRUE(left & 1) << trial;
        ASSERT_LT(left, (1u << n) - 1) << trial;
        if (t.bounds.half_area() > 0.0) {
            double brute = std::numeric_limits<double>::infinity();
            for (uint32_t mask = 1; mask + 1 < (1u << n); mask += 2) brute = std::min(brute, partition_sah(refs, mask));
            EXPECT_LE(partition_sah(refs, left), brute * (1.0 + 1e-5)) << trial;
        }
        if (!by_bins.found()) continue;
        ASSERT_LE(cost, by_bins.cost) << trial;
        (cost < by_bins.cost ? cheaper : equal)++;
    }
    EXPECT_GT(cheaper, 200u);
    EXPECT_GT(equal, 200u);
}

TEST(KernelExactSplit, RegistersMatchMemory) {
    // Where AVX-512 is compiled in, exact_split() works in registers; it
    // must return what the memory version returns, mask and cost bit for
    // bit, on random small nodes, the corner cases of varied_refs() and
    // lines (the length measure), with random costs.
#if CANOPY_REGISTER_BINS
    std::mt19937 rng(777);
    uint32_t found = 0;
    for (uint32_t trial = 0; trial < 6000; ++trial) {
        BuildOptions opt;
        opt.traversal_cost = uniform(rng, 0.1f, 3.0f);
        opt.intersection_cost = uniform(rng, 0.1f, 3.0f);
        const uint32_t n = 2 + trial % (canopy::kExactMaxPrims - 1);
        std::vector<PrimRef> refs = trial % 3 == 0 ? random_small_node(rng, n) : varied_refs(n, 500 + trial, trial, 0);
        if (trial % 7 == 4)
            for (uint32_t i = 0; i < n; ++i) refs[i] = make_ref(Vec3(float(i % 3), 0, 0), Vec3(float(i % 3), 0, 0), i);
        const NodeTask t = task_of(refs, 0, n);
        uint32_t left_mem = 0, left_reg = 0;
        double cost_mem = 0.0, cost_reg = 0.0;
        const bool mem = canopy::exact_split_in_memory(refs.data(), n, t.bounds, opt, left_mem, cost_mem);
        const bool reg = canopy::exact_split_in_registers(refs.data(), n, t.bounds, opt, left_reg, cost_reg);
        ASSERT_EQ(mem, reg) << trial;
        if (!mem) continue;
        ASSERT_EQ(left_mem, left_reg) << trial;
        ASSERT_EQ(cost_mem, cost_reg) << trial;
        ++found;
    }
    EXPECT_GT(found, 5000u);
#else
    GTEST_SKIP() << "built without AVX-512: exact_split() is the memory version";
#endif
}

TEST(KernelEvaluate, NodesOfAtLeast2To31PrimitivesUseTheUnsignedConversion) {
    // Counts of a node of 2^31 primitives or more do not fit the signed
    // conversion the sweeps use first; evaluate() must notice (from the
    // sweep's total) and sweep again with the unsigned one. The bins of a
    // small node are given counts that sum past 2^31: the result must be the
    // unsigned sweeps', and the signed sweeps must have reported it.
    const BuildOptions opt;
    uint32_t checked = 0;
    for (uint32_t seed = 0; seed < 60; ++seed) {
        const uint32_t n = 8 + seed % 40;
        const std::vector<PrimRef> refs = random_refs(n, 9100 + seed, 10.0f, 1.0f);
        const NodeTask t = task_of(refs, 0, n);
        for (const uint32_t nb : {4u, 8u, 16u, 32u}) {
            const BinMapper m = BinMapper::make(t.cbounds, nb);
            if (!m.any_valid()) continue;
            auto bins = binned(refs, 0, n, m);
            // Scale every count so the node holds about 2^31 + 2^30 primitives.
            const uint32_t scale = uint32_t((uint64_t(3) << 30) / n);
            for (int a = 0; a < 3; ++a)
                for (uint32_t b = 0; b < nb; ++b) bins->set_count(a, b, bins->count(a, b) * scale);
            uint64_t total = 0;
            for (uint32_t b = 0; b < nb; ++b) total += bins->count(m.valid[0] ? 0 : m.valid[1] ? 1 : 2, b);
            ASSERT_GE(total, uint64_t(1) << 31);
            Split signed_sweep, u;
            EXPECT_TRUE((canopy::detail::evaluate_sweeps<0, false>(*bins, m, t.bounds, opt, signed_sweep)))
                << seed << " " << nb;
            EXPECT_FALSE(signed_sweep.found());
            EXPECT_FALSE((canopy::detail::evaluate_sweeps<0, true>(*bins, m, t.bounds, opt, u)));
            const Split e = canopy::evaluate(*bins, m, t.bounds, opt);
            ASSERT_EQ(e.axis, u.axis) << seed << " " << nb;
            EXPECT_EQ(e.index, u.index);
            EXPECT_EQ(e.left_count, u.left_count);
            EXPECT_EQ(e.cost, u.cost);
            // The best split's cost, recomputed in double from the bins.
            if (u.found() && u.axis < 3) {
                Box l, r;
                uint64_t nl = 0, nr = 0;
                for (uint32_t b = 0; b < nb; ++b) {
                    Box& side = b < u.index ? l : r;
                    side.extend(bins->box(u.axis, b));
                    (b < u.index ? nl : nr) += bins->count(u.axis, b);
                }
                EXPECT_EQ(uint64_t(u.left_count), nl);
                const double expect = 1.0 + (l.half_area() * double(nl) + r.half_area() * double(nr)) /
                                                t.bounds.half_area();
                EXPECT_NEAR(u.cost, expect, expect * 1e-5) << seed << " " << nb;
                ++checked;
            }
        }
    }
    EXPECT_GT(checked, 100u);
}

TEST(KernelSimd, CountsConvertAsFloatOfUint32) {
    // evaluate() converts bin counts four lanes at a time; it must round as
    // float(uint32_t) does, above 2^24 and above 2^31 too.
    const uint32_t values[] = {0u, 1u, 3u, 16777217u, 33554435u, 33554437u, 2147483647u, 2147483648u,
                               2147483649u, 2147483715u, 2147483776u, 3000000001u, 4294967167u, 4294967295u};
    for (const uint32_t v : values) {
        const __m128i n = _mm_set_epi32(0, 1, int32_t(v), 7);
        alignas(16) float f[4];
        _mm_store_ps(f, canopy::simd::to_float(n));
        EXPECT_EQ(f[1], float(v)) << v;
        EXPECT_EQ(f[0], 7.0f);
        EXPECT_EQ(f[2], 1.0f);
    }
}
