// Tests of core/traversal: the watertight triangle test, the robust BVH
// traversal against brute force, and watertightness on closed meshes.
#include "core/traversal.h"
#include "schedulers/sequential.h"

#include <glm/geometric.hpp>
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <string>
#include <utility>
#include <vector>

using canopy::Bvh;
using canopy::BuildOptions;
using canopy::Hit;
using canopy::Node;
using canopy::Ray;
using canopy::TraversalStats;
using canopy::TriangleMesh;
using canopy::Vec3;

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// ---------------------------------------------------------------------------
// Random numbers with our own float mapping (independent of the standard
// library's distributions, so the rays are the same everywhere).

struct Rng {
    std::mt19937 gen;
    explicit Rng(uint32_t seed) : gen(seed) {}
    float uniform() { return float(gen() >> 8) * 0x1p-24f; }  // [0, 1)
    float uniform(float a, float b) { return a + (b - a) * uniform(); }
    uint32_t below(uint32_t n) { return uint32_t((uint64_t(gen()) * n) >> 32); }
    bool coin() { return (gen() >> 31) != 0; }
    Vec3 in_box(const Vec3& lo, const Vec3& hi) {
        return {uniform(lo.x, hi.x), uniform(lo.y, hi.y), uniform(lo.z, hi.z)};
    }
    Vec3 direction() {
        for (;;) {
            const Vec3 d(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1));
            const float l2 = d.x * d.x + d.y * d.y + d.z * d.z;
            if (l2 > 1e-4f && l2 <= 1.0f) return d;
        }
    }
};

// ---------------------------------------------------------------------------
// Meshes.

TriangleMesh octahedron() {
    TriangleMesh m;
    m.vertices = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (uint32_t sx = 0; sx < 2; ++sx)
        for (uint32_t sy = 0; sy < 2; ++sy)
            for (uint32_t sz = 0; sz < 2; ++sz) {
                const uint32_t x = sx, y = 2 + sy, z = 4 + sz;
                // Outward winding: flip once per negative sign.
                if ((sx + sy + sz) % 2 == 0)
                    m.indices.insert(m.indices.end(), {x, y, z});
                else
                    m.indices.insert(m.indices.end(), {x, z, y});
            }
    return m;
}

TriangleMesh cube() {
    TriangleMesh m;
    for (uint32_t i = 0; i < 8; ++i)
        m.vertices.push_back({i & 1 ? 1.0f : -1.0f, i & 2 ? 1.0f : -1.0f, i & 4 ? 1.0f : -1.0f});
    const uint32_t faces[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                                  {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    for (const auto& f : faces) m.indices.insert(m.indices.end(), {f[0], f[1], f[2], f[0], f[2], f[3]});
    return m;
}

TriangleMesh icosphere(int levels) {
    const double p = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<std::array<double, 3>> v = {{-1, p, 0}, {1, p, 0}, {-1, -p, 0}, {1, -p, 0},
                                            {0, -1, p}, {0, 1, p}, {0, -1, -p}, {0, 1, -p},
                                            {p, 0, -1}, {p, 0, 1}, {-p, 0, -1}, {-p, 0, 1}};
    std::vector<uint32_t> f = {0, 11, 5, 0, 5,  1,  0, 1, 7, 0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11,
                               4, 11, 10, 2, 10, 7, 6, 7, 1, 8, 3, 9, 4, 3, 4,  2, 3, 2, 6, 3,
                               6, 8,  3, 8, 9,  4, 9, 5, 2, 4, 11, 6, 2, 10, 8, 6, 7, 9, 8, 1};
    for (auto& x : v) {
        const double l = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        for (double& c : x) c /= l;
    }
    for (int l = 0; l < levels; ++l) {
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
        auto midpoint = [&](uint32_t a, uint32_t b) {
            const auto key = std::minmax(a, b);
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            std::array<double, 3> m;
            for (int k = 0; k < 3; ++k) m[k] = v[a][k] + v[b][k];
            const double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
            for (double& c : m) c /= len;
            v.push_back(m);
            return mid[key] = uint32_t(v.size() - 1);
        };
        std::vector<uint32_t> g;
        for (size_t t = 0; t < f.size(); t += 3) {
            const uint32_t a = f[t], b = f[t + 1], c = f[t + 2];
            const uint32_t ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
            g.insert(g.end(), {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca});
        }
        f = std::move(g);
    }
    TriangleMesh m;
    for (const auto& x : v) m.vertices.push_back({float(x[0]), float(x[1]), float(x[2])});
    m.indices = f;
    return m;
}

// An n x n grid of unit squares at integer x, y; heights from `height`.
template <class H>
TriangleMesh grid(uint32_t n, H height) {
    TriangleMesh m;
    for (uint32_t j = 0; j <= n; ++j)
        for (uint32_t i = 0; i <= n; ++i) m.vertices.push_back({float(i), float(j), height(i, j)});
    for (uint32_t j = 0; j < n; ++j)
        for (uint32_t i = 0; i < n; ++i) {
            const uint32_t a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
            m.indices.insert(m.indices.end(), {a, b, c, a, c, d});
        }
    return m;
}

TriangleMesh soup(uint32_t n, uint32_t seed) {
    Rng rng(seed);
    TriangleMesh m;
    for (uint32_t t = 0; t < n; ++t) {
        const Vec3 c = rng.in_box(Vec3(-1.0f), Vec3(1.0f));
        const float s = rng.uniform(0.01f, 0.3f);
        for (int k = 0; k < 3; ++k) {
            m.vertices.push_back(c + s * Vec3(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)));
            m.indices.push_back(uint32_t(m.vertices.size() - 1));
        }
    }
    return m;
}

// Every triangle of `base` `copies` times (same vertex order, so the copies
// are hit at bitwise-equal t), at shuffled ids: exact ties everywhere.
TriangleMesh duplicated(const TriangleMesh& base, uint32_t copies, uint32_t seed) {
    Rng rng(seed);
    const size_t n = base.triangle_count();
    std::vector<uint32_t> order(n * copies);
    for (size_t i = 0; i < order.size(); ++i) order[i] = uint32_t(i % n);
    for (size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng.below(uint32_t(i))]);
    TriangleMesh m;
    m.vertices = base.vertices;
    for (uint32_t t : order)
        for (int k = 0; k < 3; ++k) m.indices.push_back(base.indices[3 * t + k]);
    return m;
}

