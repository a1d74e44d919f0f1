// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Size splits (core/kernel/size_split.h): big and small primitives
// separated when a plane cannot.
#include "partition_util.h"

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
