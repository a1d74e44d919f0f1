#include "traversal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

// The watertight test relies on a*b - c*d being rounded as two products and a
// difference: contracting it into a fused multiply-add would break the exact
// antisymmetry of the edge function of an edge shared by two triangles, and
// rays through shared edges would leak. Clang contracts within expressions
// by default and GCC (in C++, on FMA targets such as -march=haswell)
// across them, so contraction is turned off for the triangle test.
#if defined(__clang__)
#pragma clang fp contract(off)
#define CANOPY_NO_FP_CONTRACT
#elif defined(__GNUC__)
#define CANOPY_NO_FP_CONTRACT __attribute__((optimize("fp-contract=off")))
#else
#define CANOPY_NO_FP_CONTRACT
#endif

namespace canopy {

namespace {

constexpr float kEps = 0x1p-24f;  // unit roundoff of float
constexpr float gamma_n(int n) { return (float(n) * kEps) / (1.0f - float(n) * kEps); }
// Ize 2013: the far slab distances are scaled by 1 + 2 gamma(3), so that a
// box the ray touches is never rejected because of rounding. That pushes a
// positive far distance away from the near one; a negative far distance
// (rays with tmin < 0) is scaled by 1 - 2 gamma(3) for the same effect:
// scaling it up would make a flat box, whose near and far distances are
// equal, reject the ray.
constexpr float kFarScale = 1.0f + 2.0f * gamma_n(3);
constexpr float kFarScaleNeg = 1.0f - 2.0f * gamma_n(3);

// ---------------------------------------------------------------------------
// Watertight ray-triangle test (Woop, Benthin and Wald 2013).

// Everything of the ray the triangle test needs, computed once per ray: the
// axis kz where the direction is largest in magnitude, the other two axes
// (swapped when dir[kz] < 0 so the winding is kept), and the shear constants
// that map the direction to the unit +z axis.
struct TriRay {
    int kx = 0, ky = 1, kz = 2;
    float sx = 0.0f, sy = 0.0f, sz = 0.0f;
    Vec3 org{0.0f};
    float tmin = 0.0f, tmax = 0.0f;

