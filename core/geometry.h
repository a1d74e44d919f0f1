// canopy: axis-aligned boxes on GLM.
#pragma once

#include <glm/vec3.hpp>
#include <glm/common.hpp>

#include <cmath>
#include <limits>

namespace canopy {

using Vec3 = glm::vec3;

// An axis-aligned box. The empty box has lo = +inf and hi = -inf so that
// extending it by any point gives that point's box. Min and max are exact
// operations, so merging boxes in any order gives the same bits (provided
// no coordinate is -0; primitive bounds are canonicalised to +0).
struct Box {
    Vec3 lo{std::numeric_limits<float>::infinity()};
    Vec3 hi{-std::numeric_limits<float>::infinity()};

    static Box empty() { return Box{}; }

    void extend(const Vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void extend(const Box& b) {
        lo = glm::min(lo, b.lo);
        hi = glm::max(hi, b.hi);
    }
    bool is_empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }

    // Extent in double precision: hi - lo cannot overflow there even for
    // coordinates at +-FLT_MAX.
    double extent(int axis) const { return double(hi[axis]) - double(lo[axis]); }

    // Half the surface area, in double precision so that it neither
    // overflows nor underflows for any finite float coordinates. Zero for an
    // empty box.
    double half_area() const {
        if (is_empty()) return 0.0;
        const double dx = extent(0), dy = extent(1), dz = extent(2);
        return dx * dy + dy * dz + dz * dx;
    }

    bool contains(const Box& b) const {
        return lo.x <= b.lo.x && lo.y <= b.lo.y && lo.z <= b.lo.z &&
               hi.x >= b.hi.x && hi.y >= b.hi.y && hi.z >= b.hi.z;
    }
    bool contains(const Vec3& p) const {
        return lo.x <= p.x && lo.y <= p.y && lo.z <= p.z &&
               hi.x >= p.x && hi.y >= p.y && hi.z >= p.z;
    }
    bool operator==(const Box&) const = default;
};

// Replaces -0 by +0 (and leaves every other value alone), so that min/max
// merges cannot depend on which of two equal zeros came first.
inline float canonical_zero(float v) { return v == 0.0f ? 0.0f : v; }

}  // namespace canopy
