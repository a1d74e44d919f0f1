// canopy: ray traversal of a canopy BVH over triangles.
//
// The ray-box test is robust (Ize 2013: the far distance is scaled by
// 1 + 2*gamma(3) so that rounding cannot make a ray miss a box it touches),
// and the ray-triangle test is watertight (Woop, Benthin and Wald 2013, with
// its double-precision fallback for edge functions that evaluate to zero),
// so a ray through a shared edge or vertex hits at least one of the
// triangles. The brute-force reference uses the same triangle routine.
//
// Closest hit ties: when two triangles are hit at exactly the same distance,
// the one with the lowest primitive id wins, in traversal and brute force.
#pragma once

#include "bvh.h"
#include "mesh.h"

#include <cstdint>
#include <limits>

namespace canopy {

struct Ray {
    Vec3 org{0.0f};
    Vec3 dir{0.0f, 0.0f, 1.0f};
    float tmin = 0.0f;
    float tmax = std::numeric_limits<float>::infinity();
};

struct Hit {
    float t = std::numeric_limits<float>::infinity();
    uint32_t prim = std::numeric_limits<uint32_t>::max();
    float u = 0.0f, v = 0.0f;  // barycentrics of vertices 1 and 2
    bool found() const { return prim != std::numeric_limits<uint32_t>::max(); }
};

struct TraversalStats {
    uint64_t nodes_visited = 0;
    uint64_t triangles_tested = 0;
};

// Watertight ray-triangle test: true and t in [ray.tmin, ray.tmax] on a hit.
bool intersect_triangle(const Ray& ray, const Vec3& a, const Vec3& b, const Vec3& c, float& t,
                        float& u, float& v);

Hit intersect_closest(const Bvh& bvh, const TriangleView& mesh, const Ray& ray,
                      TraversalStats* stats = nullptr);
bool intersect_any(const Bvh& bvh, const TriangleView& mesh, const Ray& ray,
                   TraversalStats* stats = nullptr);

Hit brute_force_closest(const TriangleView& mesh, const Ray& ray);
bool brute_force_any(const TriangleView& mesh, const Ray& ray);

}  // namespace canopy