// Closed: every directed edge has its reverse in the mesh exactly once.
bool is_closed(const TriangleMesh& m) {
    std::map<std::pair<uint32_t, uint32_t>, int> count;
    for (size_t t = 0; t < m.triangle_count(); ++t)
        for (int k = 0; k < 3; ++k) ++count[{m.indices[3 * t + k], m.indices[3 * t + (k + 1) % 3]}];
    for (const auto& [e, c] : count) {
        auto it = count.find({e.second, e.first});
        if (c != 1 || it == count.end() || it->second != 1) return false;
    }
    return true;
}

std::vector<std::pair<uint32_t, uint32_t>> edges(const TriangleMesh& m) {
    std::map<std::pair<uint32_t, uint32_t>, int> seen;
    std::vector<std::pair<uint32_t, uint32_t>> out;
    for (size_t t = 0; t < m.triangle_count(); ++t)
        for (int k = 0; k < 3; ++k) {
            const auto e = std::minmax(m.indices[3 * t + k], m.indices[3 * t + (k + 1) % 3]);
            if (seen[e]++ == 0) out.push_back(e);
        }
    return out;
}

canopy::Box bounds(const TriangleMesh& m) {
    canopy::Box b;
    for (const Vec3& v : m.vertices) b.extend(v);
    return b;
}

// Independent structural check of a built tree (the traversal relies on it):
// every primitive once, every box containing its children / primitives.
::testing::AssertionResult well_formed(const Bvh& bvh, const TriangleMesh& m) {
    if (bvh.permutation.size() != m.triangle_count())
        return ::testing::AssertionFailure() << "permutation size";
    std::vector<int> seen(m.triangle_count(), 0);
    for (uint32_t id : bvh.permutation) {
        if (id >= seen.size() || seen[id]++) return ::testing::AssertionFailure() << "bad id " << id;
    }
    for (size_t i = 0; i < bvh.nodes.size(); ++i) {
        const Node& n = bvh.nodes[i];
        const canopy::Box box = n.box();
        if (n.is_leaf()) {
            if (size_t(n.index) + n.count > bvh.permutation.size())
                return ::testing::AssertionFailure() << "leaf " << i << " out of range";
            for (uint32_t k = n.index; k < n.index + n.count; ++k)
                for (int c = 0; c < 3; ++c)
                    if (!box.contains(m.vertex(bvh.permutation[k], c)))
                        return ::testing::AssertionFailure() << "leaf " << i << " misses a vertex";
        } else {
            if (n.index <= i || size_t(n.index) + 1 >= bvh.nodes.size())
                return ::testing::AssertionFailure() << "inner " << i << " bad children";
            if (!box.contains(bvh.nodes[n.index].box()) || !box.contains(bvh.nodes[n.index + 1].box()))
                return ::testing::AssertionFailure() << "inner " << i << " does not contain a child";
        }
    }
    return ::testing::AssertionSuccess();
}

Bvh build(const TriangleMesh& m, const BuildOptions& o = {}) {
    return canopy::build<canopy::Sequential>(m.view(), o);
}

uint32_t bits(float f) { return std::bit_cast<uint32_t>(f); }

// ---------------------------------------------------------------------------
// Ray sets: random rays, rays aimed at vertices and at points of edges,
// axis-parallel rays (zero direction components, origins on the slab planes
// of vertex coordinates), rays from the surface, finite intervals.

