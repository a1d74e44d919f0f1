// The numerical stress suite: degenerate and extreme inputs. Every case is
// built with every scheduler compiled in (2 threads, the scheduler
// thresholds turned down so that the parallel code paths run on these small
// scenes) at several bin counts and leaf sizes; every tree must pass
// validate(), be bit-identical to the sequential build, and give the
// brute-force closest hit (t bitwise, primitive id) for every ray of a
// seeded ray set. The exact sweep-SAH reference builder (core/sweep_sah.h)
// runs on the same cases. Then: a million rays from inside a closed mesh
// through its vertices and edge midpoints must all hit, and the build must
// leave the floating-point control state (MXCSR) alone.
#include "core/rng.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/sweep_sah.h"
#include "core/traversal.h"
#include "core/validate.h"
#include "schedulers/registry.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <glm/geometric.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <mutex>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <xmmintrin.h>
#define CANOPY_TEST_MXCSR 1
#endif
#if CANOPY_HAVE_TBB
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#endif
#if CANOPY_HAVE_OPENMP
#include <omp.h>
#endif

namespace {

using namespace canopy;

uint32_t bits(float f) { return std::bit_cast<uint32_t>(f); }

// Rng (core/rng.h) with the draws these tests need.
class StressRng : public Rng {
public:
    using Rng::Rng;
    uint64_t below(uint64_t n) { return next() % n; }
    glm::dvec3 unit() {
        const double z = range(-1.0, 1.0), phi = range(0.0, 6.283185307179586);
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        return {r * std::cos(phi), r * std::sin(phi), z};
    }
};

std::string num(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

Vec3 to_float(const glm::dvec3& v) { return Vec3(float(v.x), float(v.y), float(v.z)); }

// The scheduler thresholds turned down (as in the equivalence suite) so
// that threads start, big nodes run team-parallel and tasks are spawned on
// scenes of a few thousand primitives.
BuildOptions options(uint32_t bins, uint32_t leaf, uint32_t threads) {
    BuildOptions o = canopy::test_util::small_tuning(bins, threads);
    o.max_leaf = leaf;
    return o;
}

struct BinsLeaf {
    uint32_t bins, leaf;
};
// The default, and the extremes of bins and leaf size (every stress case);
// every combination of the extremes (ordinary scenes).
constexpr BinsLeaf kMatrix[] = {{16, 4}, {2, 1}, {256, 255}};
constexpr BinsLeaf kFullMatrix[] = {{16, 4}, {2, 1}, {256, 255}, {2, 255}, {256, 1}};

bool same_tree(const Bvh& a, const Bvh& b) {
    return a.nodes.size() == b.nodes.size() && a.permutation == b.permutation &&
           (a.nodes.empty() || std::memcmp(a.nodes.data(), b.nodes.data(), a.nodes.size() * sizeof(Node)) == 0);
}

// The scene's box in double over the referenced vertices.
struct DBox {
    glm::dvec3 lo{std::numeric_limits<double>::infinity()}, hi{-std::numeric_limits<double>::infinity()};
};
DBox bounds(const TriangleMesh& m) {
    DBox b;
    for (uint32_t i : m.indices) {
        const glm::dvec3 p(m.vertices[i]);
        b.lo = glm::min(b.lo, p);
        b.hi = glm::max(b.hi, p);
    }
    return b;
}

// A seeded ray set scaled to the scene: rays from outside at random points
// of the box, at vertices and at triangle centres; rays from inside in
// random directions; axis-parallel rays (on a flat scene they run in its
// plane). Directions are unit vectors.
std::vector<Ray> make_rays(const TriangleMesh& m, size_t count, uint64_t seed) {
    StressRng rng(seed);
    const DBox b = bounds(m);
    const glm::dvec3 c = 0.5 * b.lo + 0.5 * b.hi;
    double radius = 0.5 * glm::length(b.hi - b.lo);
    if (!(radius > 0.0)) radius = std::max(std::fabs(c.x) + std::fabs(c.y) + std::fabs(c.z), 1.0) * 1e-3;
    auto in_box = [&] {
        return glm::dvec3(rng.range(b.lo.x, b.hi.x), rng.range(b.lo.y, b.hi.y), rng.range(b.lo.z, b.hi.z));
    };
    auto vertex = [&](size_t t, int k) { return glm::dvec3(m.vertex(t, k)); };
    std::vector<Ray> rays;
    rays.reserve(count);
    const size_t nt = m.triangle_count();
    for (size_t i = 0; i < count; ++i) {
        glm::dvec3 org, dir;
        switch (i % 5) {
            case 0:
                org = c + 3.0 * radius * rng.unit();
                dir = in_box() - org;
                break;
            case 1: {
                const size_t t = rng.below(nt);
                org = c + 3.0 * radius * rng.unit();
                dir = vertex(t, int(rng.below(3))) - org;
                break;
            }
            case 2:
                org = in_box();
                dir = rng.unit();
                break;
            case 3: {
                const int axis = int(rng.below(3));
                const double sign = rng.below(2) ? 1.0 : -1.0;
                org = in_box();
                org[axis] = c[axis] - sign * 2.0 * radius;
                dir = glm::dvec3(0.0);
                dir[axis] = sign;
                break;
            }
            default: {
                const size_t t = rng.below(nt);
                org = c + 3.0 * radius * rng.unit();
                dir = (vertex(t, 0) + vertex(t, 1) + vertex(t, 2)) / 3.0 - org;
                break;
            }
        }
        const double len = glm::length(dir);
        dir = len > 0.0 ? dir / len : glm::dvec3(0.0, 0.0, 1.0);
        Ray r;
        r.org = to_float(org);
        r.dir = to_float(dir);
        rays.push_back(r);
    }
    return rays;
}

// Traversal of `bvh` against the brute-force hits: counts mismatches and
// reports the first few.
size_t compare_with_brute_force(const Bvh& bvh, const TriangleMesh& mesh, const std::vector<Ray>& rays,
                                const std::vector<Hit>& brute, const std::string& what) {
    const TriangleView view = mesh.view();
    size_t bad = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        const Hit h = intersect_closest(bvh, view, rays[i]);
        const bool any = intersect_any(bvh, view, rays[i]);
        if (h.prim != brute[i].prim || bits(h.t) != bits(brute[i].t) || any != brute[i].found()) {
            if (++bad <= 3)
                ADD_FAILURE() << what << ": ray " << i << " org (" << rays[i].org.x << ", " << rays[i].org.y << ", "
                              << rays[i].org.z << ") dir (" << rays[i].dir.x << ", " << rays[i].dir.y << ", "
                              << rays[i].dir.z << "): bvh prim " << h.prim << " t " << h.t << " any " << any
                              << ", brute force prim " << brute[i].prim << " t " << brute[i].t;
        }
    }
    return bad;
}

// The whole check of one stress case (see the top of the file).
struct CaseConfig {
    bool expect_hits = true;                      // the ray set must hit something
    std::span<const BinsLeaf> matrix = kMatrix;   // bins and leaf sizes to build with
    bool default_tuning = false;                  // the schedulers' default thresholds (big scenes)
};

// With CANOPY_STRESS_DIR set, every case is also written there as a binary
// PLY (exact floats), so that `canopy build DIR/CASE.ply` reproduces it.
void write_case(const std::string& name, const TriangleMesh& mesh) {
    const char* dir = std::getenv("CANOPY_STRESS_DIR");
    if (!dir || !*dir) return;
    std::string file;
    for (const char c : name) file += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
    const std::string path = std::string(dir) + "/" + file + ".ply";
    std::FILE* f = std::fopen(path.c_str(), "wb");
    ASSERT_NE(f, nullptr) << path;
    std::fprintf(f,
                 "ply\nformat binary_little_endian 1.0\nelement vertex %zu\nproperty float x\nproperty float y\n"
                 "property float z\nelement face %zu\nproperty list uchar uint vertex_indices\nend_header\n",
                 mesh.vertices.size(), mesh.triangle_count());
    for (const Vec3& v : mesh.vertices) std::fwrite(&v.x, sizeof(float), 3, f);  // x86-64: little-endian
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        const unsigned char three = 3;
        std::fwrite(&three, 1, 1, f);
        std::fwrite(&mesh.indices[3 * t], sizeof(uint32_t), 3, f);
    }
    ASSERT_EQ(std::fclose(f), 0) << path;
}

