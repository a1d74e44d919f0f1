// Tests of core/geometry.h (Box, canonical_zero), the centroid of a PrimRef,
// the tree hash and the binary file format of core/bvh.h.
#include "core/bvh.h"
#include "core/error.h"
#include "core/geometry.h"
#include "core/primitives.h"

#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

using canopy::Box;
using canopy::Bvh;
using canopy::Node;
using canopy::PrimRef;
using canopy::Vec3;

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

PrimRef make_ref(Vec3 lo, Vec3 hi, uint32_t id = 0) {
    PrimRef r;
    std::memset(static_cast<void*>(&r), 0, sizeof r);
    r.lo = lo;
    r.hi = hi;
    r.id = id;
    return r;
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

Node leaf_node(Box b, uint32_t index, uint32_t count) {
    Node n{};
    n.set_box(b);
    n.index = index;
    n.count = count;
    return n;
}

// A small but non-trivial tree (not validated here: only bytes matter).
Bvh sample_bvh() {
    Bvh b;
    Node root{};
    root.set_box(Box{Vec3(0, 0, 0), Vec3(2, 1, 1)});
    root.index = 1;
    root.count = 0;
    b.nodes = {root, leaf_node(Box{Vec3(0, 0, 0), Vec3(1, 1, 1)}, 0, 2),
               leaf_node(Box{Vec3(1, 0, 0), Vec3(2, 1, 1)}, 2, 1)};
    b.permutation = {2, 0, 1};
    return b;
}

// Independent FNV-1a 64 over the same bytes (node array, then permutation).
uint64_t reference_hash(const Bvh& b) {
    uint64_t h = 0xcbf29ce484222325ull;
    auto feed = [&](const void* p, size_t n) {
        const auto* c = static_cast<const unsigned char*>(p);
        for (size_t i = 0; i < n; ++i) {
            h ^= c[i];
            h *= 0x100000001b3ull;
        }
    };
    feed(b.nodes.data(), b.nodes.size() * sizeof(Node));
    feed(b.permutation.data(), b.permutation.size() * sizeof(uint32_t));
    return h;
}

bool is_lower_hex16(const std::string& s) {
    if (s.size() != 16) return false;
    for (char c : s)
        if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
    return true;
}

}  // namespace

// ---------------------------------------------------------------- Box

TEST(GeometryBox, DefaultIsEmptyWithInfiniteCorners) {
    const Box b;
    EXPECT_TRUE(b.is_empty());
    EXPECT_TRUE(Box::empty().is_empty());
    EXPECT_EQ(b, Box::empty());
    for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(b.lo[a], kInf);
        EXPECT_EQ(b.hi[a], -kInf);
    }
    EXPECT_EQ(b.half_area(), 0.0);
}

TEST(GeometryBox, ExtendByPointsAndBoxes) {
    Box b;
    b.extend(Vec3(1, 2, 3));
    EXPECT_FALSE(b.is_empty());
    EXPECT_EQ(b.lo, Vec3(1, 2, 3));
    EXPECT_EQ(b.hi, Vec3(1, 2, 3));
    EXPECT_EQ(b.half_area(), 0.0);  // a point

    b.extend(Vec3(-1, 5, 0));
    EXPECT_EQ(b.lo, Vec3(-1, 2, 0));
    EXPECT_EQ(b.hi, Vec3(1, 5, 3));

    // Extending by the empty box changes nothing; extending the empty box
    // by a box gives that box.
    Box c = b;
    c.extend(Box::empty());
    EXPECT_EQ(c, b);
    Box e;
    e.extend(b);
    EXPECT_EQ(e, b);

    // Merging in either order gives the same bits.
    const Box p{Vec3(0, -4, 2), Vec3(0.5f, 7, 2.5f)};
    Box m1 = b, m2 = p;
    m1.extend(p);
    m2.extend(b);
    EXPECT_EQ(m1, m2);
    EXPECT_EQ(m1.lo, Vec3(-1, -4, 0));
    EXPECT_EQ(m1.hi, Vec3(1, 7, 3));
}

