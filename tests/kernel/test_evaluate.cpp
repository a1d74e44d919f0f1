// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Step 2, evaluating the partitions (core/kernel/evaluate.h,
// register_bins.h): the SAH sweeps over the bins and their tie rules.
#include "kernel_test_util.h"

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