void check_case(const std::string& name, const TriangleMesh& mesh, size_t ray_count, CaseConfig cc = {}) {
    write_case(name, mesh);
    const bool expect_hits = cc.expect_hits;
    const std::span<const BinsLeaf> matrix = cc.matrix;
    auto options = [&](uint32_t bins, uint32_t leaf, uint32_t threads) {
        BuildOptions o = ::options(bins, leaf, threads);
        if (cc.default_tuning) o.tuning = SchedulerTuning{};
        return o;
    };
    SCOPED_TRACE(name);
    const TriangleView view = mesh.view();
    const std::vector<Ray> rays = make_rays(mesh, ray_count, 0xC0FFEE);
    std::vector<Hit> brute(rays.size());
    size_t hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        brute[i] = brute_force_closest(view, rays[i]);
        hits += brute[i].found();
    }
    if (expect_hits) {
        EXPECT_GT(hits, 0u) << "the ray set should hit something";
    }

    for (const BinsLeaf& bl : matrix) {
        const std::string cfg = name + " bins " + std::to_string(bl.bins) + " leaf " + std::to_string(bl.leaf);
        const BuildOptions seq_opt = options(bl.bins, bl.leaf, 1);
        Bvh ref;
        ASSERT_NO_THROW(ref = build<Sequential>(view, seq_opt)) << cfg;
        const ValidationReport rep = validate(ref, view, seq_opt);
        ASSERT_TRUE(rep.ok()) << cfg << ": " << rep.summary();
        for (const SchedulerEntry& s : schedulers()) {
            const BuildOptions opt = options(bl.bins, bl.leaf, 2);
            Bvh got;
            ASSERT_NO_THROW(got = s.build_triangles(view, opt)) << cfg << " " << s.name;
            const ValidationReport r = validate(got, view, opt);
            EXPECT_TRUE(r.ok()) << cfg << " " << s.name << ": " << r.summary();
            EXPECT_TRUE(same_tree(ref, got)) << cfg << " " << s.name << ": differs from the sequential build";
        }
        EXPECT_EQ(compare_with_brute_force(ref, mesh, rays, brute, cfg), 0u) << cfg;
        if (::testing::Test::HasFatalFailure()) return;
    }

    // The exact reference builder on the same input.
    for (const uint32_t leaf : {1u, 4u}) {
        BuildOptions opt;
        opt.max_leaf = leaf;
        const std::string cfg = name + " sweep leaf " + std::to_string(leaf);
        Bvh sweep;
        ASSERT_NO_THROW(sweep = build_sweep_sah(view, opt)) << cfg;
        const ValidationReport rep = validate(sweep, view, opt);
        ASSERT_TRUE(rep.ok()) << cfg << ": " << rep.summary();
        EXPECT_EQ(compare_with_brute_force(sweep, mesh, rays, brute, cfg), 0u) << cfg;
    }
}