TEST(GeometryBox, Contains) {
    const Box b{Vec3(0, 0, 0), Vec3(1, 2, 3)};
    EXPECT_TRUE(b.contains(b));
    EXPECT_TRUE(b.contains(Vec3(0, 0, 0)));
    EXPECT_TRUE(b.contains(Vec3(1, 2, 3)));
    EXPECT_TRUE(b.contains(Vec3(0.5f, 1, 1.5f)));
    EXPECT_FALSE(b.contains(Vec3(1.0001f, 1, 1)));
    EXPECT_FALSE(b.contains(Vec3(0.5f, -0.0001f, 1)));
    EXPECT_FALSE(b.contains(Vec3(0.5f, 1, 3.0001f)));
    EXPECT_TRUE(b.contains(Box{Vec3(0.25f, 0.5f, 1), Vec3(0.75f, 2, 3)}));
    // One ulp outside on a single face is outside.
    for (int a = 0; a < 3; ++a) {
        Box lo_out = b, hi_out = b;
        lo_out.lo[a] = std::nextafter(b.lo[a], -kInf);
        hi_out.hi[a] = std::nextafter(b.hi[a], kInf);
        EXPECT_FALSE(b.contains(lo_out)) << a;
        EXPECT_FALSE(b.contains(hi_out)) << a;
        EXPECT_TRUE(lo_out.contains(b)) << a;
    }
    // Every box contains the empty box; the empty box contains no point.
    EXPECT_TRUE(b.contains(Box::empty()));
    EXPECT_FALSE(Box::empty().contains(Vec3(0, 0, 0)));
    // -0 and +0 compare equal.
    const Box z{Vec3(0.0f), Vec3(1.0f)};
    EXPECT_TRUE(z.contains(Vec3(-0.0f, -0.0f, -0.0f)));
}

TEST(GeometryBox, HalfAreaHandValues) {
    EXPECT_EQ((Box{Vec3(0, 0, 0), Vec3(1, 2, 3)}.half_area()), 11.0);  // 1*2 + 2*3 + 3*1
    EXPECT_EQ((Box{Vec3(-1, -1, -1), Vec3(1, 1, 1)}.half_area()), 12.0);
    EXPECT_EQ((Box{Vec3(0, 0, 0), Vec3(4, 0, 0)}.half_area()), 0.0);    // a segment
    EXPECT_EQ((Box{Vec3(0, 0, 5), Vec3(2, 3, 5)}.half_area()), 6.0);    // a rectangle
    EXPECT_EQ((Box{Vec3(0, 0, 0), Vec3(1, 2, 3)}.extent(2)), 3.0);
}

TEST(GeometryBox, HalfAreaDoesNotOverflowAtFltMax) {
    const Box b{Vec3(-FLT_MAX), Vec3(FLT_MAX)};
    const double f = FLT_MAX;
    for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(b.extent(a), 2.0 * f);
        EXPECT_TRUE(std::isfinite(b.extent(a)));
    }
    const double ha = b.half_area();
    EXPECT_TRUE(std::isfinite(ha));
    // 3 * (2 FLT_MAX)^2 = 12 FLT_MAX^2, exact in double (50 significant bits).
    EXPECT_EQ(ha, 12.0 * f * f);
    EXPECT_NEAR(ha / 1.38951e78, 1.0, 1e-5);  // 12 * 3.4028235e38^2

    // Mixed: one axis spans the whole float range, the others are unit.
    const Box m{Vec3(-FLT_MAX, 0, 0), Vec3(FLT_MAX, 1, 1)};
    EXPECT_EQ(m.half_area(), 2.0 * f * 1 + 1 * 1 + 1 * 2.0 * f);
}

