#include "primitives.h"

#include "error.h"
#include "kernel.h"
#include "options.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace canopy {

namespace {

bool finite(const Vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// A point as (x, y, z, 0), reading exactly its 12 bytes. (x, y) is one
// unaligned 8-byte load: _mm_loadl_epi64 reads through an unaligned type,
// where _mm_load_sd would dereference a misaligned double (UBSan: undefined).
inline __m128 load_point(const Vec3& p) {
    const __m128 xy = _mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i_u*>(&p.x)));
    return _mm_movelh_ps(xy, _mm_load_ss(&p.z));
}

// Every coordinate of the three points finite: x - x is 0 for a finite x
// and NaN for an infinity or a NaN, and a sum with a NaN is NaN.
inline bool all_finite(__m128 a, __m128 b, __m128 c) {
    const __m128 d = _mm_add_ps(_mm_add_ps(_mm_sub_ps(a, a), _mm_sub_ps(b, b)), _mm_sub_ps(c, c));
    return (_mm_movemask_ps(_mm_cmpeq_ps(d, _mm_setzero_ps())) & 7) == 7;
}

// The running summary of a range, in registers.
struct Accumulator {
    __m128 lo = simd::pos_inf();
    __m128 hi = simd::neg_inf();
    __m128 clo = lo, chi = hi;
    float max_area = 0.0f;

    // Writes the record of box [lo, hi] (lane 3 ignored) and adds it. Zeros
    // are made +0 (x + 0 is x for every other x, and +0 for -0), as
    // canonical_zero() does; the centroid is the kernel's (simd::centroid).
    void record(PrimRef& r, __m128 lo4, __m128 hi4, size_t id) {
        const __m128 zero = _mm_setzero_ps();
        lo4 = _mm_add_ps(lo4, zero);
        hi4 = _mm_add_ps(hi4, zero);
        _mm_store_ps(&r.lo.x, lo4);
        _mm_store_ps(&r.hi.x, hi4);
        r.id = static_cast<uint32_t>(id);
        r.area = prim_area(r.lo, r.hi);
        max_area = std::max(max_area, r.area);
        lo = _mm_min_ps(lo, lo4);
        hi = _mm_max_ps(hi, hi4);
        const __m128 c = simd::centroid(lo4, hi4);
        clo = _mm_min_ps(clo, c);
        chi = _mm_max_ps(chi, c);
    }
    void into(PrepareSummary& s) const {
        s.bounds = Box{simd::vec3(lo), simd::vec3(hi)};  // empty boxes when no record was added
        s.cbounds = Box{simd::vec3(clo), simd::vec3(chi)};
        s.max_area = max_area;
    }
};

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
    Accumulator acc;
    const size_t nv = mesh.vertices.size();
    const uint32_t* idx = mesh.indices.data();
    const Vec3* v = mesh.vertices.data();
    for (size_t t = first; t < last; ++t) {
        const uint32_t i0 = idx[3 * t], i1 = idx[3 * t + 1], i2 = idx[3 * t + 2];
        if (i0 >= nv || i1 >= nv || i2 >= nv) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = t;
            continue;
        }
        const __m128 a = load_point(v[i0]), b = load_point(v[i1]), c = load_point(v[i2]);
        // Checked on the vertices themselves: min/max would drop a NaN.
        if (!all_finite(a, b, c)) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = t;
            continue;
        }
        acc.record(out[t], _mm_min_ps(a, _mm_min_ps(b, c)), _mm_max_ps(a, _mm_max_ps(b, c)), t);
    }
    acc.into(s);
    return s;
}

PrepareSummary prepare_boxes(std::span<const Box> boxes, size_t first, size_t last, PrimRef* out) {
    PrepareSummary s;
    Accumulator acc;
    for (size_t i = first; i < last; ++i) {
        const Box& b = boxes[i];
        if (!finite(b.lo) || !finite(b.hi) || b.is_empty()) {
            if (s.first_bad == PrepareSummary::kNone) s.first_bad = i;
            continue;
        }
        acc.record(out[i], load_point(b.lo), load_point(b.hi), i);
    }
    acc.into(s);
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