// ---------------------------------------------------------------------------
// Mesh makers.

TriangleMesh from_triangles(const std::vector<std::array<glm::dvec3, 3>>& tris) {
    TriangleMesh m;
    for (const auto& t : tris) {
        for (const auto& p : t) {
            m.indices.push_back(static_cast<uint32_t>(m.vertices.size()));
            m.vertices.push_back(to_float(p));
        }
    }
    return m;
}

TriangleMesh append(TriangleMesh a, const TriangleMesh& b) {
    const uint32_t base = static_cast<uint32_t>(a.vertices.size());
    a.vertices.insert(a.vertices.end(), b.vertices.begin(), b.vertices.end());
    for (uint32_t i : b.indices) a.indices.push_back(base + i);
    return a;
}

// Every vertex mapped as s * v + offset, in double, rounded once.
TriangleMesh transformed(TriangleMesh m, double scale, glm::dvec3 offset) {
    for (Vec3& v : m.vertices) v = to_float(glm::dvec3(v) * scale + offset);
    return m;
}

// Random triangles of size `size` with centres in [lo, hi]^3.
std::vector<std::array<glm::dvec3, 3>> random_triangles(StressRng& rng, size_t n, double lo, double hi, double size) {
    std::vector<std::array<glm::dvec3, 3>> out;
    for (size_t i = 0; i < n; ++i) {
        const glm::dvec3 c(rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi));
        out.push_back({c + size * rng.unit(), c + size * rng.unit(), c + size * rng.unit()});
    }
    return out;
}

// ---------------------------------------------------------------------------
// The cases.

TEST(Stress, HundredThousandIdenticalTriangles) {
    const TriangleMesh m = generate("coincident", 100000);
    ASSERT_EQ(m.triangle_count(), 100000u);
    // The default thresholds: with the turned-down ones every node of 512 or
    // more primitives (hundreds of middle splits here) would run team-parallel.
    check_case("identical", m, 150, {.default_tuning = true});
}

TEST(Stress, CentroidsOnOneLine) {
    StressRng rng(11);
    // Along x: boxes symmetric about the x axis, of various lengths, so
    // every box centre has y = z = 0; overlapping in x.
    std::vector<std::array<glm::dvec3, 3>> tris;
    for (int i = 0; i < 6000; ++i) {
        const double x = rng.range(-10.0, 10.0), len = rng.range(0.01, 3.0);
        const double h = rng.range(0.01, 1.0), d = rng.range(0.0, 1.0);
        tris.push_back({glm::dvec3(x, -h, -d), glm::dvec3(x + len, h, d), glm::dvec3(x + 0.5 * len, rng.range(-h, h), 0.0)});
    }
    check_case("centroids on the x axis", from_triangles(tris), 2000);
    // Along the diagonal, exactly: dyadic centres (t, t, t) and offsets, so
    // every corner and every box centre is exact in float; the third corner
    // stays inside the box of the first two.
    tris.clear();
    for (int i = 0; i < 6000; ++i) {
        const double t = double(i % 1500) / 64.0;
        const glm::dvec3 c(t, t, t);
        const glm::dvec3 e(double(1 + rng.below(64)) / 1024.0, double(1 + rng.below(64)) / 1024.0,
                           double(1 + rng.below(64)) / 1024.0);
        tris.push_back({c - e, c + e, c + glm::dvec3(0.5 * e.x, -0.75 * e.y, -0.25 * e.z)});
    }
    check_case("centroids on the diagonal", from_triangles(tris), 2000);
}

TEST(Stress, PlanarScene) {
    // A grid in z = 0 and random triangles in the same plane, overlapping it.
    TriangleMesh m = generate("plane", 10000);
    StressRng rng(12);
    std::vector<std::array<glm::dvec3, 3>> tris;
    for (int i = 0; i < 4000; ++i) {
        const glm::dvec3 c(rng.range(-1.5, 1.5), rng.range(-1.5, 1.5), 0.0);
        const double r = rng.range(0.001, 0.2);
        tris.push_back({c + r * glm::dvec3(rng.range(-1, 1), rng.range(-1, 1), 0),
                        c + r * glm::dvec3(rng.range(-1, 1), rng.range(-1, 1), 0),
                        c + r * glm::dvec3(rng.range(-1, 1), rng.range(-1, 1), 0)});
    }
    check_case("planar (z = 0)", append(m, from_triangles(tris)), 2000);
}

TEST(Stress, ZeroAreaTriangles) {
    StressRng rng(13);
    std::vector<std::array<glm::dvec3, 3>> tris;
    for (int i = 0; i < 4000; ++i) {  // points
        const glm::dvec3 p(rng.range(-1, 1), rng.range(-1, 1), rng.range(-1, 1));
        tris.push_back({p, p, p});
    }
    for (int i = 0; i < 4000; ++i) {  // segments: two equal corners, or a corner on the segment
        const glm::dvec3 a(rng.range(-1, 1), rng.range(-1, 1), rng.range(-1, 1));
        const glm::dvec3 b = a + 0.1 * rng.unit();
        if (i % 2)
            tris.push_back({a, b, a});
        else
            tris.push_back({a, a + 0.5 * (b - a), b});
    }
    // Mixed with ordinary triangles, so that rays hit something.
    const auto normal = random_triangles(rng, 3000, -1.0, 1.0, 0.05);
    tris.insert(tris.end(), normal.begin(), normal.end());
    check_case("points, segments and triangles", from_triangles(tris), 2000);
}