    explicit TriRay(const Ray& r) : org(r.org), tmin(r.tmin), tmax(r.tmax) {
        const Vec3 ad(std::fabs(r.dir.x), std::fabs(r.dir.y), std::fabs(r.dir.z));
        kz = 0;
        if (ad.y > ad[kz]) kz = 1;
        if (ad.z > ad[kz]) kz = 2;
        kx = kz == 2 ? 0 : kz + 1;
        ky = kx == 2 ? 0 : kx + 1;
        if (r.dir[kz] < 0.0f) std::swap(kx, ky);
        sx = r.dir[kx] / r.dir[kz];
        sy = r.dir[ky] / r.dir[kz];
        sz = 1.0f / r.dir[kz];
    }
};

// The end of the test, shared by the float path and the double fallback:
// sign test of the edge functions, determinant, scaled distance, range test
// before the division, then the division.
template <class F>
bool finish(F U, F V, F W, float az, float bz, float cz, const TriRay& r, float& t, float& u,
            float& v) {
    // Mixed signs: the ray passes outside one of the edges. Zeros are on an
    // edge and count as inside (both triangles of a shared edge may hit).
    if ((U < F(0) || V < F(0) || W < F(0)) && (U > F(0) || V > F(0) || W > F(0))) return false;
    const F det = U + V + W;
    if (det == F(0)) return false;  // the ray is parallel to the triangle (or it is degenerate)
    const F T = U * F(az) + V * F(bz) + W * F(cz);
    // t = T / det. With D = |det| > 0 and Tp = T * sign(det), the range test
    // tmin <= t <= tmax reads tmin * D <= Tp <= tmax * D and needs no
    // division. Written so that NaN fails it.
    const bool neg = det < F(0);
    const F D = neg ? -det : det;
    const F Tp = neg ? -T : T;
    if (!(Tp >= F(r.tmin) * D && Tp <= F(r.tmax) * D)) return false;
    const float tt = static_cast<float>(T / det);
    // The test above is done on rounded products; the quotient decides.
    if (!(tt >= r.tmin && tt <= r.tmax)) return false;
    t = tt;
    // Barycentrics: the hit point is (U a + V b + W c) / det, so u weighs
    // vertex 1 (b) and v weighs vertex 2 (c); vertex 0 has 1 - u - v.
    u = static_cast<float>(V / det);
    v = static_cast<float>(W / det);
    return true;
}

CANOPY_NO_FP_CONTRACT bool intersect_prepared(const TriRay& r, const Vec3& a, const Vec3& b,
                                              const Vec3& c, float& t, float& u, float& v) {
    // Vertices relative to the ray origin.
    const float A[3] = {a.x - r.org.x, a.y - r.org.y, a.z - r.org.z};
    const float B[3] = {b.x - r.org.x, b.y - r.org.y, b.z - r.org.z};
    const float C[3] = {c.x - r.org.x, c.y - r.org.y, c.z - r.org.z};
    // Shear (and, implicitly, permute) so the ray becomes the +z axis.
    const float ax = A[r.kx] - r.sx * A[r.kz];
    const float ay = A[r.ky] - r.sy * A[r.kz];
    const float bx = B[r.kx] - r.sx * B[r.kz];
    const float by = B[r.ky] - r.sy * B[r.kz];
    const float cx = C[r.kx] - r.sx * C[r.kz];
    const float cy = C[r.ky] - r.sy * C[r.kz];
    // Scaled z of the vertices (the distances along the ray of their planes).
    const float az = r.sz * A[r.kz];
    const float bz = r.sz * B[r.kz];
    const float cz = r.sz * C[r.kz];
    // 2D edge functions: U for edge bc, V for edge ca, W for edge ab.
    const float U = cx * by - cy * bx;
    const float V = ax * cy - ay * cx;
    const float W = bx * ay - by * ax;
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
        // The paper's fallback: products of floats are exact in double, so
        // the signs of the edge functions are exact.
        const double Ud = double(cx) * double(by) - double(cy) * double(bx);
        const double Vd = double(ax) * double(cy) - double(ay) * double(cx);
        const double Wd = double(bx) * double(ay) - double(by) * double(ax);
        return finish<double>(Ud, Vd, Wd, az, bz, cz, r, t, u, v);
    }
    return finish<float>(U, V, W, az, bz, cz, r, t, u, v);
}

bool intersect_prim(const TriRay& r, const TriangleView& mesh, uint32_t prim, float& t, float& u,
                    float& v) {
    const uint32_t* idx = mesh.indices.data() + 3 * size_t(prim);
    const Vec3* vs = mesh.vertices.data();
    return intersect_prepared(r, vs[idx[0]], vs[idx[1]], vs[idx[2]], t, u, v);
}

// The closest-hit order: smaller t, then the lower primitive id.
bool better(float t, uint32_t prim, const Hit& best) {
    return t < best.t || (t == best.t && prim < best.prim);
}

// ---------------------------------------------------------------------------
// Robust ray-box test (Ize 2013).

struct BoxRay {
    float org[3];
    float inv[3];  // 1 / dir: +-inf for a zero component
    bool neg[3];   // sign bit of inv: the near plane is max, not min
    // How far the box interval is widened around the ray's interval (see
    // widen_*).
    float scale = 0.0f;