TEST(GeometryBox, HalfAreaDoesNotUnderflowForTinyBoxes) {
    const float t = 1e-30f;
    const double e = t;
    const Box b{Vec3(0.0f), Vec3(t)};
    const double ha = b.half_area();
    EXPECT_GT(ha, 0.0);
    EXPECT_EQ(ha, 3.0 * e * e);  // exact: e has 24 significant bits
    EXPECT_NEAR(ha / 3e-60, 1.0, 1e-6);
    // In float the same product would be 0: the double is what saves it.
    EXPECT_EQ(t * t, 0.0f);

    // A one-ulp box away from the origin: extents of ~6.5e-28 each.
    const float o = 1e-20f, p = std::nextafter(o, kInf);
    const Box c{Vec3(o), Vec3(p)};
    const double u = double(p) - double(o);
    EXPECT_GT(u, 0.0);
    EXPECT_EQ(c.half_area(), 3.0 * u * u);
    EXPECT_GT(c.half_area(), 0.0);

    // The smallest subnormal extent.
    const float d = std::numeric_limits<float>::denorm_min();
    const Box s{Vec3(0.0f), Vec3(d)};
    EXPECT_EQ(s.half_area(), 3.0 * double(d) * double(d));
    EXPECT_GT(s.half_area(), 0.0);
}

TEST(GeometryCanonicalZero, ReplacesNegativeZeroOnly) {
    EXPECT_TRUE(same_bits(canopy::canonical_zero(-0.0f), 0.0f));
    EXPECT_FALSE(std::signbit(canopy::canonical_zero(-0.0f)));
    EXPECT_TRUE(same_bits(canopy::canonical_zero(0.0f), 0.0f));
    for (float v : {1.0f, -1.0f, FLT_MAX, -FLT_MAX, FLT_MIN, -FLT_MIN,
                    std::numeric_limits<float>::denorm_min(), -std::numeric_limits<float>::denorm_min(),
                    kInf, -kInf})
        EXPECT_TRUE(same_bits(canopy::canonical_zero(v), v)) << v;
    EXPECT_TRUE(std::isnan(canopy::canonical_zero(std::numeric_limits<float>::quiet_NaN())));
}

// ---------------------------------------------------------------- centroid

TEST(GeometryCentroid, NeverNegativeZero) {
    const float dm = std::numeric_limits<float>::denorm_min();
    struct Case {
        float lo, hi;
    };
    // Each of these gives a zero centre (exactly or by underflow of halves).
    const Case cases[] = {{-0.0f, -0.0f}, {-0.0f, 0.0f}, {0.0f, -0.0f}, {-1.0f, 1.0f},
                          {-FLT_MAX, FLT_MAX}, {-dm, -dm}, {-dm, dm}, {-dm, -0.0f}};
    for (const Case& c : cases) {
        const Vec3 v = canopy::centroid(make_ref(Vec3(c.lo), Vec3(c.hi)));
        for (int a = 0; a < 3; ++a) {
            EXPECT_EQ(v[a], 0.0f) << c.lo << " " << c.hi;
            EXPECT_FALSE(std::signbit(v[a])) << c.lo << " " << c.hi;
        }
    }
    // Mixed axes.
    const Vec3 v = canopy::centroid(make_ref(Vec3(-0.0f, -2.0f, -dm), Vec3(-0.0f, 2.0f, -0.0f)));
    for (int a = 0; a < 3; ++a) EXPECT_TRUE(same_bits(v[a], 0.0f)) << a;
}

TEST(GeometryCentroid, FiniteAtFltMax) {
    struct Case {
        float lo, hi, expected;
    };
    const Case cases[] = {{-FLT_MAX, FLT_MAX, 0.0f},
                          {FLT_MAX, FLT_MAX, FLT_MAX},
                          {-FLT_MAX, -FLT_MAX, -FLT_MAX},
                          {0.0f, FLT_MAX, FLT_MAX * 0.5f},
                          {-FLT_MAX, 0.0f, -FLT_MAX * 0.5f}};
    for (const Case& c : cases) {
        const Vec3 v = canopy::centroid(make_ref(Vec3(c.lo), Vec3(c.hi)));
        for (int a = 0; a < 3; ++a) {
            EXPECT_TRUE(std::isfinite(v[a])) << c.lo << " " << c.hi;
            EXPECT_EQ(v[a], c.expected) << c.lo << " " << c.hi;
        }
    }
    // (lo + hi) / 2 in float would overflow here; the centroid must not.
    const float big = FLT_MAX;
    EXPECT_FALSE(std::isfinite(big + big));
}

