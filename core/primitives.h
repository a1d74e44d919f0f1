// canopy: per-primitive bounds and centroids, computed once per build.
//
// The build never looks at the input triangles again after this step: every
// node reads the records below through the permutation of primitive ids.
#pragma once

#include "geometry.h"
#include "mesh.h"

#include <algorithm>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace canopy {

// One 32-byte record per input primitive: its box, its (uint32) id and the
// box's half area. The kernel partitions these records themselves, so every
// node streams through a contiguous range of them. -0 is stored as +0. The id
// and the area sit in the fourth lanes, which no arithmetic touches: the
// kernel masks them off before computing with a box (the id's bits as a float
// would be a slow subnormal), and only compares, sums and takes maxima of the
// area.
// Aligned to 32 bytes, so that no record straddles two cache lines: the bins
// load a record as one 256-bit vector where AVX is compiled in.
struct alignas(32) PrimRef {
    Vec3 lo;
    uint32_t id;
    Vec3 hi;
    float area;  // see prim_area()
};
static_assert(sizeof(PrimRef) == 32);

// The centroid the bins are built over: the centre of the primitive's box,
// as 0.5 * lo + 0.5 * hi, which cannot overflow for any finite float box
// (+ 0 turns a -0 from underflowing negative halves into +0). This one
// function defines it for prepare, bin and partition alike.
inline Vec3 centroid(const PrimRef& r) { return r.lo * 0.5f + r.hi * 0.5f + 0.0f; }

// The area stored in a record: the box's half area, computed in double (no
// overflow, no NaN) and rounded to float, saturated at the largest float, and
// 0 below the smallest normal float (so it is never subnormal). Used to find
// a node's large primitives (the size split in kernel/size_split.h) and for the SAH
// lower bound of small nodes (leaf_by_bound()).
inline float prim_area(const Vec3& lo, const Vec3& hi) {
    const double dx = double(hi.x) - double(lo.x), dy = double(hi.y) - double(lo.y),
                 dz = double(hi.z) - double(lo.z);
    const double a = dx * dy + dy * dz + dz * dx;
    if (!(a >= double(std::numeric_limits<float>::min()))) return 0.0f;
    return static_cast<float>(std::min(a, double(std::numeric_limits<float>::max())));
}

// What a range of primitives produced: the union of their boxes and of their
// centroids, the largest record area, and the first primitive (lowest index)
// that was rejected.
struct PrepareSummary {
    static constexpr uint64_t kNone = ~uint64_t(0);
    Box bounds;
    Box cbounds;
    float max_area = 0.0f;
    uint64_t first_bad = kNone;

    void merge(const PrepareSummary& o) {
        bounds.extend(o.bounds);
        cbounds.extend(o.cbounds);
        max_area = std::max(max_area, o.max_area);
        if (o.first_bad < first_bad) first_bad = o.first_bad;
    }
};

// Fills out[first..last) from triangles first..last of the mesh. Triangles
// with an index out of range or a non-finite coordinate are not written;
// the lowest such triangle is reported in first_bad.
PrepareSummary prepare_triangles(const TriangleView& mesh, size_t first, size_t last, PrimRef* out);

// The same for caller-given primitive boxes (any primitive type). A box with
// a non-finite coordinate or lo > hi on some axis is rejected.
PrepareSummary prepare_boxes(std::span<const Box> boxes, size_t first, size_t last, PrimRef* out);

// Throws InputError describing what is wrong with triangle / box `index`.
[[noreturn]] void throw_bad_triangle(const TriangleView& mesh, size_t index);
[[noreturn]] void throw_bad_box(std::span<const Box> boxes, size_t index);

// Throws InputError when the count exceeds kMaxPrimitives, or the index
// array is not a multiple of 3.
void check_triangle_input(const TriangleView& mesh);
void check_box_input(std::span<const Box> boxes);

}  // namespace canopy