    BoxRay(const Ray& r, const Node& root) {
        float dmax = 0.0f, omax = 0.0f;
        for (int a = 0; a < 3; ++a) {
            org[a] = r.org[a];
            inv[a] = 1.0f / r.dir[a];
            neg[a] = std::signbit(inv[a]);
            dmax = std::fmax(dmax, std::fabs(r.dir[a]));
            omax = std::fmax(omax, std::fmax(std::fabs(root.min[a] - r.org[a]),
                                             std::fabs(root.max[a] - r.org[a])));
        }
        scale = omax / dmax;
        if (!(scale < std::numeric_limits<float>::infinity()))
            scale = std::numeric_limits<float>::infinity();  // includes NaN (0 / 0)
    }
};

// The triangle test rounds differently from the box test: a triangle's
// computed t can lie slightly outside the slab interval of a box that
// contains it (typically a hit on a vertex or edge that is also a face of
// its leaf box, e.g. an axis-parallel ray on a flat grid). Pruning boxes at
// exactly the ray's interval could then skip a triangle that the brute force
// accepts, or that ties the current best with a lower id. So the interval a
// box is tested against is widened by 2^-16 (256 units of roundoff) times
// |t| plus the scene's extent seen from the origin in units of t (the scale
// of the absolute rounding error of t). Only pruning is affected; the hits
// themselves are decided by the triangle test on the ray's own [tmin, tmax],
// so the result is the brute-force result.
// Relative padding cannot cover subnormal distances, whose roundoff is
// absolute (up to half of 2^-149 per operation): both the ray's interval and
// every slab's far distance are also widened by the smallest normal float,
// which is negligible for any t of normal size and stops pruning altogether
// among boxes that are all within subnormal distances.
constexpr float kSlack = 0x1p-16f;
constexpr float kAbsSlack = std::numeric_limits<float>::min();

float widen_up(float t, const BoxRay& r) {
    if (!std::isfinite(t)) return t;
    return t + kSlack * (std::fabs(t) + r.scale) + kAbsSlack;
}
float widen_down(float t, const BoxRay& r) {
    if (!std::isfinite(t)) return t;
    return t - kSlack * (std::fabs(t) + r.scale) - kAbsSlack;
}

// True when the ray meets the node's box within [lo, hi]; tnear is then the
// entry distance (at least lo). NaN slab distances, from 0 * inf when the
// origin lies on a slab plane and the direction has a zero component along
// that axis, are ignored (the ray runs inside that slab): every comparison
// is written so that a NaN leaves tn / tf unchanged.
bool box_hit(const Node& n, const BoxRay& r, float lo, float hi, float& tnear) {
    float tn = lo, box_far = std::numeric_limits<float>::infinity();
    for (int a = 0; a < 3; ++a) {
        const float t0 = (n.min[a] - r.org[a]) * r.inv[a];
        const float t1 = (n.max[a] - r.org[a]) * r.inv[a];
        const float near = r.neg[a] ? t1 : t0;
        const float f = r.neg[a] ? t0 : t1;
        const float far = f * (f < 0.0f ? kFarScaleNeg : kFarScale);
        if (near > tn) tn = near;
        if (far < box_far) box_far = far;
    }
    // The absolute pad once, on the nearest far distance (adding it is
    // monotone, so this equals padding every slab).
    const float tf = std::min(hi, box_far + kAbsSlack);
    tnear = tn;
    return tn <= tf;
}

// ---------------------------------------------------------------------------
// Traversal stack: fixed storage for every valid tree (depth <= 255, at most
// one pending node per level), spilling to the heap should a tree from
// elsewhere be deeper.

struct Entry {
    uint32_t node;
    float tnear;
};

class Stack {
public:
    void push(Entry e) {
        if (sp_ < fixed_.size())
            fixed_[sp_++] = e;
        else
            spill_.push_back(e);
    }
    bool pop(Entry& e) {
        if (!spill_.empty()) {
            e = spill_.back();
            spill_.pop_back();
            return true;
        }
        if (sp_ == 0) return false;
        e = fixed_[--sp_];
        return true;
    }

private:
    std::array<Entry, 256> fixed_;
    size_t sp_ = 0;
    std::vector<Entry> spill_;
};

// Both traversals. Closest: keep the best hit, prune at it. Any: stop at the
// first hit.
template <bool kAny>
Hit traverse(const Bvh& bvh, const TriangleView& mesh, const Ray& ray, TraversalStats* stats) {
    Hit best;
    if (bvh.empty()) return best;
    const Node* nodes = bvh.nodes.data();
    const uint32_t* perm = bvh.permutation.data();
    const TriRay tr(ray);
    const BoxRay br(ray, nodes[0]);
    const float lo = widen_down(ray.tmin, br);
    float hi = widen_up(ray.tmax, br);
    uint64_t visited = 0, tested = 0;

    Stack stack;
    float tnear;
    uint32_t node = 0;
    bool have = box_hit(nodes[0], br, lo, hi, tnear);
    while (have) {
        ++visited;
        const Node& n = nodes[node];
        have = false;
        if (n.is_leaf()) {
            for (uint32_t i = n.index, end = n.index + n.count; i < end; ++i) {
                const uint32_t prim = perm[i];
                float t, u, v;
                ++tested;
                if (!intersect_prim(tr, mesh, prim, t, u, v)) continue;
                if constexpr (kAny) {
                    best = Hit{t, prim, u, v};
                    break;
                }
                if (better(t, prim, best)) {
                    best = Hit{t, prim, u, v};
                    hi = widen_up(t, br);
                }
            }
            if (kAny && best.found()) break;
        } else {
            const uint32_t c0 = n.index, c1 = n.index + 1;
            float n0, n1;
            const bool h0 = box_hit(nodes[c0], br, lo, hi, n0);
            const bool h1 = box_hit(nodes[c1], br, lo, hi, n1);
            if (h0 && h1) {
                // Nearer child first (the left one on a tie).
                if (n1 < n0) {
                    stack.push({c0, n0});
                    node = c1;
                } else {
                    stack.push({c1, n1});
                    node = c0;
                }
                have = true;
            } else if (h0 || h1) {
                node = h0 ? c0 : c1;
                have = true;
            }
        }
        if (have) continue;
        // Pop the next pending node that still starts within the interval.
        Entry e;
        while (stack.pop(e)) {
            if (e.tnear <= hi) {
                node = e.node;
                have = true;
                break;
            }
        }
    }
    if (stats) {
        stats->nodes_visited += visited;
        stats->triangles_tested += tested;
    }
    return best;
}

}  // namespace