TEST(Stress, DuplicatedMesh) {
    const TriangleMesh sphere = generate("sphere", 8000);
    TriangleMesh m = append(append(sphere, sphere), sphere);  // equal triangles: ties go to the lowest id
    ASSERT_EQ(m.triangle_count(), 3 * sphere.triangle_count());
    check_case("sphere x3", m, 2000);
}

TEST(Stress, TranslatedFarFromTheOrigin) {
    const TriangleMesh sphere = generate("sphere", 3000);
    StressRng rng(14);
    const TriangleMesh box = from_triangles(random_triangles(rng, 3000, -1.0, 1.0, 0.05));
    for (const double offset : {1e6, 1e12, 1e18}) {
        const glm::dvec3 off(offset, -0.5 * offset, 0.25 * offset);
        // Unit-size meshes (at 1e12 and 1e18 every vertex rounds to the same
        // float, at 1e6 to a grid of 1/16) inside a sphere big enough to keep
        // its shape in float (radius 1e-4 of the offset).
        const TriangleMesh m = append(append(transformed(sphere, 1.0, off), transformed(box, 1.0, off)),
                                      transformed(sphere, offset * 1e-4, off));
        check_case("translated by " + num(offset), m, 2000);
    }
}

TEST(Stress, ScaledTinyAndHuge) {
    const TriangleMesh sphere = generate("sphere", 5000);
    StressRng rng(15);
    const TriangleMesh random = from_triangles(random_triangles(rng, 5000, -1.0, 1.0, 0.05));
    for (const double s : {1e-30, 1e30}) {
        const std::string by = " scaled by " + num(s);
        check_case("sphere and random" + by, transformed(append(sphere, random), s, glm::dvec3(0.0)), 2000);
    }
    // Close to the largest floats (the rays start 3 radii from the centre;
    // at radius 1e38 the triangle test's vertex - origin would overflow).
    check_case("sphere of radius 1e37", transformed(sphere, 1e37, glm::dvec3(0.0)), 2000);
}

TEST(Stress, MixedScales) {
    StressRng rng(16);
    auto tris = random_triangles(rng, 5000, -1.0, 1.0, 1e-6);   // tiny, in the unit cube
    const auto big = random_triangles(rng, 5000, -1e7, 1e7, 1e6);  // huge, around it
    tris.insert(tris.end(), big.begin(), big.end());
    check_case("1e-6 beside 1e6", from_triangles(tris), 2000);
}

TEST(Stress, Slivers) {
    StressRng rng(17);
    std::vector<std::array<glm::dvec3, 3>> tris;
    for (int i = 0; i < 8000; ++i) {
        const glm::dvec3 p(rng.range(-10, 10), rng.range(-10, 10), rng.range(-10, 10));
        glm::dvec3 u;
        if (i % 3 == 0) {
            u = glm::dvec3(0.0);
            u[i % 9 / 3] = 1.0;  // axis-aligned: a flat box
        } else {
            u = rng.unit();
        }
        glm::dvec3 v = glm::normalize(glm::cross(u, rng.unit()));
        const double len = std::pow(10.0, rng.range(0.0, 3.0));
        const double width = len * std::pow(10.0, rng.range(-9.0, -5.0));
        tris.push_back({p, p + len * u, p + 0.5 * len * u + width * v});
    }
    check_case("slivers", from_triangles(tris), 2000);
}

// FAILS: traversal misses hits (and returns farther ones, or the higher id
// of a tie) on scenes whose slab distances are subnormal: in box_hit
// (core/traversal.cpp) a product (min - org) * inv that is subnormal has an
// absolute rounding error of up to 2^-150, which the relative far padding
// 1 + 2 gamma(3) cannot cover (it rounds away below 2^-126), so a ray that
// grazes a leaf box gets tnear > tfar by one subnormal ulp and the box is
// culled although its triangle is hit. The trees themselves are valid and
// identical across schedulers; only the comparison with brute force fails.
TEST(Stress, DenormalCoordinates) {
    StressRng rng(18);
    // Centres within 1e-40 of the origin, sizes about 1e-41: every
    // coordinate subnormal (below 1.18e-38).
    // And a sphere of radius 1e-40 around them.
    // (Small: subnormal arithmetic is slow.)
    const TriangleMesh m = append(from_triangles(random_triangles(rng, 1500, -1e-40, 1e-40, 1e-41)),
                                  transformed(generate("sphere", 600), 1e-40, glm::dvec3(0.0)));
    for (const Vec3& v : m.vertices)
        for (int a = 0; a < 3; ++a) ASSERT_LT(std::fabs(v[a]), std::numeric_limits<float>::min());
    check_case("subnormal coordinates", m, 1000);
}