std::vector<Ray> ray_set(const TriangleMesh& m, size_t count, uint32_t seed) {
    Rng rng(seed);
    const canopy::Box b = bounds(m);
    const Vec3 ext = b.hi - b.lo;
    const Vec3 lo = b.lo - 0.5f * ext - Vec3(0.1f), hi = b.hi + 0.5f * ext + Vec3(0.1f);
    const auto es = edges(m);
    auto vertex = [&] { return m.vertices[m.indices[rng.below(uint32_t(m.indices.size()))]]; };
    auto edge_point = [&] {
        const auto& e = es[rng.below(uint32_t(es.size()))];
        const Vec3 a = m.vertices[e.first], c = m.vertices[e.second];
        const float s = rng.coin() ? 0.5f : rng.uniform();
        return a + s * (c - a);
    };
    auto surface_point = [&] {
        const uint32_t t = rng.below(uint32_t(m.triangle_count()));
        float u = rng.uniform(), v = rng.uniform();
        if (u + v > 1) u = 1 - u, v = 1 - v;
        return m.vertex(t, 0) + u * (m.vertex(t, 1) - m.vertex(t, 0)) + v * (m.vertex(t, 2) - m.vertex(t, 0));
    };
    std::vector<Ray> rays;
    rays.reserve(count);
    for (size_t i = 0; i < count; ++i) {
        Ray r;
        switch (i % 9) {
        case 0:  // random
            r.org = rng.in_box(lo, hi);
            r.dir = rng.direction();
            break;
        case 1:  // aimed at a vertex
            r.org = rng.in_box(lo, hi);
            r.dir = vertex() - r.org;
            break;
        case 2:  // aimed at an edge midpoint or edge point
            r.org = rng.in_box(lo, hi);
            r.dir = edge_point() - r.org;
            break;
        case 3: {  // axis-parallel, origin on vertex slab planes
            const int a = int(rng.below(3));
            const Vec3 v = vertex();
            r.org = rng.in_box(lo, hi);
            for (int k = 0; k < 3; ++k)
                if (k != a && rng.below(4) != 0) r.org[k] = v[k];
            r.dir = Vec3(rng.coin() ? 0.0f : -0.0f, rng.coin() ? 0.0f : -0.0f, rng.coin() ? 0.0f : -0.0f);
            r.dir[a] = rng.coin() ? 1.0f : -1.0f;
            break;
        }
        case 4: {  // one zero component, aimed near an edge point / vertex
            const int a = int(rng.below(3));
            const Vec3 p = rng.coin() ? vertex() : edge_point();
            r.org = rng.in_box(lo, hi);
            r.org[a] = p[a];
            r.dir = p - r.org;
            r.dir[a] = rng.coin() ? 0.0f : -0.0f;
            if (r.dir == Vec3(0.0f)) r.dir[(a + 1) % 3] = 1.0f;
            break;
        }
        case 5:  // from the surface (or a vertex), tmin = 0
            r.org = rng.coin() ? surface_point() : vertex();
            r.dir = rng.direction();
            break;
        case 6: {  // finite interval on a ray aimed at the surface
            r.org = rng.in_box(lo, hi);
            r.dir = surface_point() - r.org;
            r.tmin = rng.uniform(0.0f, 0.9f);
            r.tmax = r.tmin + rng.uniform(0.0f, 0.5f);
            if (rng.below(4) == 0) r.tmax = 1.0f;  // ends near the aimed point
            break;
        }
        case 7:  // from inside the bounds, unnormalised direction
            r.org = rng.in_box(b.lo, b.hi);
            r.dir = rng.direction() * rng.uniform(0.01f, 100.0f);
            break;
        default:  // through a vertex, along a random direction, from far away
            r.dir = rng.direction();
            r.org = vertex() - 4.0f * r.dir;
            if (rng.coin()) r.tmin = -kInf;
            break;
        }
        rays.push_back(r);
    }
    return rays;
}

// Traversal and brute force agree bitwise on every ray.
void expect_matches_brute_force(const Bvh& bvh, const TriangleMesh& m, const std::vector<Ray>& rays,
                                const std::string& what) {
    size_t mismatches = 0, hits = 0;
    TraversalStats stats;
    for (size_t i = 0; i < rays.size(); ++i) {
        const Ray& r = rays[i];
        const Hit ref = brute_force_closest(m.view(), r);
        const Hit got = intersect_closest(bvh, m.view(), r, &stats);
        // Brute-force any-hit (a full scan on a miss) on every fourth ray;
        // an any-hit exists exactly when a closest hit does.
        const bool any_ref = i % 4 == 0 ? brute_force_any(m.view(), r) : ref.found();
        const bool any_got = intersect_any(bvh, m.view(), r, &stats);
        hits += ref.found();
        const bool same = got.prim == ref.prim && bits(got.t) == bits(ref.t) &&
                          bits(got.u) == bits(ref.u) && bits(got.v) == bits(ref.v) &&
                          any_ref == ref.found() && any_got == any_ref;
        if (!same && ++mismatches <= 5)
            ADD_FAILURE() << what << " ray " << i << " org (" << r.org.x << ", " << r.org.y << ", "
                          << r.org.z << ") dir (" << r.dir.x << ", " << r.dir.y << ", " << r.dir.z
                          << ") [" << r.tmin << ", " << r.tmax << "]: brute force prim " << ref.prim
                          << " t " << ref.t << " any " << any_ref << "; traversal prim " << got.prim
                          << " t " << got.t << " any " << any_got;
    }
    EXPECT_EQ(mismatches, 0u) << what;
    // The ray sets are meant to hit often, and the tree to prune.
    EXPECT_GT(hits, rays.size() / 10) << what;
    // Closest and any-hit together test far fewer triangles than brute force.
    if (m.triangle_count() >= 500) {
        EXPECT_LT(stats.triangles_tested, uint64_t(rays.size()) * m.triangle_count() / 4) << what;
    }
}

// ---------------------------------------------------------------------------
// Triangle test on hand-made cases.

const Vec3 kA(0, 0, 0), kB(1, 0, 0), kC(0, 1, 0);

Ray down(float x, float y) {
    Ray r;
    r.org = {x, y, 1.0f};
    r.dir = {0, 0, -1};
    return r;
}

bool hit(const Ray& r, const Vec3& a = kA, const Vec3& b = kB, const Vec3& c = kC) {
    float t, u, v;
    return canopy::intersect_triangle(r, a, b, c, t, u, v);
}

TEST(Triangle, HitInteriorWithBarycentrics) {
    float t = -1, u = -1, v = -1;
    ASSERT_TRUE(canopy::intersect_triangle(down(0.25f, 0.5f), kA, kB, kC, t, u, v));
    EXPECT_EQ(t, 1.0f);
    EXPECT_FLOAT_EQ(u, 0.25f);  // weight of vertex 1 (b = (1,0,0))
    EXPECT_FLOAT_EQ(v, 0.5f);   // weight of vertex 2 (c = (0,1,0))
    // Either side: no backface culling.
    Ray up = down(0.25f, 0.5f);
    up.org.z = -3.0f;
    up.dir = {0, 0, 1};
    ASSERT_TRUE(canopy::intersect_triangle(up, kA, kB, kC, t, u, v));
    EXPECT_EQ(t, 3.0f);
    // t is in units of the (unnormalised) direction.
    Ray fast = down(0.25f, 0.25f);
    fast.dir = {0, 0, -4};
    ASSERT_TRUE(canopy::intersect_triangle(fast, kA, kB, kC, t, u, v));
    EXPECT_EQ(t, 0.25f);
    // Oblique.
    Ray ob;
    ob.org = {-1.0f, 0.25f, 2.0f};
    ob.dir = {1.0f, 0.0f, -2.0f};  // reaches (0, 0.25, 0) at t = 1
    ASSERT_TRUE(canopy::intersect_triangle(ob, kA, kB, kC, t, u, v));
    EXPECT_FLOAT_EQ(t, 1.0f);
    EXPECT_NEAR(u, 0.0f, 1e-6f);
    EXPECT_FLOAT_EQ(v, 0.25f);
}

