// Tests of the node-task kernel, one step at a time, on hand-made primitive
// records. Step 3, partitioning (core/kernel/partition.h, team_partition.h,
// middle_split.h): the in-place partitions, their child bounds, and the
// blocked and two-ended versions a team runs, bit for bit against the simple one.
#include "partition_util.h"

// ---------------------------------------------------------------- partition

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