// FAILS: the smallest case of the bug above. One triangle with subnormal
// coordinates (a one-leaf tree) and a ray aimed at its vertex v0: the
// triangle test hits it (t = 0x1.31d6p-132) but box_hit computes
// tnear > tfar for the leaf box, by one subnormal ulp, and the traversal
// returns no hit. About one such ray in five aimed at vertices misses.
TEST(Stress, SubnormalTriangleHitAtAVertexIsNotCulled) {
    TriangleMesh m;
    m.vertices = {Vec3(-0x1.1702p-134f, -0x1.6acp-136f, -0x1.3664p-134f),
                  Vec3(-0x1.c54p-138f, 0x1.521ep-134f, -0x1.d028p-135f),
                  Vec3(0x1.15a2p-134f, -0x1.dd24p-135f, -0x1.0086p-134f)};
    m.indices = {0, 1, 2};
    Ray r;
    r.org = Vec3(-0x1.f0ddp-133f, -0x1.0e23p-132f, -0x1.d2ecp-135f);
    r.dir = Vec3(0x1.2b20eep-1f, 0x1.9e4824p-1f, -0x1.0193b2p-4f);
    const Hit bf = brute_force_closest(m.view(), r);
    ASSERT_TRUE(bf.found());
    for (const SchedulerEntry& s : schedulers()) {
        const Bvh bvh = s.build_triangles(m.view());
        ASSERT_TRUE(validate(bvh, m.view()).ok());
        const Hit h = intersect_closest(bvh, m.view(), r);
        EXPECT_EQ(h.prim, bf.prim) << s.name;
        EXPECT_EQ(bits(h.t), bits(bf.t)) << s.name;
        EXPECT_TRUE(intersect_any(bvh, m.view(), r)) << s.name;
    }
}

// Every combination of the bin and leaf extremes on ordinary scenes (the
// stress cases above run bins 2 with leaf 1 and bins 256 with leaf 255).
TEST(Stress, BinsAndLeafExtremesOnOrdinaryScenes) {
    check_case("sphere", generate("sphere", 6000), 2000, {.matrix = kFullMatrix});
    check_case("random", generate("random", 6000, 3), 2000, {.matrix = kFullMatrix});
    check_case("stadium", generate("stadium", 6000), 2000, {.matrix = kFullMatrix});
}

// ---------------------------------------------------------------------------
// Leaks: rays from inside a closed mesh exactly through its vertices and
// edge midpoints (computed in float, from the float vertices the triangles
// have) must all hit. The count uses BVH traversal; a sample is checked
// against brute force.

TEST(Leak, MillionRaysFromInsideAClosedSphere) {
    const TriangleMesh m = generate("sphere", 20000);
    const TriangleView view = m.view();
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    for (size_t t = 0; t < m.triangle_count(); ++t)
        for (int k = 0; k < 3; ++k) {
            const uint32_t a = m.indices[3 * t + k], b = m.indices[3 * t + (k + 1) % 3];
            edges.emplace_back(std::min(a, b), std::max(a, b));
        }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    // Closed: every edge is shared by exactly two triangles (V - E + F = 2).
    ASSERT_EQ(int64_t(m.vertices.size()) - int64_t(edges.size()) + int64_t(m.triangle_count()), 2);
    std::vector<Vec3> targets(m.vertices.begin(), m.vertices.end());
    for (const auto& [a, b] : edges) targets.push_back(0.5f * m.vertices[a] + 0.5f * m.vertices[b]);

    StressRng rng(19);
    std::vector<Vec3> origins{Vec3(0.0f)};
    while (origins.size() * targets.size() < 1000000) origins.push_back(to_float(rng.range(0.0, 0.6) * rng.unit()));

    struct Config {
        uint32_t bins, leaf;
    };
    for (const Config cfg : {Config{16, 4}, Config{2, 1}, Config{256, 255}}) {
        BuildOptions opt = options(cfg.bins, cfg.leaf, 2);
        const Bvh bvh = find_scheduler("sequential")->build_triangles(view, opt);
        ASSERT_TRUE(validate(bvh, view, opt).ok());
        const bool full = cfg.bins == 16;  // a million rays on the default tree, a tenth on the others
        uint64_t rays = 0, leaks = 0, brute_mismatch = 0;
        for (size_t oi = 0; oi < origins.size(); ++oi) {
            for (size_t ti = 0; ti < targets.size(); ++ti) {
                if (!full && (oi * targets.size() + ti) % 10) continue;
                Ray r;
                r.org = origins[oi];
                r.dir = targets[ti] - origins[oi];
                ++rays;
                const Hit h = intersect_closest(bvh, view, r);
                if (!h.found()) {
                    if (++leaks <= 5)
                        ADD_FAILURE() << "leak (bins " << cfg.bins << " leaf " << cfg.leaf << "): org ("
                                      << r.org.x << ", " << r.org.y << ", " << r.org.z << ") dir (" << r.dir.x
                                      << ", " << r.dir.y << ", " << r.dir.z << ")";
                }
                if (rays % 997 == 0) {
                    const Hit b = brute_force_closest(view, r);
                    if (b.prim != h.prim || bits(b.t) != bits(h.t) || !intersect_any(bvh, view, r)) ++brute_mismatch;
                }
            }
        }
        EXPECT_EQ(leaks, 0u) << "bins " << cfg.bins << " leaf " << cfg.leaf << ", of " << rays << " rays";
        EXPECT_EQ(brute_mismatch, 0u);
        if (full) {
            EXPECT_GE(rays, 1000000u);
        }
    }
}

// ---------------------------------------------------------------------------
// Floating-point state.

#if CANOPY_TEST_MXCSR
constexpr unsigned kFlags = 0x3F;       // the sticky exception flags (arithmetic sets them)
constexpr unsigned kFtzDaz = 0x8040;    // flush-to-zero (bit 15), denormals-are-zero (bit 6)