TEST(GeometryCentroid, HandValues) {
    const Vec3 v = canopy::centroid(make_ref(Vec3(0, -2, 1), Vec3(1, 4, 1)));
    EXPECT_EQ(v, Vec3(0.5f, 1.0f, 1.0f));
}

TEST(GeometryCentroid, InsideTheBoxForNormalValues) {
    // Normal coordinates whose halves are normal too (|x| >= 2 FLT_MIN), at
    // every magnitude from 2 FLT_MIN to FLT_MAX, and adjacent floats.
    // (Just above FLT_MIN the halves are subnormal and round; there the
    // centroid can leave a point box by one subnormal ulp, which is harmless
    // since bin and partition use the same centroid.)
    std::mt19937 rng(1234);
    auto random_coord = [&]() -> float {
        const int e = int(rng() % 252) - 125;  // 2^-125 .. 2^126
        const float m = 1.0f + float(rng() >> 9) * 0x1p-23f;
        const float v = std::ldexp(m, e);
        return (rng() & 1) ? -v : v;
    };
    for (int i = 0; i < 20000; ++i) {
        Vec3 lo(0.0f), hi(0.0f);  // every lane set below (initialised for GCC's -Wmaybe-uninitialized)
        for (int a = 0; a < 3; ++a) {
            float x = random_coord(), y;
            switch (i % 3) {
                case 0: y = random_coord(); break;
                case 1: y = std::nextafter(x, kInf); break;
                default: y = x; break;
            }
            lo[a] = std::min(x, y);
            hi[a] = std::max(x, y);
        }
        const PrimRef r = make_ref(lo, hi);
        const Vec3 c = canopy::centroid(r);
        const Box b{lo, hi};
        ASSERT_TRUE(b.contains(c)) << i << " lo " << lo.x << " " << lo.y << " " << lo.z << " hi " << hi.x
                                   << " " << hi.y << " " << hi.z << " c " << c.x << " " << c.y << " "
                                   << c.z;
        for (int a = 0; a < 3; ++a) {
            ASSERT_TRUE(std::isfinite(c[a]));
            ASSERT_FALSE(c[a] == 0.0f && std::signbit(c[a]));
        }
    }
}

// ---------------------------------------------------------------- tree hash

TEST(GeometryTreeHash, EmptyBvhIsTheOffsetBasis) {
    const Bvh empty;
    EXPECT_EQ(canopy::tree_hash(empty), 0xcbf29ce484222325ull);
    EXPECT_EQ(canopy::tree_hash_hex(empty), "cbf29ce484222325");
}

TEST(GeometryTreeHash, HexFormatAndValue) {
    const Bvh b = sample_bvh();
    const std::string hex = canopy::tree_hash_hex(b);
    EXPECT_TRUE(is_lower_hex16(hex)) << hex;
    EXPECT_EQ(canopy::tree_hash(b), reference_hash(b));
    EXPECT_EQ(std::stoull(hex, nullptr, 16), canopy::tree_hash(b));

    // Leading zeros are kept: find a permutation whose hash has a zero top
    // nibble and check the width.
    Bvh c;
    bool found = false;
    for (uint32_t k = 0; k < 4096 && !found; ++k) {
        c.permutation = {k};
        if ((canopy::tree_hash(c) >> 60) == 0) found = true;
    }
    ASSERT_TRUE(found);
    const std::string h = canopy::tree_hash_hex(c);
    EXPECT_TRUE(is_lower_hex16(h)) << h;
    EXPECT_EQ(h[0], '0');

    // Any change of a byte changes the hash.
    Bvh d = b;
    d.nodes[1].max[0] = std::nextafter(d.nodes[1].max[0], kInf);
    EXPECT_NE(canopy::tree_hash(d), canopy::tree_hash(b));
    Bvh e = b;
    std::swap(e.permutation[0], e.permutation[1]);
    EXPECT_NE(canopy::tree_hash(e), canopy::tree_hash(b));
}

