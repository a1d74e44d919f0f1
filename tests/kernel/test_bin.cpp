// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Step 1, binning (core/kernel/bin.h, bin_mapper.h, bins.h, simd.h): bins per
// node, the centroid-to-bin mapping, and the bins' counts and boxes.
#include "kernel_test_util.h"

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