TEST(Triangle, Miss) {
    EXPECT_FALSE(hit(down(2.0f, 2.0f)));
    EXPECT_FALSE(hit(down(0.6f, 0.6f)));
    EXPECT_FALSE(hit(down(-0.01f, 0.5f)));
    EXPECT_FALSE(hit(down(0.5f, -1e-7f)));
}

TEST(Triangle, EdgesAndVerticesAreInclusive) {
    EXPECT_TRUE(hit(down(0.5f, 0.0f)));   // edge ab
    EXPECT_TRUE(hit(down(0.0f, 0.5f)));   // edge ca
    EXPECT_TRUE(hit(down(0.5f, 0.5f)));   // edge bc
    EXPECT_TRUE(hit(down(0.0f, 0.0f)));   // vertices
    EXPECT_TRUE(hit(down(1.0f, 0.0f)));
    EXPECT_TRUE(hit(down(0.0f, 1.0f)));
    float t, u, v;
    ASSERT_TRUE(canopy::intersect_triangle(down(1.0f, 0.0f), kA, kB, kC, t, u, v));
    EXPECT_EQ(u, 1.0f);
    EXPECT_EQ(v, 0.0f);
}

TEST(Triangle, ParallelAndDegenerate) {
    Ray in_plane;
    in_plane.org = {-1.0f, 0.25f, 0.0f};
    in_plane.dir = {1.0f, 0.0f, 0.0f};
    EXPECT_FALSE(hit(in_plane));
    Ray above = in_plane;
    above.org.z = 0.5f;
    EXPECT_FALSE(hit(above));
    // Degenerate triangles (collinear, or a point) are never hit.
    EXPECT_FALSE(hit(down(0.5f, 0.0f), kA, kB, Vec3(2, 0, 0)));
    EXPECT_FALSE(hit(down(0.0f, 0.0f), kA, kA, kA));
    // A zero direction hits nothing.
    Ray zero = down(0.25f, 0.25f);
    zero.dir = Vec3(0.0f);
    EXPECT_FALSE(hit(zero));
    // Neither does a NaN ray.
    Ray nan = down(0.25f, 0.25f);
    nan.org.x = std::numeric_limits<float>::quiet_NaN();
    EXPECT_FALSE(hit(nan));
}

TEST(Triangle, OriginOnTheSurface) {
    Ray r;
    r.org = {0.25f, 0.25f, 0.0f};
    r.dir = {0.3f, -0.2f, 1.0f};
    float t = -1, u, v;
    ASSERT_TRUE(canopy::intersect_triangle(r, kA, kB, kC, t, u, v));
    EXPECT_EQ(t, 0.0f);
    r.tmin = 1e-6f;  // the usual self-intersection epsilon rejects it
    EXPECT_FALSE(hit(r));
    // Origin on an edge / a vertex.
    r.tmin = 0.0f;
    r.org = {0.5f, 0.0f, 0.0f};
    EXPECT_TRUE(hit(r));
    r.org = kC;
    EXPECT_TRUE(hit(r));
}

TEST(Triangle, IntervalBoundsAreInclusive) {
    Ray r = down(0.25f, 0.25f);  // t = 1
    r.tmax = 1.0f;
    EXPECT_TRUE(hit(r));
    r.tmax = std::nextafter(1.0f, 0.0f);
    EXPECT_FALSE(hit(r));
    r.tmax = kInf;
    r.tmin = 1.0f;
    EXPECT_TRUE(hit(r));
    r.tmin = std::nextafter(1.0f, 2.0f);
    EXPECT_FALSE(hit(r));
    // Behind the origin: t = -1.
    Ray back = down(0.25f, 0.25f);
    back.dir = {0, 0, 1};
    EXPECT_FALSE(hit(back));
    back.tmin = -kInf;
    float t, u, v;
    ASSERT_TRUE(canopy::intersect_triangle(back, kA, kB, kC, t, u, v));
    EXPECT_EQ(t, -1.0f);
    back.tmin = -1.0f;
    back.tmax = -1.0f;
    EXPECT_TRUE(hit(back));
    // Empty interval.
    Ray empty = down(0.25f, 0.25f);
    empty.tmin = 2.0f;
    empty.tmax = 0.5f;
    EXPECT_FALSE(hit(empty));
    // The other winding and a negative determinant obey the same bounds.
    r = down(0.25f, 0.25f);
    r.tmax = std::nextafter(1.0f, 0.0f);
    EXPECT_FALSE(hit(r, kA, kC, kB));
    r.tmax = 1.0f;
    EXPECT_TRUE(hit(r, kA, kC, kB));
}