// ---------------------------------------------------------------- save / load

namespace {

class GeometryFile : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir_ = std::filesystem::temp_directory_path() /
               ("canopy_test_geometry_" + std::to_string(::getpid()) + "_" + info->name());
        std::filesystem::remove_all(dir_);
        std::filesystem::create_directories(dir_);
    }
    void TearDown() override {
        std::error_code ec;
        std::filesystem::remove_all(dir_, ec);
    }
    std::string path(const std::string& name) const { return (dir_ / name).string(); }

    static std::vector<char> read_all(const std::string& p) {
        std::ifstream in(p, std::ios::binary);
        return std::vector<char>(std::istreambuf_iterator<char>(in), {});
    }
    static void write_all(const std::string& p, const std::vector<char>& bytes) {
        std::ofstream out(p, std::ios::binary | std::ios::trunc);
        out.write(bytes.data(), std::streamsize(bytes.size()));
    }
    // load_bvh must throw canopy::Error naming the path and containing `what`.
    static void expect_load_error(const std::string& p, const std::string& what) {
        try {
            (void)canopy::load_bvh(p);
            ADD_FAILURE() << "load_bvh(" << p << ") did not throw";
        } catch (const canopy::Error& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find(p), std::string::npos) << msg;
            EXPECT_NE(msg.find(what), std::string::npos) << msg;
        } catch (const std::exception& e) {
            ADD_FAILURE() << "load_bvh threw a non-canopy exception: " << e.what();
        }
    }

    std::filesystem::path dir_;
};

}  // namespace

TEST_F(GeometryFile, RoundTrip) {
    const Bvh b = sample_bvh();
    const std::string p = path("tree.bvh");
    canopy::save_bvh(b, p);
    EXPECT_EQ(std::filesystem::file_size(p), 8u + 16u + 3u * 32u + 3u * 4u);
    const Bvh l = canopy::load_bvh(p);
    EXPECT_EQ(l, b);
    EXPECT_EQ(l.nodes.size(), b.nodes.size());
    EXPECT_EQ(0, std::memcmp(l.nodes.data(), b.nodes.data(), b.nodes.size() * sizeof(Node)));
    EXPECT_EQ(l.permutation, b.permutation);
    EXPECT_EQ(canopy::tree_hash(l), canopy::tree_hash(b));

    // The header as documented.
    const std::vector<char> bytes = read_all(p);
    ASSERT_GE(bytes.size(), 24u);
    EXPECT_EQ(0, std::memcmp(bytes.data(), "CANOPYBV", 8));
    uint32_t header[4];
    std::memcpy(header, bytes.data() + 8, sizeof header);
    EXPECT_EQ(header[0], 1u);
    EXPECT_EQ(header[1], 3u);
    EXPECT_EQ(header[2], 3u);
    EXPECT_EQ(header[3], 0u);
    EXPECT_EQ(0, std::memcmp(bytes.data() + 24, b.nodes.data(), 3 * sizeof(Node)));
}

TEST_F(GeometryFile, RoundTripEmptyAndLarger) {
    const std::string p = path("empty.bvh");
    canopy::save_bvh(Bvh{}, p);
    EXPECT_EQ(std::filesystem::file_size(p), 24u);
    const Bvh l = canopy::load_bvh(p);
    EXPECT_TRUE(l.empty());
    EXPECT_TRUE(l.permutation.empty());

    // Arbitrary bytes (including NaN payloads and -0) survive unchanged.
    Bvh big;
    std::mt19937 rng(7);
    big.nodes.resize(1000);
    for (Node& n : big.nodes) {
        uint32_t words[8];
        for (uint32_t& w : words) w = rng();
        std::memcpy(static_cast<void*>(&n), words, sizeof n);
    }
    big.permutation.resize(777);
    for (uint32_t& v : big.permutation) v = rng();
    const std::string q = path("big.bvh");
    canopy::save_bvh(big, q);
    const Bvh lb = canopy::load_bvh(q);
    EXPECT_EQ(lb, big);
    EXPECT_EQ(canopy::tree_hash_hex(lb), canopy::tree_hash_hex(big));
}