bool intersect_triangle(const Ray& ray, const Vec3& a, const Vec3& b, const Vec3& c, float& t,
                        float& u, float& v) {
    return intersect_prepared(TriRay(ray), a, b, c, t, u, v);
}

Hit intersect_closest(const Bvh& bvh, const TriangleView& mesh, const Ray& ray,
                      TraversalStats* stats) {
    return traverse<false>(bvh, mesh, ray, stats);
}

bool intersect_any(const Bvh& bvh, const TriangleView& mesh, const Ray& ray,
                   TraversalStats* stats) {
    return traverse<true>(bvh, mesh, ray, stats).found();
}

Hit brute_force_closest(const TriangleView& mesh, const Ray& ray) {
    const TriRay tr(ray);
    Hit best;
    const size_t n = mesh.triangle_count();
    for (size_t i = 0; i < n; ++i) {
        const uint32_t prim = static_cast<uint32_t>(i);
        float t, u, v;
        if (intersect_prim(tr, mesh, prim, t, u, v) && better(t, prim, best))
            best = Hit{t, prim, u, v};
    }
    return best;
}

bool brute_force_any(const TriangleView& mesh, const Ray& ray) {
    const TriRay tr(ray);
    const size_t n = mesh.triangle_count();
    for (size_t i = 0; i < n; ++i) {
        float t, u, v;
        if (intersect_prim(tr, mesh, static_cast<uint32_t>(i), t, u, v)) return true;
    }
    return false;
}

}  // namespace canopy