// The double-precision fallback: near-degenerate configurations where float
// edge functions round to 0. For a ray along +z from (0,0,0) the sheared
// coordinates are the vertices' x, y, and the exact signs of the edge
// functions are those of the differences of products computed in double.
TEST(Triangle, DoubleFallbackGivesExactSigns) {
    auto exact_hit = [](const Vec3& a, const Vec3& b, const Vec3& c) {
        auto e = [](const Vec3& p, const Vec3& q) { return double(q.x) * p.y - double(q.y) * p.x; };
        const double U = e(b, c), V = e(c, a), W = e(a, b);
        const bool mixed = (U < 0 || V < 0 || W < 0) && (U > 0 || V > 0 || W > 0);
        return !mixed && U + V + W != 0.0;
    };
    Rng rng(7);
    Ray r;
    r.org = Vec3(0.0f);
    r.dir = {0, 0, 1};
    r.tmin = -kInf;
    int float_zero_exact_nonzero = 0, checked = 0;
    for (int i = 0; i < 20000; ++i) {
        // b and c nearly on a line through the origin (the ray's trace).
        const Vec3 b(rng.uniform(0.5f, 2.0f), rng.uniform(0.5f, 2.0f), 1.0f);
        const float lambda = rng.uniform(0.5f, 2.0f);
        const Vec3 c(b.x * lambda, b.y * lambda, 1.0f);
        const Vec3 a(rng.uniform(-2.0f, 2.0f), rng.uniform(-2.0f, 2.0f), 1.0f);
        // (volatile: no fused multiply-add, this is the float evaluation)
        const volatile float p1 = c.x * b.y, p2 = c.y * b.x;
        const float Uf = p1 - p2;
        const double Ud = double(c.x) * b.y - double(c.y) * b.x;
        if (Uf == 0.0f && Ud != 0.0) ++float_zero_exact_nonzero;
        ++checked;
        ASSERT_EQ(hit(r, a, b, c), exact_hit(a, b, c)) << i;
        ASSERT_EQ(hit(r, a, c, b), exact_hit(a, c, b)) << i;
    }
    EXPECT_GT(float_zero_exact_nonzero, 100) << "the fallback was not exercised";

    // A hand-made one: with e = 2^-23, b = (1, 1+e), c = (1+e, 1+2e) and
    // a = -2^-10 c, the float edge functions are all 0 (det = 0: a float-only
    // test misses), while exactly U = e^2 > 0, V = 0, W = 2^-10 e^2 > 0: the
    // origin lies on edge ca, so the triangle is hit.
    const float e = 0x1p-23f;
    const Vec3 b(1.0f, 1.0f + e, 1.0f), c(1.0f + e, 1.0f + 2 * e, 1.0f);
    const Vec3 a(-c.x * 0x1p-10f, -c.y * 0x1p-10f, 1.0f);
    const volatile float p1 = c.x * b.y, p2 = c.y * b.x;
    ASSERT_EQ(p1 - p2, 0.0f);
    float t, u, v;
    EXPECT_TRUE(canopy::intersect_triangle(r, a, b, c, t, u, v));
    EXPECT_EQ(t, 1.0f);
}

// A shared edge: a ray through any point of it hits at least one of the two
// triangles, whatever the rounding (the point of the watertight test).
TEST(Triangle, SharedEdgeNeverLeaks) {
    Rng rng(11);
    int leaks = 0;
    for (int i = 0; i < 20000; ++i) {
        const Vec3 p = rng.in_box(Vec3(-1.0f), Vec3(1.0f)), q = rng.in_box(Vec3(-1.0f), Vec3(1.0f));
        const Vec3 l = rng.in_box(Vec3(-1.0f), Vec3(1.0f)), s = rng.in_box(Vec3(-1.0f), Vec3(1.0f));
        const Vec3 target = p + rng.uniform() * (q - p);
        Ray r;
        r.org = rng.in_box(Vec3(-3.0f), Vec3(3.0f));
        r.dir = target - r.org;
        r.tmin = -kInf;
        // Triangles (p, q, l) and (q, p, s): consistent winding across pq.
        // Only count rays that pass between l and s (so the pair covers
        // the neighbourhood of the target on the ray's trace).
        float t, u, v;
        const bool h1 = canopy::intersect_triangle(r, p, q, l, t, u, v);
        const bool h2 = canopy::intersect_triangle(r, q, p, s, t, u, v);
        // Projected onto the ray's view, l and s on opposite sides of pq?
        auto side = [&](const Vec3& x) {
            const Vec3 n = glm::cross(q - p, r.dir);
            return double(n.x) * (x.x - p.x) + double(n.y) * (x.y - p.y) + double(n.z) * (x.z - p.z);
        };
        const double sl = side(l), ss = side(s);
        if (sl * ss < 0 && std::fabs(sl) > 1e-3 && std::fabs(ss) > 1e-3 && !h1 && !h2) ++leaks;
    }
    EXPECT_EQ(leaks, 0);
}

// ---------------------------------------------------------------------------
// Watertightness on closed meshes.

// A convex polytope {x : n_f . x <= 1 for every face f}.
struct Polytope {
    TriangleMesh mesh;
    std::vector<Vec3> normals;
    // Points of its surface with dyadic coordinates: vertices, edge midpoints
    // and quarter points, face-diagonal points.
    std::vector<Vec3> special;
    // The ray from outside through p along d enters the body at p.
    bool enters(const Vec3& p, const Vec3& d) const {
        for (const Vec3& n : normals)
            if (glm::dot(n, p) == 1.0f && !(glm::dot(n, d) < 0.0f)) return false;
        return true;
    }
    bool outside(const Vec3& o) const {
        for (const Vec3& n : normals)
            if (glm::dot(n, o) > 1.0f) return true;
        return false;
    }
};

Polytope make_polytope(TriangleMesh mesh, std::vector<Vec3> normals) {
    Polytope p{std::move(mesh), std::move(normals), {}};
    for (const Vec3& v : p.mesh.vertices) p.special.push_back(v);
    for (size_t t = 0; t < p.mesh.triangle_count(); ++t)
        for (int k = 0; k < 3; ++k) {
            const Vec3 a = p.mesh.vertex(t, k), b = p.mesh.vertex(t, (k + 1) % 3);
            for (float s : {0.25f, 0.5f, 0.75f, 0.125f}) p.special.push_back(a + s * (b - a));
        }
    return p;
}