TEST_F(GeometryFile, SaveToUnwritablePathThrows) {
    const std::string p = path("no_such_dir/tree.bvh");
    try {
        canopy::save_bvh(sample_bvh(), p);
        ADD_FAILURE() << "save_bvh did not throw";
    } catch (const canopy::Error& e) {
        EXPECT_NE(std::string(e.what()).find(p), std::string::npos) << e.what();
    }
}

TEST_F(GeometryFile, LoadMissingFile) { expect_load_error(path("missing.bvh"), "cannot open"); }

TEST_F(GeometryFile, LoadShortFile) {
    const std::string p = path("short.bvh");
    write_all(p, {'C', 'A', 'N', 'O', 'P', 'Y', 'B', 'V', 1, 0});
    expect_load_error(p, "too short");
    const std::string z = path("zero.bvh");
    write_all(z, {});
    expect_load_error(z, "too short");
    // One byte short of a header.
    canopy::save_bvh(Bvh{}, z);
    std::vector<char> bytes = read_all(z);
    bytes.pop_back();
    write_all(z, bytes);
    expect_load_error(z, "too short");
}

TEST_F(GeometryFile, LoadBadMagic) {
    const std::string p = path("magic.bvh");
    canopy::save_bvh(sample_bvh(), p);
    std::vector<char> bytes = read_all(p);
    bytes[7] = 'X';
    write_all(p, bytes);
    expect_load_error(p, "bad magic");
}

TEST_F(GeometryFile, LoadBadVersion) {
    const std::string p = path("version.bvh");
    canopy::save_bvh(sample_bvh(), p);
    std::vector<char> bytes = read_all(p);
    const uint32_t v = 2;
    std::memcpy(bytes.data() + 8, &v, 4);
    write_all(p, bytes);
    expect_load_error(p, "version 2");
}

TEST_F(GeometryFile, LoadSizeMismatch) {
    const std::string p = path("size.bvh");
    canopy::save_bvh(sample_bvh(), p);
    const std::vector<char> good = read_all(p);

    std::vector<char> longer = good;
    longer.push_back(0);
    write_all(p, longer);
    expect_load_error(p, "does not match");

    // All but the last byte (copied, not popped: GCC 12 warned a false
    // -Warray-bounds on pop_back() of the copy).
    const std::vector<char> shorter(good.begin(), good.end() - 1);
    write_all(p, shorter);
    expect_load_error(p, "does not match");

    // The header claims more nodes than the file holds.
    std::vector<char> claims = good;
    const uint32_t nodes = 4;
    std::memcpy(claims.data() + 12, &nodes, 4);
    write_all(p, claims);
    expect_load_error(p, "does not match");

    // A header whose counts would overflow 32-bit size arithmetic.
    std::vector<char> huge = good;
    const uint32_t big = 0xFFFFFFFFu;
    std::memcpy(huge.data() + 12, &big, 4);
    std::memcpy(huge.data() + 16, &big, 4);
    write_all(p, huge);
    expect_load_error(p, "does not match");
}

TEST_F(GeometryFile, LoadReservedFieldNotZero) {
    const std::string p = path("reserved.bvh");
    canopy::save_bvh(sample_bvh(), p);
    std::vector<char> bytes = read_all(p);
    const uint32_t r = 1;
    std::memcpy(bytes.data() + 20, &r, 4);
    write_all(p, bytes);
    expect_load_error(p, "reserved");
}