// MXCSR of every worker of a parallel region of `threads` threads run after
// the build, on the same thread pools: a build that switched FTZ/DAZ on in
// its workers and left it would show here.
std::vector<unsigned> worker_csrs(uint32_t threads) {
    std::vector<unsigned> out;
#if CANOPY_HAVE_OPENMP
#pragma omp parallel num_threads(threads)
    {
        const unsigned csr = _mm_getcsr();
#pragma omp critical
        out.push_back(csr);
    }
#endif
#if CANOPY_HAVE_TBB
    std::mutex mu;
    tbb::task_arena arena(static_cast<int>(threads));
    arena.execute([&] {
        tbb::parallel_for(0, 256, 1, [&](int) {
            const unsigned csr = _mm_getcsr();
            std::lock_guard<std::mutex> lock(mu);
            out.push_back(csr);
        });
    });
#endif
    (void)threads;
    return out;
}

TEST(FloatingPoint, BuildLeavesMxcsrUnchanged) {
    StressRng rng(20);
    // Denormal and ordinary triangles: workers see both.
    TriangleMesh m = append(generate("sphere", 20000),
                            from_triangles(random_triangles(rng, 6000, -1e-40, 1e-40, 1e-41)));
    const TriangleView view = m.view();
    std::vector<std::string> failures;
    std::thread caller([&] {
        _mm_setcsr(_mm_getcsr() & ~kFtzDaz);  // FTZ and DAZ explicitly off
        const unsigned before = _mm_getcsr() & ~kFlags;
        for (const SchedulerEntry& s : schedulers()) {
            for (const uint32_t threads : {1u, 2u}) {
                const BuildOptions opt = options(16, 4, threads);
                const std::string what = std::string(s.name) + " threads " + std::to_string(threads);
                const Bvh bvh = s.build_triangles(view, opt);
                const unsigned after = _mm_getcsr() & ~kFlags;
                if (after != before)
                    failures.push_back(what + ": caller's MXCSR changed from " + std::to_string(before) + " to " +
                                       std::to_string(after));
                if (!validate(bvh, view, opt).ok()) failures.push_back(what + ": invalid tree");
                for (const unsigned w : worker_csrs(threads))
                    if ((w & ~kFlags) != before)
                        failures.push_back(what + ": a worker thread's MXCSR is " + std::to_string(w) +
                                           " after the build, expected " + std::to_string(before));
            }
        }
        BuildOptions opt;
        const Bvh sweep = build_sweep_sah(view, opt);
        if ((_mm_getcsr() & ~kFlags) != before) failures.push_back("build_sweep_sah changed the caller's MXCSR");
        if (!validate(sweep, view, opt).ok()) failures.push_back("sweep: invalid tree");
    });
    caller.join();
    for (const std::string& f : failures) ADD_FAILURE() << f;
}

// With FTZ and DAZ off, subnormal coordinates must stay inside their leaf
// boxes exactly (validate() compares floats exactly), and the leaf boxes
// must be the primitives' exact bounds (not flushed to zero).
TEST(FloatingPoint, DenormalsStayInsideTheirLeafBoxes) {
    StressRng rng(21);
    const TriangleMesh m = from_triangles(random_triangles(rng, 5000, -1e-40, 1e-40, 1e-41));
    const TriangleView view = m.view();
    std::vector<std::string> failures;
    std::thread caller([&] {
        _mm_setcsr(_mm_getcsr() & ~kFtzDaz);
        for (const SchedulerEntry& s : schedulers()) {
            const BuildOptions opt = options(16, 1, 2);
            const Bvh bvh = s.build_triangles(view, opt);
            const ValidationReport rep = validate(bvh, view, opt);
            if (!rep.ok()) failures.push_back(std::string(s.name) + ": " + rep.summary());
            // One primitive per leaf: the leaf box is exactly its bounds.
            for (const Node& n : bvh.nodes) {
                if (!n.is_leaf()) continue;
                Box b;
                for (int k = 0; k < 3; ++k) b.extend(m.vertex(bvh.permutation[n.index], k));
                for (int a = 0; a < 3; ++a)
                    if (canonical_zero(b.lo[a]) != n.min[a] || canonical_zero(b.hi[a]) != n.max[a]) {
                        failures.push_back(std::string(s.name) + ": a leaf box is not its primitive's bounds");
                        return;
                    }
            }
        }
    });
    caller.join();
    for (const std::string& f : failures) ADD_FAILURE() << f;
}
#endif

// ---------------------------------------------------------------------------
// The exact sweep-SAH reference builder against a naive one: the same
// greedy rules, written the slow, obvious way (every node re-sorts its
// primitives per axis and unions every candidate's boxes from scratch).

struct Naive {
    const BuildOptions& opt;
    std::vector<Box> box;
    std::vector<Vec3> cent;
    Bvh bvh;

    Box bounds_of(const std::vector<uint32_t>& ids, size_t b, size_t e) const {
        Box r;
        for (size_t i = b; i < e; ++i) r.extend(box[ids[i]]);
        return r;
    }
    static double measure(const Box& b, bool use_length) {
        if (b.is_empty()) return 0.0;
        return use_length ? b.extent(0) + b.extent(1) + b.extent(2) : b.half_area();
    }
    std::vector<uint32_t> sorted(std::vector<uint32_t> ids, int a) const {
        std::sort(ids.begin(), ids.end(), [&](uint32_t x, uint32_t y) {
            return cent[x][a] < cent[y][a] || (cent[x][a] == cent[y][a] && x < y);
        });
        return ids;
    }
    static uint32_t ceil_log2(uint32_t n) { return n <= 1 ? 0 : 32 - std::countl_zero(n - 1); }