std::vector<Polytope> polytopes() {
    std::vector<Polytope> out;
    std::vector<Vec3> oct_normals;
    for (float x : {-1.0f, 1.0f})
        for (float y : {-1.0f, 1.0f})
            for (float z : {-1.0f, 1.0f}) oct_normals.push_back({x, y, z});
    out.push_back(make_polytope(octahedron(), oct_normals));
    out.push_back(make_polytope(cube(), {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}}));
    return out;
}

// Rays exactly through vertices, edge points and face-diagonal points of a
// cube and an octahedron (dyadic coordinates: the rays pass exactly through
// the points), from outside and from inside: every one must hit, at t = 1.
TEST(Watertight, ExactVerticesAndEdgesOfPolytopes) {
    for (const Polytope& poly : polytopes()) {
        ASSERT_TRUE(is_closed(poly.mesh));
        for (uint32_t leaf : {1u, 4u}) {
            BuildOptions opt;
            opt.max_leaf = leaf;
            const Bvh bvh = build(poly.mesh, opt);
            ASSERT_TRUE(well_formed(bvh, poly.mesh));
            Rng rng(3);
            int leaks = 0, rays = 0;
            auto check = [&](const Ray& r, const char* kind) {
                ++rays;
                const Hit h = intersect_closest(bvh, poly.mesh.view(), r);
                const Hit bf = brute_force_closest(poly.mesh.view(), r);
                const bool any = intersect_any(bvh, poly.mesh.view(), r);
                if (!h.found() || !bf.found() || !any) {
                    if (++leaks <= 5)
                        ADD_FAILURE() << kind << " leak: org (" << r.org.x << ", " << r.org.y << ", "
                                      << r.org.z << ") dir (" << r.dir.x << ", " << r.dir.y << ", "
                                      << r.dir.z << ")";
                    return;
                }
                EXPECT_EQ(h.prim, bf.prim);
                EXPECT_EQ(bits(h.t), bits(bf.t));
                EXPECT_NEAR(h.t, 1.0f, 1e-5f) << kind;
            };
            const Vec3 inside[] = {{0, 0, 0}, {0.25f, -0.125f, 0.0625f}, {-0.5f, 0, 0}, {0, 0, 0.25f}};
            for (const Vec3& p : poly.special) {
                // From inside: the ray leaves through p.
                for (const Vec3& o : inside) {
                    Ray r;
                    r.org = o;
                    r.dir = p - o;
                    check(r, "inside");
                }
                // From outside, entering at p: small integer offsets.
                for (int k = 0; k < 24; ++k) {
                    const Vec3 off(float(int(rng.below(9)) - 4), float(int(rng.below(9)) - 4),
                                   float(int(rng.below(9)) - 4));
                    const Vec3 o = p + off;
                    if (!poly.outside(o) || !poly.enters(p, -off)) continue;
                    Ray r;
                    r.org = o;
                    r.dir = -off;
                    check(r, "outside");
                }
                // Straight at the centre from 3p.
                Ray r;
                r.org = 3.0f * p;
                r.dir = -2.0f * p;
                check(r, "radial");
            }
            EXPECT_EQ(leaks, 0);
            EXPECT_GT(rays, 100);
        }
    }
}

// A finer closed mesh: a subdivided icosahedron (5120 triangles). Rays from
// inside (the centre, exactly through vertices, and random interior points)
// and from outside near the normal through vertices and edge points.
TEST(Watertight, FineSphereHasNoLeaks) {
    const TriangleMesh m = icosphere(4);
    ASSERT_EQ(m.triangle_count(), 5120u);
    ASSERT_TRUE(is_closed(m));
    const Bvh bvh = build(m);
    ASSERT_TRUE(well_formed(bvh, m));
    const auto es = edges(m);
    Rng rng(5);
    int leaks = 0, rays = 0;
    auto check = [&](const Ray& r) {
        ++rays;
        const Hit h = intersect_closest(bvh, m.view(), r);
        if (!h.found() || !intersect_any(bvh, m.view(), r)) {
            if (++leaks <= 5)
                ADD_FAILURE() << "leak: org (" << r.org.x << ", " << r.org.y << ", " << r.org.z
                              << ") dir (" << r.dir.x << ", " << r.dir.y << ", " << r.dir.z << ")";
        }
    };
    std::vector<Vec3> targets(m.vertices.begin(), m.vertices.end());
    for (const auto& e : es) {
        const Vec3 a = m.vertices[e.first], b = m.vertices[e.second];
        targets.push_back(0.5f * a + 0.5f * b);
        targets.push_back(a + rng.uniform() * (b - a));
    }
    for (const Vec3& p : targets) {
        Ray r;
        r.dir = p;  // from the centre, exactly through p
        check(r);
        r.org = rng.in_box(Vec3(-0.5f), Vec3(0.5f));
        r.dir = p - r.org;
        check(r);
        // From outside, near the normal, through (the float rounding of) p.
        r.org = 3.0f * p + rng.in_box(Vec3(-0.3f), Vec3(0.3f));
        r.dir = p - r.org;
        check(r);
    }
    EXPECT_EQ(leaks, 0);
    EXPECT_GT(rays, 40000);
}

// Axis-parallel rays from the centre of the octahedron through its
// vertices: zero direction components with the origin on slab planes of the
// leaf boxes (0 * inf in the box test).
TEST(Watertight, AxisParallelFromInsideOnSlabPlanes) {
    const TriangleMesh m = octahedron();
    const Bvh bvh = build(m, [] { BuildOptions o; o.max_leaf = 1; return o; }());
    for (int a = 0; a < 3; ++a)
        for (float s : {1.0f, -1.0f})
            for (float zero : {0.0f, -0.0f}) {
                Ray r;
                r.org = Vec3(0.0f);
                r.dir = Vec3(zero);
                r.dir[a] = s;
                const Hit h = intersect_closest(bvh, m.view(), r);
                ASSERT_TRUE(h.found()) << a << " " << s;
                EXPECT_EQ(h.t, 1.0f);
                EXPECT_TRUE(intersect_any(bvh, m.view(), r));
            }
}

