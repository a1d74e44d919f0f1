// canopy: the SIMD vocabulary of the kernel: a record's box and centroid as
// vectors, boxes for the hot loops (Box4, and MinBox, kept as (lo, -hi)),
// and the SAH measure of boxes within one node (Measure).
#pragma once

#include "../geometry.h"
#include "../primitives.h"

#include <algorithm>
#include <bit>
#include <cstdint>
#include <limits>

#include <emmintrin.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

namespace canopy {

// SSE2 helpers. A PrimRef loads as two 4-lane vectors: (lo, id) and
// (hi, pad). Lane 3 is cleared before any arithmetic, so the id's bits are
// never used as a float (they would be subnormal and slow, and meaningless).
namespace simd {
inline __m128 xyz_mask() { return _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1)); }
inline __m128 lo(const PrimRef& r) { return _mm_and_ps(_mm_load_ps(&r.lo.x), xyz_mask()); }
inline __m128 hi(const PrimRef& r) { return _mm_and_ps(_mm_load_ps(&r.hi.x), xyz_mask()); }
// (hi, area) unmasked: for comparisons and maxima only. Growing a box's hi
// with it leaves the largest area in lane 3 (see lane3()), at no cost.
inline __m128 hi_area(const PrimRef& r) { return _mm_load_ps(&r.hi.x); }
inline float lane(__m128 v, int k) {
    alignas(16) float f[4];
    _mm_store_ps(f, v);
    return f[k];
}
inline float lane3(__m128 v) { return _mm_cvtss_f32(_mm_shuffle_ps(v, v, _MM_SHUFFLE(3, 3, 3, 3))); }
// The centroid, lane for lane the same IEEE operations as centroid().
inline __m128 centroid(__m128 lo, __m128 hi) {
    const __m128 half = _mm_set1_ps(0.5f);
    return _mm_add_ps(_mm_add_ps(_mm_mul_ps(lo, half), _mm_mul_ps(hi, half)), _mm_setzero_ps());
}
#if defined(__AVX__)
// xyz_mask() in both 128-bit halves.
inline __m256 xyz_mask2() { return _mm256_castsi256_ps(_mm256_set_epi32(0, -1, -1, -1, 0, -1, -1, -1)); }
// Lanes 0-2 and 4-7 (a record's lo, hi and area; not its id).
inline __m256 xyz_area_mask2() { return _mm256_castsi256_ps(_mm256_set_epi32(-1, -1, -1, -1, 0, -1, -1, -1)); }
// centroid() of two boxes at once, one in each 128-bit half (lane 3 of lo
// and hi cleared): lane for lane the same IEEE operations.
inline __m256 centroid2(__m256 lo, __m256 hi) {
    const __m256 half = _mm256_set1_ps(0.5f);
    return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(lo, half), _mm256_mul_ps(hi, half)), _mm256_setzero_ps());
}
#endif
inline __m128 vec(const Vec3& v) { return _mm_set_ps(0.0f, v.z, v.y, v.x); }
inline Vec3 vec3(__m128 v) {
    alignas(16) float f[4];
    _mm_store_ps(f, v);
    return {f[0], f[1], f[2]};
}
// Lane by lane: a where mask is all ones, b where it is all zeros (masks
// from comparisons only).
inline __m128 select(__m128 mask, __m128 a, __m128 b) {
#if defined(__SSE4_1__)
    return _mm_blendv_ps(b, a, mask);
#else
    return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
#endif
}
inline __m128i select(__m128i mask, __m128i a, __m128i b) {
#if defined(__SSE4_1__)
    return _mm_blendv_epi8(b, a, mask);
#else
    return _mm_or_si128(_mm_and_si128(mask, a), _mm_andnot_si128(mask, b));
#endif
}
// uint32 lanes to float, rounded as float(uint32_t) rounds. Lanes of 2^31 or
// more are halved with the lost bit kept as a sticky bit (round to odd),
// converted, and doubled: one correct rounding.
inline __m128 to_float(__m128i n) {
    const __m128 direct = _mm_cvtepi32_ps(n);
    const __m128i halved = _mm_or_si128(_mm_srli_epi32(n, 1), _mm_and_si128(n, _mm_set1_epi32(1)));
    const __m128 big = _mm_cvtepi32_ps(halved);
    const __m128 high = _mm_castsi128_ps(_mm_srai_epi32(n, 31));
    return select(high, _mm_add_ps(big, big), direct);
}
inline __m128 pos_inf() { return _mm_set1_ps(std::numeric_limits<float>::infinity()); }
inline __m128 neg_inf() { return _mm_set1_ps(-std::numeric_limits<float>::infinity()); }