    // ids sorted by (centroid x, id); fills node `node`, whose primitives go
    // to permutation[begin...].
    void node(std::vector<uint32_t> ids, uint32_t node_index, uint32_t begin, uint32_t depth) {
        const uint32_t n = static_cast<uint32_t>(ids.size());
        const Box b = bounds_of(ids, 0, n);
        bvh.nodes[node_index].set_box(b);
        bool leaf = false, splittable = false;
        std::vector<uint32_t> left, right;
        for (int a = 0; a < 3; ++a) {
            const auto s = sorted(ids, a);
            splittable |= cent[s.front()][a] < cent[s.back()][a];
        }
        int best_axis = -1;
        uint32_t best_k = 0;
        double best_sum = 0.0;
        const uint32_t budget = opt.max_depth > depth ? opt.max_depth - depth : 0;
        if (n <= 1) {
            leaf = true;
        } else if (budget <= ceil_log2(n) || !splittable) {
            leaf = n <= opt.max_leaf;
        } else {
            const bool use_length = !(b.half_area() > 0.0);
            const double parent = measure(b, use_length);
            for (int a = 0; a < 3 && parent > 0.0; ++a) {
                const auto s = sorted(ids, a);
                for (uint32_t k = 1; k < n; ++k) {
                    if (!(cent[s[k - 1]][a] < cent[s[k]][a])) continue;
                    const double sum = measure(bounds_of(s, 0, k), use_length) * double(k) +
                                       measure(bounds_of(s, k, n), use_length) * double(n - k);
                    if (best_axis < 0 || sum < best_sum) {
                        best_axis = a;
                        best_k = k;
                        best_sum = sum;
                    }
                }
            }
            const double cost = double(opt.traversal_cost) + double(opt.intersection_cost) * best_sum / parent;
            leaf = n <= opt.max_leaf && (best_axis < 0 || cost >= double(opt.intersection_cost) * double(n));
        }
        if (leaf) {
            bvh.nodes[node_index].index = begin;
            bvh.nodes[node_index].count = n;
            std::copy(ids.begin(), ids.end(), bvh.permutation.begin() + begin);
            return;
        }
        if (best_axis < 0) {  // middle split of the x order
            left.assign(ids.begin(), ids.begin() + n / 2);
            right.assign(ids.begin() + n / 2, ids.end());
        } else {
            const auto s = sorted(ids, best_axis);
            left.assign(s.begin(), s.begin() + best_k);
            right.assign(s.begin() + best_k, s.end());
        }
        const uint32_t first = static_cast<uint32_t>(bvh.nodes.size());
        bvh.nodes[node_index].index = first;
        bvh.nodes[node_index].count = 0;
        bvh.nodes.emplace_back();
        bvh.nodes.emplace_back();
        const uint32_t nl = static_cast<uint32_t>(left.size());
        node(sorted(std::move(left), 0), first, begin, depth + 1);
        node(sorted(std::move(right), 0), first + 1, begin + nl, depth + 1);
    }
};

Bvh naive_sweep(const TriangleMesh& m, const BuildOptions& opt) {
    Naive nv{opt, {}, {}, {}};
    const size_t n = m.triangle_count();
    for (size_t t = 0; t < n; ++t) {
        PrimRef r{};
        Box b;
        for (int k = 0; k < 3; ++k) b.extend(m.vertex(t, k));
        for (int a = 0; a < 3; ++a) {
            r.lo[a] = canonical_zero(b.lo[a]);
            r.hi[a] = canonical_zero(b.hi[a]);
        }
        nv.box.push_back(Box{r.lo, r.hi});
        nv.cent.push_back(centroid(r));
    }
    std::vector<uint32_t> ids(n);
    std::iota(ids.begin(), ids.end(), 0u);
    nv.bvh.permutation.resize(n);
    nv.bvh.nodes.emplace_back();
    nv.node(nv.sorted(ids, 0), 0, 0, 0);
    return std::move(nv.bvh);
}

TEST(SweepSah, MatchesANaiveGreedyBuilder) {
    StressRng rng(22);
    std::vector<std::pair<std::string, TriangleMesh>> scenes;
    scenes.emplace_back("random", generate("random", 400, 9));
    scenes.emplace_back("sphere", generate("sphere", 300));
    scenes.emplace_back("plane", generate("plane", 200));
    scenes.emplace_back("coincident", generate("coincident", 40));
    scenes.emplace_back("stadium", generate("stadium", 500));
    {
        auto tris = random_triangles(rng, 150, -1.0, 1.0, 1e-3);
        const auto big = random_triangles(rng, 150, -100.0, 100.0, 20.0);
        tris.insert(tris.end(), big.begin(), big.end());
        scenes.emplace_back("mixed", from_triangles(tris));
    }
    for (const auto& [name, mesh] : scenes) {
        for (const uint32_t leaf : {1u, 4u, 16u}) {
            for (const uint32_t depth : {64u, 9u}) {
                BuildOptions opt;
                opt.max_leaf = leaf;
                opt.max_depth = depth;
                const uint64_t leaves = (mesh.triangle_count() + leaf - 1) / leaf;
                if (Naive::ceil_log2(uint32_t(leaves)) > depth) continue;
                const std::string what = name + " leaf " + std::to_string(leaf) + " depth " + std::to_string(depth);
                const Bvh fast = build_sweep_sah(mesh.view(), opt);
                const ValidationReport rep = validate(fast, mesh.view(), opt);
                EXPECT_TRUE(rep.ok()) << what << ": " << rep.summary();
                EXPECT_TRUE(same_tree(fast, naive_sweep(mesh, opt))) << what;
            }
        }
    }
}