// ---------------------------------------------------------------------------
// Traversal against brute force.

struct Scene {
    std::string name;
    TriangleMesh mesh;
};

std::vector<Scene> scenes() {
    std::vector<Scene> s;
    s.push_back({"octahedron", octahedron()});
    s.push_back({"cube", cube()});
    s.push_back({"icosphere3", icosphere(3)});
    s.push_back({"flat_grid", grid(16, [](uint32_t, uint32_t) { return 0.0f; })});
    {
        Rng rng(17);
        std::vector<float> h(17 * 17);
        for (float& x : h) x = float(rng.below(4)) * 0.25f;
        s.push_back({"terrain", grid(16, [&](uint32_t i, uint32_t j) { return h[j * 17 + i]; })});
    }
    s.push_back({"soup", soup(500, 23)});
    s.push_back({"duplicates", duplicated(icosphere(2), 2, 29)});
    return s;
}

TEST(Traversal, MatchesBruteForce) {
    uint32_t seed = 100;
    for (const Scene& sc : scenes()) {
        const std::vector<Ray> rays = ray_set(sc.mesh, 10008, seed++);
        for (int variant = 0; variant < 2; ++variant) {
            BuildOptions opt;
            if (variant == 1) {
                opt.max_leaf = 1;
                opt.bins = 4;
            }
            const Bvh bvh = build(sc.mesh, opt);
            ASSERT_TRUE(well_formed(bvh, sc.mesh)) << sc.name;
            expect_matches_brute_force(bvh, sc.mesh, variant == 0 ? rays
                                                                  : std::vector<Ray>(rays.begin(), rays.begin() + 1000),
                                       sc.name + (variant ? " leaf1" : ""));
        }
    }
}

// Exact ties: every triangle three times at shuffled ids; the lowest id of
// the copies hit first must win, as in brute force.
TEST(Traversal, TiesGoToTheLowestId) {
    const TriangleMesh base = icosphere(1);
    const TriangleMesh m = duplicated(base, 4, 31);
    const Bvh bvh = build(m, [] { BuildOptions o; o.max_leaf = 1; return o; }());
    Rng rng(37);
    int checked = 0;
    for (int i = 0; i < 2000; ++i) {
        Ray r;
        r.org = rng.in_box(Vec3(-0.3f), Vec3(0.3f));
        r.dir = rng.direction();
        const Hit h = intersect_closest(bvh, m.view(), r);
        ASSERT_TRUE(h.found());
        // No copy of the same triangle has a lower id.
        for (size_t t = 0; t < h.prim; ++t)
            if (m.indices[3 * t] == m.indices[3 * h.prim] && m.indices[3 * t + 1] == m.indices[3 * h.prim + 1] &&
                m.indices[3 * t + 2] == m.indices[3 * h.prim + 2])
                FAIL() << "copy " << t << " has a lower id than " << h.prim;
        ++checked;
    }
    EXPECT_EQ(checked, 2000);
}

TEST(Traversal, EmptyBvhHitsNothing) {
    const TriangleMesh empty;
    const Bvh none = build(empty);
    ASSERT_TRUE(none.empty());
    TraversalStats stats;
    const Ray r;
    EXPECT_FALSE(intersect_closest(none, empty.view(), r, &stats).found());
    EXPECT_FALSE(intersect_any(none, empty.view(), r, &stats));
    EXPECT_EQ(stats.nodes_visited, 0u);
    EXPECT_EQ(stats.triangles_tested, 0u);
    EXPECT_FALSE(brute_force_closest(empty.view(), r).found());
    EXPECT_FALSE(brute_force_any(empty.view(), r));
    // An empty tree over a non-empty mesh still hits nothing.
    const TriangleMesh m = cube();
    EXPECT_FALSE(intersect_closest(Bvh{}, m.view(), r).found());
    EXPECT_FALSE(intersect_any(Bvh{}, m.view(), r));
}

TEST(Traversal, SingleTriangleAndStats) {
    TriangleMesh m;
    m.vertices = {kA, kB, kC};
    m.indices = {0, 1, 2};
    const Bvh bvh = build(m);
    ASSERT_EQ(bvh.nodes.size(), 1u);
    TraversalStats stats;
    const Hit h = intersect_closest(bvh, m.view(), down(0.25f, 0.25f), &stats);
    ASSERT_TRUE(h.found());
    EXPECT_EQ(h.prim, 0u);
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_EQ(stats.nodes_visited, 1u);
    EXPECT_EQ(stats.triangles_tested, 1u);
    // A ray missing the root box visits nothing.
    Ray away = down(5.0f, 5.0f);
    EXPECT_FALSE(intersect_closest(bvh, m.view(), away, &stats).found());
    EXPECT_EQ(stats.nodes_visited, 1u);
    // Stats accumulate; null stats are fine.
    EXPECT_TRUE(intersect_any(bvh, m.view(), down(0.25f, 0.25f), &stats));
    EXPECT_EQ(stats.nodes_visited, 2u);
    EXPECT_TRUE(intersect_any(bvh, m.view(), down(0.25f, 0.25f)));
}

