#include "primitives.h"

#include "error.h"
#include "options.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace canopy {

namespace {

bool finite(const Vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

Vec3 canonical(const Vec3& v) { return {canonical_zero(v.x), canonical_zero(v.y), canonical_zero(v.z)}; }

void record(PrimRef& r, PrepareSummary& s, const Vec3& lo, const Vec3& hi, size_t id) {
    r.lo = canonical(lo);
    r.hi = canonical(hi);
    r.id = static_cast<uint32_t>(id);
    r.area = prim_area(r.lo, r.hi);
    s.max_area = std::max(s.max_area, r.area);
    s.bounds.lo = glm::min(s.bounds.lo, r.lo);
    s.bounds.hi = glm::max(s.bounds.hi, r.hi);
    s.cbounds.extend(centroid(r));
}

std::string vec_str(const Vec3& v) {
    std::ostringstream os;
    os << '(' << v.x << ", " << v.y << ", " << v.z << ')';
    return os.str();
}

}  // namespace

void check_triangle_input(const TriangleView& mesh) {
    if (mesh.indices.size() % 3 != 0)
        throw InputError("triangle index array has " + std::to_string(mesh.indices.size()) +
                         " entries, not a multiple of 3");
    if (mesh.triangle_count() > kMaxPrimitives)
        throw InputError("too many triangles: " + std::to_string(mesh.triangle_count()) +
                         " (the limit is " + std::to_string(kMaxPrimitives) + ")");
}

void check_box_input(std::span<const Box> boxes) {
    if (boxes.size() > kMaxPrimitives)
        throw InputError("too many primitives: " + std::to_string(boxes.size()) + " (the limit is " +
                         std::to_string(kMaxPrimitives) + ")");
}

PrepareSummary prepare_triangles(const TriangleView& mesh, size_t first, size_t last, PrimRef* out) {
    PrepareSummary s;
    const size_t nv = mesh.vertices.size();
    const uint32_t* idx = mesh.indices.data();
    const Vec3* v = mesh.vertices.data();
    for (size_t t = first; t < last; ++t) {
        const uint32_t i0 = idx[3 * t], i1 = idx[3 * t + 1], i2 = idx[3 * t + 2];
        if (i0 >= nv || i1 >= nv || i2 >= nv) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = t;
            continue;
        }
        const Vec3 a = v[i0], b = v[i1], c = v[i2];
        // Checked on the vertices themselves: min/max would drop a NaN.
        if (!finite(a) || !finite(b) || !finite(c)) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = t;
            continue;
        }
        record(out[t], s, glm::min(a, glm::min(b, c)), glm::max(a, glm::max(b, c)), t);
    }
    return s;
}

PrepareSummary prepare_boxes(std::span<const Box> boxes, size_t first, size_t last, PrimRef* out) {
    PrepareSummary s;
    for (size_t i = first; i < last; ++i) {
        const Box& b = boxes[i];
        if (!finite(b.lo) || !finite(b.hi) || b.is_empty()) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = i;
            continue;
        }
        record(out[i], s, b.lo, b.hi, i);
    }
    return s;
}

void throw_bad_triangle(const TriangleView& mesh, size_t t) {
    const size_t nv = mesh.vertices.size();
    for (int k = 0; k < 3; ++k) {
        const uint32_t i = mesh.indices[3 * t + k];
        if (i >= nv)
            throw InputError("triangle " + std::to_string(t) + ": vertex index " + std::to_string(i) +
                             " is out of range (the mesh has " + std::to_string(nv) + " vertices)");
    }
    for (int k = 0; k < 3; ++k) {
        const uint32_t i = mesh.indices[3 * t + k];
        if (!finite(mesh.vertices[i]))
            throw InputError("triangle " + std::to_string(t) + ": vertex " + std::to_string(i) +
                             " has a non-finite coordinate " + vec_str(mesh.vertices[i]));
    }
    throw InputError("triangle " + std::to_string(t) + " is invalid");
}

void throw_bad_box(std::span<const Box> boxes, size_t i) {
    const Box& b = boxes[i];
    if (!finite(b.lo) || !finite(b.hi))
        throw InputError("primitive box " + std::to_string(i) + " has a non-finite coordinate: " +
                         vec_str(b.lo) + " - " + vec_str(b.hi));
    throw InputError("primitive box " + std::to_string(i) + " is inverted (lo > hi): " + vec_str(b.lo) +
                     " - " + vec_str(b.hi));
}

}  // namespace canopy