// The exact tree is the best split at every node, so at the root (when it
// splits) no binned build finds a cheaper first split: the root's two
// children's SAH contribution is no larger than any binned build's.
uint32_t subtree_prims(const Bvh& b, uint32_t node) {
    const Node& n = b.nodes[node];
    return n.is_leaf() ? n.count : subtree_prims(b, n.index) + subtree_prims(b, n.index + 1);
}

// A_L n_L + A_R n_R of the root split (half areas, in double).
double root_cost(const Bvh& b) {
    const uint32_t c = b.nodes[0].index;
    return b.nodes[c].box().half_area() * subtree_prims(b, c) +
           b.nodes[c + 1].box().half_area() * subtree_prims(b, c + 1);
}

TEST(SweepSah, RootSplitIsNoWorseThanBinned) {
    for (const char* spec : {"gen:random:5000:4", "gen:stadium:5000", "gen:sphere:5000"}) {
        const Scene s = load_scene(spec);
        BuildOptions opt;
        const Bvh exact = build_sweep_sah(s.mesh.view(), opt);
        ASSERT_GE(exact.nodes.size(), 3u);
        ASSERT_FALSE(exact.nodes[0].is_leaf());
        for (const uint32_t bins : {2u, 16u, 256u}) {
            opt.bins = bins;
            const Bvh binned = build<Sequential>(s.mesh.view(), opt);
            EXPECT_LE(root_cost(exact), root_cost(binned) * (1.0 + 1e-12)) << spec << " bins " << bins;
        }
    }
}

// Large primitives around a detailed object (the Cornell box scenes): binning
// alone cannot separate them (gen:room:20000 was 16.9% above the exact tree,
// CBcoil 22%); with the size split (SizeCuts in core/kernel/size_split.h) both are at or
// below it. The shared CBcoil is checked when present.
TEST(SweepSah, RoomsStayNearTheExactTree) {
    std::vector<std::pair<std::string, TriangleMesh>> scenes;
    scenes.emplace_back("gen:room:20000", generate("room", 20000));
    const std::filesystem::path coil = std::filesystem::path(CANOPY_SCENES_DIR) / "CBcoil.obj";
    if (std::filesystem::exists(coil)) scenes.emplace_back(coil.string(), load_scene(coil.string()).mesh);
    else std::printf("[ note ] %s absent: checking the generated room only\n", coil.string().c_str());
    for (const auto& [name, mesh] : scenes) {
        BuildStats stats;
        const Bvh binned = build<Sequential>(mesh.view(), {}, &stats);
        ASSERT_TRUE(validate(binned, mesh.view()).ok()) << name;
        const double exact = sah_cost(build_sweep_sah(mesh.view()));
        EXPECT_LE(sah_cost(binned), 1.015 * exact) << name << ": exact " << exact;
        EXPECT_GT(stats.skipped.size_splits, 0u) << name;
    }
}

// A regression test: binned SAH quality once collapsed on tiny scenes.
// BinMapper::make (core/kernel/bin_mapper.h) computed the bin scale bins / extent in
// float; for a centroid extent below about bins / FLT_MAX (4.7e-38 at 16
// bins) it overflowed, the axis was skipped, and a node with no valid axis
// was counted as coincident and split in the middle: valid trees, but at
// scale 1e-37 a SAH of 463 against 97.5 (exact), at 1e-38 8890. The mapping
// now prescales tiny extents by a power of two. The SAH must not depend on
// the scale while every coordinate is a normal float or a subnormal with a
// few bits.
TEST(SweepSah, BinnedQualityDoesNotDependOnTheScale) {
    const TriangleMesh unit = generate("random", 20000, 3);
    const double unit_sah = sah_cost(build<Sequential>(unit.view()));
    for (const double s : {1e-30, 1e-36, 1e-37, 1e-38}) {
        const TriangleMesh m = transformed(unit, s, glm::dvec3(0.0));
        BuildStats stats;
        const Bvh binned = build<Sequential>(m.view(), {}, &stats);
        ASSERT_TRUE(validate(binned, m.view()).ok());
        const double exact = sah_cost(build_sweep_sah(m.view()));
        EXPECT_LT(sah_cost(binned), 1.05 * exact) << "scale " << s << ": binned SAH " << sah_cost(binned)
                                                  << " (at scale 1: " << unit_sah << "), exact " << exact
                                                  << ", coincident nodes " << stats.skipped.coincident_nodes;
    }
}

TEST(SweepSah, EmptyInputAndErrors) {
    const TriangleMesh empty;
    EXPECT_TRUE(build_sweep_sah(empty.view()).empty());
    BuildOptions bad;
    bad.max_leaf = 0;
    EXPECT_THROW(build_sweep_sah(generate("sphere", 100).view(), bad), OptionError);
    TriangleMesh m = generate("sphere", 100);
    m.vertices[5].y = std::numeric_limits<float>::quiet_NaN();
    EXPECT_THROW(build_sweep_sah(m.view()), InputError);
    std::vector<Box> boxes(10, Box{Vec3(0.0f), Vec3(1.0f)});
    EXPECT_EQ(build_sweep_sah(std::span<const Box>(boxes)).permutation.size(), 10u);
}

}  // namespace