// A box as two vectors, for accumulation in the hot loops.
struct Box4 {
    __m128 lo = pos_inf();
    __m128 hi = neg_inf();
    void grow(__m128 l, __m128 h) {
        lo = _mm_min_ps(lo, l);
        hi = _mm_max_ps(hi, h);
    }
    void grow(const Box4& b) { grow(b.lo, b.hi); }
    Box box() const { return Box{vec3(lo), vec3(hi)}; }
    static Box4 of(const Box& b) { return Box4{vec(b.lo), vec(b.hi)}; }
};

// A box kept as (lo, -hi), for the bins: growing it is one minimum over both
// halves, a single 256-bit operation where AVX is compiled in (two 128-bit
// ones otherwise). min(-a, -b) = -max(a, b) exactly, and on a tie (equal
// values, +0 and -0 included) both return their second operand, so the box
// is bit for bit the Box4 that max() would have grown.
inline __m128 negate(__m128 v) { return _mm_xor_ps(v, _mm_set1_ps(-0.0f)); }
#if defined(__AVX__)
struct MinBox {
    __m256 v = _mm256_set1_ps(std::numeric_limits<float>::infinity());
    // A record's (lo, -hi), both with lane 3 cleared.
    static __m256 of(const PrimRef& r) {
        const __m256 keep = xyz_mask2();
        constexpr int32_t s = std::numeric_limits<int32_t>::min();  // the sign bit
        const __m256 sign = _mm256_castsi256_ps(_mm256_set_epi32(0, s, s, s, 0, 0, 0, 0));
        return _mm256_xor_ps(_mm256_and_ps(_mm256_loadu_ps(&r.lo.x), keep), sign);
    }
    // of() with the record's area kept in lane 7, negated like hi (so box4()
    // has the largest area in lane 3 of hi): what the bins hold.
    static __m256 with_area(const PrimRef& r) {
        const __m256 keep = xyz_area_mask2();
        constexpr int32_t s = std::numeric_limits<int32_t>::min();
        const __m256 sign = _mm256_castsi256_ps(_mm256_set_epi32(s, s, s, s, 0, 0, 0, 0));
        return _mm256_xor_ps(_mm256_and_ps(_mm256_loadu_ps(&r.lo.x), keep), sign);
    }
    void grow(__m256 x) { v = _mm256_min_ps(v, x); }
    void grow(const MinBox& o) { grow(o.v); }
    Box4 box4() const { return Box4{_mm256_castps256_ps128(v), negate(_mm256_extractf128_ps(v, 1))}; }
#if defined(__AVX2__)
    // of() with lane 3 all ones (a NaN): a minimum whose first operand it is
    // returns the second operand's lane 3 unchanged, whatever its bits
    // (MINPS returns the second operand when either is a NaN). The bins
    // keep their count there (see BinArrays). That operand order is the
    // reverse of grow()'s, which matters only on a tie of +0 and -0: the
    // records hold no -0 (prepare makes it +0), so the boxes are the same.
    // Lane 7 holds the negated area, as with_area().
    static __m256 counted(const PrimRef& r) {
        const __m256 keep = xyz_area_mask2();
        constexpr int32_t s = std::numeric_limits<int32_t>::min();
        const __m256 flip = _mm256_castsi256_ps(_mm256_set_epi32(s, s, s, s, -1, 0, 0, 0));
        return _mm256_xor_ps(_mm256_and_ps(_mm256_loadu_ps(&r.lo.x), keep), flip);
    }
#endif
};
#else
struct MinBox {
    struct Packed {
        __m128 lo, nhi;
    };
    __m128 lo = pos_inf(), nhi = pos_inf();
    static Packed of(const PrimRef& r) {
        return {simd::lo(r), negate(simd::hi(r))};
    }
    static Packed with_area(const PrimRef& r) { return {simd::lo(r), negate(simd::hi_area(r))}; }
    void grow(const Packed& x) {
        lo = _mm_min_ps(lo, x.lo);
        nhi = _mm_min_ps(nhi, x.nhi);
    }
    void grow(const MinBox& o) { grow(Packed{o.lo, o.nhi}); }
    Box4 box4() const { return Box4{lo, negate(nhi)}; }
};
#endif

