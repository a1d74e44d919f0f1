// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Exact splits of small nodes (core/kernel/small_node.h): every
// partition costed, in registers and in memory alike.
#include "kernel_test_util.h"

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
