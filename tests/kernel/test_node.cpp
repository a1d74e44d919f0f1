// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Step 4 and the node task around the steps (core/kernel/emit.h,
// core/kernel.h): emitting children, plan(), run_node(), and the leaf tests.
#include "kernel_test_util.h"

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