// Closest hit prunes: on a stack of parallel planes a ray through all of
// them tests far fewer triangles than there are.
TEST(Traversal, ClosestHitPrunes) {
    TriangleMesh m;
    for (uint32_t k = 0; k < 512; ++k) {
        const float z = float(k);
        const uint32_t b = uint32_t(m.vertices.size());
        m.vertices.insert(m.vertices.end(), {{0, 0, z}, {1, 0, z}, {0, 1, z}});
        m.indices.insert(m.indices.end(), {b, b + 1, b + 2});
    }
    const Bvh bvh = build(m);
    TraversalStats stats;
    Ray r;
    r.org = {0.25f, 0.25f, -1.0f};
    r.dir = {0, 0, 1};
    const Hit h = intersect_closest(bvh, m.view(), r, &stats);
    ASSERT_TRUE(h.found());
    EXPECT_EQ(h.prim, 0u);
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_LT(stats.triangles_tested, 64u);
    // A finite tmax beyond which everything is ignored.
    r.tmin = 11.5f;  // triangle k is at t = k + 1
    r.tmax = 13.0f;
    const Hit mid = intersect_closest(bvh, m.view(), r);
    ASSERT_TRUE(mid.found());
    EXPECT_EQ(mid.prim, 11u);
    EXPECT_EQ(mid.t, 12.0f);
    r.tmax = 11.9f;
    EXPECT_FALSE(intersect_closest(bvh, m.view(), r).found());
    EXPECT_FALSE(intersect_any(bvh, m.view(), r));
}

// A hand-made, deeper-than-255 chain tree (node k: a leaf with triangle k
// and the rest), with the far child pushed at every level: exercises a stack
// deeper than any tree the builder makes.
TEST(Traversal, HandMadeChainDeeperThanTheStack) {
    const uint32_t n = 400;
    TriangleMesh m;
    // Triangle k at z = n - k: the chain's shallow leaves are the far ones.
    for (uint32_t k = 0; k < n; ++k) {
        const float z = float(n - k);
        const uint32_t b = uint32_t(m.vertices.size());
        m.vertices.insert(m.vertices.end(), {{0, 0, z}, {1, 0, z}, {0, 1, z}});
        m.indices.insert(m.indices.end(), {b, b + 1, b + 2});
    }
    auto tri_box = [&](uint32_t k) {
        canopy::Box b;
        for (int c = 0; c < 3; ++c) b.extend(m.vertex(k, c));
        return b;
    };
    Bvh bvh;
    bvh.permutation.resize(n);
    for (uint32_t k = 0; k < n; ++k) bvh.permutation[k] = k;
    // Nodes: 0 = root (inner over 0..n); inner node for suffix k at
    // position 2k (k >= 1), its leaf sibling (triangle k - 1) at 2k - 1.
    bvh.nodes.resize(2 * n - 1);
    std::vector<canopy::Box> suffix(n + 1);
    for (uint32_t k = n; k-- > 0;) {
        suffix[k] = suffix[k + 1];
        suffix[k].extend(tri_box(k));
    }
    auto inner_pos = [&](uint32_t k) { return k == 0 ? 0u : 2 * k; };
    for (uint32_t k = 0; k + 1 < n; ++k) {
        Node& in = bvh.nodes[inner_pos(k)];
        in.set_box(suffix[k]);
        in.count = 0;
        in.index = 2 * k + 1;
        Node& leaf = bvh.nodes[2 * k + 1];
        leaf.set_box(tri_box(k));
        leaf.index = k;
        leaf.count = 1;
    }
    // The last suffix (one triangle) is a leaf.
    Node& last = bvh.nodes[inner_pos(n - 1)];
    last.set_box(tri_box(n - 1));
    last.index = n - 1;
    last.count = 1;
    ASSERT_TRUE(well_formed(bvh, m));

    Ray r;
    r.org = {0.25f, 0.25f, 0.0f};
    r.dir = {0, 0, 1};
    TraversalStats stats;
    const Hit h = intersect_closest(bvh, m.view(), r, &stats);
    ASSERT_TRUE(h.found());
    EXPECT_EQ(h.prim, n - 1);
    EXPECT_EQ(h.t, 1.0f);
    EXPECT_GE(stats.nodes_visited, uint64_t(n));
    // Every interval and the any-hit query agree with brute force.
    Rng rng(41);
    for (int i = 0; i < 500; ++i) {
        Ray q = r;
        q.org = {rng.uniform(-0.2f, 1.0f), rng.uniform(-0.2f, 1.0f), rng.uniform(-10.0f, 410.0f)};
        q.dir = {rng.uniform(-0.01f, 0.01f), rng.uniform(-0.01f, 0.01f), rng.coin() ? 1.0f : -1.0f};
        q.tmax = rng.uniform(0.0f, 500.0f);
        const Hit a = intersect_closest(bvh, m.view(), q), b = brute_force_closest(m.view(), q);
        ASSERT_EQ(a.prim, b.prim) << i;
        ASSERT_EQ(bits(a.t), bits(b.t)) << i;
        ASSERT_EQ(intersect_any(bvh, m.view(), q), brute_force_any(m.view(), q)) << i;
    }
}

// Rays with NaN or zero directions, or infinite origins, do not crash and
// hit nothing.
TEST(Traversal, DegenerateRays) {
    const TriangleMesh m = icosphere(2);
    const Bvh bvh = build(m);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    std::vector<Ray> rays(4);
    rays[0].dir = Vec3(0.0f);
    rays[1].dir = Vec3(nan, 0.0f, 1.0f);
    rays[2].org = Vec3(nan);
    rays[3].org = Vec3(kInf, 0.0f, 0.0f);
    rays[3].dir = Vec3(-1.0f, 0.0f, 0.0f);
    for (const Ray& r : rays) {
        EXPECT_FALSE(intersect_closest(bvh, m.view(), r).found());
        EXPECT_FALSE(intersect_any(bvh, m.view(), r));
        EXPECT_FALSE(brute_force_closest(m.view(), r).found());
    }
}

}  // namespace