// The SAH measure of boxes inside one node, in float without overflow or
// loss: every box is scaled by the same power of two, 2^-e with 2^e at least
// the node's largest extent, so scaled extents are at most 1 and the
// measure at most 3 (a power-of-two scale is exact for normal results, and
// the same factor for every candidate keeps their ranking). Half area, or
// with use_length (a node of zero area) the sum of extents.
struct Measure {
    __m128 scale;
    bool use_length;
    [[gnu::always_inline]] Measure(const Box& node, bool length) : use_length(length) {
        const double ext = std::max({node.extent(0), node.extent(1), node.extent(2)});
        // e = floor(log2(ext)) + 1 from the double's exponent field, so
        // ext < 2^e; the scale 2^-e is built from its bits (1 <= 127 - e <= 253
        // keeps it a normal float).
        const int e = int((std::bit_cast<uint64_t>(ext) >> 52) & 0x7FF) - 1022;
        const int biased = std::clamp(127 - e, 1, 253);
        scale = _mm_set1_ps(std::bit_cast<float>(uint32_t(biased) << 23));
    }
    // The measure of three (lo, -hi) boxes at once, lane a for box a (lane
    // 3: 0); lane for lane the same value as operator(). It starts from the
    // negated extents lo * s + (-hi) * s, which are exactly -(hi * s - lo * s)
    // (a zero extent comes out +0 either way): three operations per box
    // instead of five. Products of two negated extents are the products of
    // the extents; a length is negated back.
    [[gnu::always_inline]] __m128 three(const MinBox (&b)[3]) const { return three(b[0], b[1], b[2]); }
    [[gnu::always_inline]] __m128 three(const MinBox& b0, const MinBox& b1, const MinBox& b2) const {
#if defined(__AVX__)
        const __m256 s8 = _mm256_set_m128(scale, scale);
        const auto neg_extent = [&](const MinBox& m) {
            const __m256 v = _mm256_mul_ps(m.v, s8);
            return _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
        };
#else
        const auto neg_extent = [&](const MinBox& m) {
            return _mm_add_ps(_mm_mul_ps(m.lo, scale), _mm_mul_ps(m.nhi, scale));
        };
#endif
        __m128 x = neg_extent(b0), y = neg_extent(b1), z = neg_extent(b2), w = _mm_setzero_ps();
        _MM_TRANSPOSE4_PS(x, y, z, w);  // now x = (-dx of box 0, 1, 2, 0), y = -dys, z = -dzs
        if (use_length) return negate(_mm_add_ps(_mm_add_ps(x, y), z));
        return _mm_add_ps(_mm_add_ps(_mm_mul_ps(x, y), _mm_mul_ps(y, z)), _mm_mul_ps(z, x));
    }
    float operator()(const Box4& b) const {
        const __m128 d = _mm_sub_ps(_mm_mul_ps(b.hi, scale), _mm_mul_ps(b.lo, scale));
        alignas(16) float f[4];
        if (use_length) {
            _mm_store_ps(f, d);
            return f[0] + f[1] + f[2];
        }
        // (dx, dy, dz) * (dy, dz, dx) = (dx dy, dy dz, dz dx)
        const __m128 p = _mm_mul_ps(d, _mm_shuffle_ps(d, d, _MM_SHUFFLE(3, 0, 2, 1)));
        _mm_store_ps(f, p);
        return f[0] + f[1] + f[2];
    }
};
}  // namespace simd

}  // namespace canopy
