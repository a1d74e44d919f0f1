// canopy: the node-task kernel of binned SAH, in four steps that can each be
// called alone: bin, evaluate, partition, emit. Every scheduler drives these
// same functions; nothing here knows about threads.
//
// The canonical partition is in place and swaps misplaced records in pairs:
// the k-th record of the left part that goes right trades places with the
// k-th record of the right part that goes left (see partition()). The pairs
// depend only on each record's side, so a team-parallel node that finds the
// sides by chunks reproduces the result bit for bit.
//
// The records live in one buffer; each node task owns a contiguous range of
// it, and a leaf writes its primitive ids straight to the permutation.
#pragma once

#include "geometry.h"
#include "options.h"
#include "primitives.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cassert>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <type_traits>
#include <vector>

#include <emmintrin.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

namespace canopy {

// A node task: a range of the permutation and what its parent knew of it.
struct NodeTask {
    uint32_t begin = 0;
    uint32_t end = 0;
    Box bounds;   // union of the primitives' boxes
    Box cbounds;  // union of the primitives' centroids
    float max_area = 0.0f;  // the largest PrimRef::area in the range
    uint32_t depth = 0;
    // Where the node sits, for schedulers that place nodes by arithmetic
    // (see layout.h): the parent's begin, how many right turns lead here,
    // and whether this is a right child.
    uint32_t parent_begin = 0;
    uint8_t rights = 0;
    bool is_right = false;

    uint32_t size() const { return end - begin; }
};

// Counters of work skipped, summed over a build. Integers only, so the sums
// do not depend on the order workers add them.
struct SkipCounts {
    uint64_t axes_not_binned = 0;     // axes with (numerically) zero centroid extent
    uint64_t coincident_nodes = 0;    // all centroids equal: middle split / leaf, no evaluation
    uint64_t depth_cap_splits = 0;    // middle splits forced by the depth budget
    uint64_t single_leaves = 0;       // one-primitive nodes, no binning
    uint64_t inline_tasks = 0;        // node tasks run inline below the task cutoff
    uint64_t parallel_nodes = 0;      // nodes binned and partitioned by the whole team
    uint64_t bound_leaves = 0;        // leaves found by the SAH lower bound, not binned
    uint64_t size_splits = 0;         // not a skip: nodes split by primitive size (see SizeCuts)
    uint64_t exact_nodes = 0;         // nodes of at most kExactMaxPrims primitives costed exactly, not binned
    uint64_t sampled_axes = 0;        // big nodes binned on one axis, chosen from a sample (samples_axis())

    void add(const SkipCounts& o) {
        axes_not_binned += o.axes_not_binned;
        coincident_nodes += o.coincident_nodes;
        depth_cap_splits += o.depth_cap_splits;
        single_leaves += o.single_leaves;
        inline_tasks += o.inline_tasks;
        parallel_nodes += o.parallel_nodes;
        bound_leaves += o.bound_leaves;
        size_splits += o.size_splits;
        exact_nodes += o.exact_nodes;
        sampled_axes += o.sampled_axes;
    }
};

// Nodes of at least this many primitives are binned with twice the bins,
// and from kWidestBinsMin on with four times the bins.
inline constexpr uint32_t kWideBinsMin = 1u << 16;
inline constexpr uint32_t kWidestBinsMin = 1u << 19;

// Bins for a node of n primitives: min(bins, 4) up to 32 primitives, else
// min(bins, bit_ceil(n) / 4), and at least 2; from kWideBinsMin primitives
// up, min(256, 2 * bins); from kWidestBinsMin up, min(256, 4 * bins).
// Small nodes, which are most nodes, use fewer bins: clearing and sweeping
// bins is the fixed cost of a node (with bit_ceil(n) / 2, nodes of 5 to 64
// primitives took 43% of a 1M-sphere build at 600 to 3,700 cycles per node; a
// quarter keeps about 4 primitives per bin). Nodes of 17 to 32 primitives
// had 8 bins until 2026-12-05, when 4-bin nodes came to be binned in
// registers (bin_evaluate_4()): with 4 they took the sequential builds
// 0.978x-0.986x as long (1M sphere, stadium, random; dragon_vrip_res2;
// alternated, 7 rounds) for SAH +0.00% to +0.3% (1M random 383.15 ->
// 384.26, dragon_vrip_res2 43.344 -> 43.423; every mesh of ../shared/scenes
// within 0.9% of the exact sweep, all scenes below Embree's rtcBuildBVH
// but the 1M stadium, as before). 8 bins for 33 to 64 as well (0.968x)
// put Sibenik 2.6% above the exact sweep: not taken. The few huge nodes
// near the root use more: their cost is the pass over their records, not
// the bins, and they are where an object far smaller than the node must not
// be cut by a bin boundary (the 1M stadium's dense sphere sat across the
// middle boundary of the root's 32 bins: SAH 35.19, with 64 there 32.68).
// The 4M stadium needed more in its nodes of one to four million records:
// SAH 39.40 with 64 bins there, 36.76 with 128 (Embree's rtcBuildBVH:
// 37.15).
inline uint32_t bins_for(uint32_t n, uint32_t bins) {
    if (n >= kWidestBinsMin) return std::min(kMaxBins, 4 * bins);
    if (n >= kWideBinsMin) return std::min(kMaxBins, 2 * bins);
    const uint32_t quarter = n <= 32 ? 4 : std::bit_floor(n - 1) / 2;  // bit_ceil(n) / 4 without overflow
    return std::max(kMinBins, std::min(bins, std::max(4u, quarter)));
}

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

// Maps a centroid to its bin on each axis. The one mapping used by both
// bin() and partition(), so the partition agrees with the counts evaluated.
struct BinMapper {
    Vec3 origin{0.0f};
    Vec3 scale{0.0f};  // 0 on axes that are not valid
    Vec3 prescale{1.0f};  // a power of two for tiny extents, else 1
    uint32_t bins = 0;
    std::array<bool, 3> valid{false, false, false};  // axis can be split
    __m128 origin4 = _mm_setzero_ps(), scale4 = _mm_setzero_ps(), last4 = _mm_setzero_ps();
    __m128 prescale4 = _mm_set1_ps(1.0f);
    bool prescaled = false;  // some prescale is not 1 (then bin() takes its slower loop)

    // scale = bins / extent: the largest centroid maps to `bins` and the
    // clamp puts it in the last bin (so every bin is used, for any bin
    // count). An axis is skipped when its extent is zero, when the scale is
    // not finite (a tiny extent), or when the largest centroid still maps
    // to bin 0.
    //
    // Tiny extents (below 2^-64, e.g. a mesh scaled by 10^-30, or subnormal
    // coordinates) would make bins / extent overflow float: there the
    // offset c - origin (exact for such small differences) is first
    // multiplied by a power of two (exact too) that brings the extent near
    // 1, and the scale is computed for the rescaled extent. Other axes keep
    // a prescale of 1, so the mapping of ordinary scenes is unchanged.
    static BinMapper make(const Box& cbounds, uint32_t bins) {
        // The common case, the three axes at once: no extent in (0, 2^-64).
        // The same IEEE operations as make_general() (double extents, bins /
        // extent in double, rounded to float), so the same mapping. There
        // bins / extent <= 2^8 / 2^-64 cannot overflow float, and >= 2^-128
        // (extents of finite floats are below 2^129) is not 0.
        BinMapper m = started(cbounds, bins);
        const __m128 hi4 = simd::vec(cbounds.hi);
        const __m128d ext_xy = _mm_sub_pd(_mm_cvtps_pd(hi4), _mm_cvtps_pd(m.origin4));
        const __m128d ext_z = _mm_sub_pd(_mm_cvtps_pd(_mm_movehl_ps(hi4, hi4)),
                                         _mm_cvtps_pd(_mm_movehl_ps(m.origin4, m.origin4)));  // (z, 0)
        const __m128d zero = _mm_setzero_pd(), tiny = _mm_set1_pd(0x1p-64);
        const __m128d pos_xy = _mm_cmpgt_pd(ext_xy, zero), pos_z = _mm_cmpgt_pd(ext_z, zero);
        if (_mm_movemask_pd(_mm_and_pd(pos_xy, _mm_cmplt_pd(ext_xy, tiny))) |
            _mm_movemask_pd(_mm_and_pd(pos_z, _mm_cmplt_pd(ext_z, tiny))))
            return make_general(cbounds, bins);
        const __m128d nb = _mm_set1_pd(double(bins));
        const __m128 sf = _mm_movelh_ps(_mm_cvtpd_ps(_mm_div_pd(nb, ext_xy)), _mm_cvtpd_ps(_mm_div_pd(nb, ext_z)));
        // The extents' signs as float lanes (x, y, z, 0).
        const __m128 pos = _mm_shuffle_ps(_mm_castpd_ps(pos_xy), _mm_castpd_ps(pos_z), _MM_SHUFFLE(2, 0, 2, 0));
        const __m128 ok = _mm_and_ps(pos, _mm_and_ps(_mm_cmplt_ps(sf, simd::pos_inf()), _mm_cmpgt_ps(sf, _mm_setzero_ps())));
        m.prescale4 = simd::vec(m.prescale);
        m.scale4 = _mm_and_ps(ok, sf);
        m.finish(hi4);
        return m;
    }
    // Any extents, tiny ones included (see above).
    static BinMapper make_general(const Box& cbounds, uint32_t bins) {
        BinMapper m = started(cbounds, bins);
        for (int a = 0; a < 3; ++a) {
            double ext = cbounds.extent(a);
            if (!(ext > 0.0)) continue;
            if (ext < 0x1p-64) {
                const int e = std::min(-std::ilogb(ext), 126);
                m.prescale[a] = std::ldexp(1.0f, e);
                ext = std::ldexp(ext, e);
            }
            const float sf = static_cast<float>(double(bins) / ext);
            if (std::isfinite(sf) && sf > 0.0f) m.scale[a] = sf;
        }
        m.prescale4 = simd::vec(m.prescale);
        m.prescaled = m.prescale != Vec3(1.0f);
        m.scale4 = simd::vec(m.scale);
        m.finish(simd::vec(cbounds.hi));
        return m;
    }
    // The fields both makes start with.
    static BinMapper started(const Box& cbounds, uint32_t bins) {
        BinMapper m;
        m.origin = cbounds.lo;
        m.bins = bins;
        m.origin4 = simd::vec(m.origin);
        m.last4 = _mm_set1_ps(float(bins - 1));
        return m;
    }
    // With scale4 and prescale4 set: an axis is valid when its scale is
    // positive and the largest centroid (hi4) leaves bin 0; the scale of
    // every other axis becomes 0.
    void finish(__m128 hi4) {
        const __m128 ok = _mm_and_ps(_mm_cmpgt_ps(scale4, _mm_setzero_ps()),
                                     _mm_castsi128_ps(_mm_cmpgt_epi32(indices4(hi4), _mm_setzero_si128())));
        scale4 = _mm_and_ps(ok, scale4);
        scale = simd::vec3(scale4);
        const int bits = _mm_movemask_ps(ok);
        for (int a = 0; a < 3; ++a) valid[a] = (bits >> a) & 1;
    }
    bool any_valid() const { return valid[0] || valid[1] || valid[2]; }
    // The same mapping with `axis` the only valid axis.
    BinMapper only(int axis) const {
        BinMapper m = *this;
        for (int a = 0; a < 3; ++a)
            if (a != axis) {
                m.valid[a] = false;
                m.scale[a] = 0.0f;
            }
        m.scale4 = simd::vec(m.scale);
        return m;
    }
    int valid_count() const { return valid[0] + valid[1] + valid[2]; }

    // The bin of a centroid on each axis: floor of (c - origin) * scale,
    // clamped to [0, bins - 1] before the conversion (so no out-of-range
    // float-to-int conversion can happen, even for an infinite product).
    // Prescaled = false leaves out the multiplication by prescale4, which is
    // exact and changes nothing when every prescale is 1 (!prescaled).
    template <bool Prescaled = true>
    __m128i indices4(__m128 c) const {
        __m128 f = _mm_sub_ps(c, origin4);
        if constexpr (Prescaled) f = _mm_mul_ps(f, prescale4);
        f = _mm_mul_ps(f, scale4);
        f = _mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), last4);
        return _mm_cvttps_epi32(f);
    }
    std::array<int32_t, 4> indices(__m128 c) const {
        alignas(16) std::array<int32_t, 4> k;
        _mm_store_si128(reinterpret_cast<__m128i*>(k.data()), indices4(c));
        return k;
    }
    uint32_t index(const Vec3& c, int axis) const { return static_cast<uint32_t>(indices(simd::vec(c))[axis]); }
};

// Per-axis bins: the box of the primitives, their largest area (lane 3 of
// the box's hi, see MinBox::with_area()) and their count.
//
// With AVX2 a bin's count is kept in lane 3 of its box (the lo half's spare
// lane) as an integer: an update is one minimum (MinBox::counted() leaves
// that lane alone) and one integer add, instead of the minimum and a
// separate increment in memory: half the stores. Measured against separate
// counts (bench/ab/run.sh: warm sequential builds of both versions in one
// process, alternated build by build; medians of per-round ratios, several
// runs): the cow 0.96x to 0.97x as long (one run 1.005x), dragon_vrip_res2
// 0.97x (one run 1.00x), the 1M sphere 0.94x to 0.98x (one run 1.02x); in
// the reverse order old/new 1.01x to 1.04x.
// (Otherwise: counts[axis][b]. Stored bin-major instead, so that evaluate()
// could load a bin's three counts as one vector, the sequential dragon build
// took 1% to 2% longer in three alternated comparisons; why is not known.)
#if defined(__AVX2__)
#define CANOPY_PACKED_COUNTS 1
#else
#define CANOPY_PACKED_COUNTS 0
#endif
//
// The bins of axis a are base[a * stride, a * stride + bins), stride being
// the node's bin count rounded up to four (clear() sets it), in storage a
// BinSet owns: a node's bins lie together (3 KiB for 32 bins), and the
// second set of the binning of large ranges right after them. (Until
// 2026-12-05 each axis had room for kMaxBins, 8 KiB apart, and the second
// set was 24 KiB further: a node's hot bins spread over six or seven 4 KiB
// pages. On this project's virtual machine the time of the bin updates
// depended on which physical pages the bins got, stable for as long as a
// set lived: binning the same 202,520 records into twelve sets allocated
// one after another took 0.8 ms for most and 1.0 to 1.9 ms for a third of
// them, and whole sequential builds of dragon_vrip_res2 took 33 ms in some
// processes and 41 to 50 in others, the extra samples all in the bin
// updates. With the bins of a node together, 3 of 72 sets were slow (1.2
// to 1.6 ms), and 1 of 10 dragon processes. Why pages differ was not
// found: no hardware counters here. README, "Slow pages for the bins";
// the measurements in docs/performance-log.md.)
struct BinArrays {
    simd::MinBox* base = nullptr;  // (lo, -hi): see simd::MinBox
    uint32_t stride = 0;
#if !CANOPY_PACKED_COUNTS
    uint32_t* counts = nullptr;  // bin k of axis a: counts[a * stride + k]
#endif
    simd::MinBox& at(int axis, uint32_t k) { return base[size_t(axis) * stride + k]; }
    const simd::MinBox& at(int axis, uint32_t k) const { return base[size_t(axis) * stride + k]; }
    // The three axes' first bins, for the hot loops (locals stay in
    // registers, where the fields would be reloaded after every store).
    struct Axes {
        simd::MinBox* a[3];
    };
    Axes axes() const { return {{base, base + stride, base + 2 * size_t(stride)}}; }
#if CANOPY_PACKED_COUNTS
    // An empty bin: an empty box with count 0.
    static simd::MinBox empty() {
        const float inf = std::numeric_limits<float>::infinity();
        return simd::MinBox{_mm256_setr_ps(inf, inf, inf, 0.0f, inf, inf, inf, inf)};
    }
    // What add() takes for a record.
    static __m256 record(const PrimRef& x) { return simd::MinBox::counted(x); }
    // Adds `inc` records (lane 3 of inc) whose boxes' minimum is rec to bin b.
    static void add(simd::MinBox& b, __m256 rec, __m256i inc) {
        b.v = _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(_mm256_min_ps(rec, b.v)), inc));
    }
    static __m256i one() { return _mm256_setr_epi32(0, 0, 0, 1, 0, 0, 0, 0); }
    // Merges bin `from` into bin `into`: the boxes' minimum, lane 3 the
    // counts' sum.
    static void merge_bin(simd::MinBox& into, const simd::MinBox& from) {
        const __m256 x = from.v, y = into.v;
        const __m256 sum = _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(x), _mm256_castps_si256(y)));
        into.v = _mm256_blend_ps(_mm256_min_ps(y, x), sum, 0x08);
    }
    // Adds a record (record()) to bin k of an axis.
    void add(int axis, int32_t k, __m256 rec) { add(at(axis, uint32_t(k)), rec, one()); }
    uint32_t count(int axis, uint32_t b) const {
        return uint32_t(_mm_extract_epi32(_mm_castps_si128(_mm256_castps256_ps128(at(axis, b).v)), 3));
    }
    void set_count(int axis, uint32_t b, uint32_t n) {  // for tests
        simd::MinBox& x = at(axis, b);
        const __m128i lo = _mm_insert_epi32(_mm_castps_si128(_mm256_castps256_ps128(x.v)), int(n), 3);
        x.v = _mm256_insertf128_ps(x.v, _mm_castsi128_ps(lo), 0);
    }
    // Bin b's counts on the three axes, (x, y, z, 0).
    __m128i count_row(uint32_t b) const {
        const __m128 x = _mm256_castps256_ps128(at(0, b).v), y = _mm256_castps256_ps128(at(1, b).v),
                     z = _mm256_castps256_ps128(at(2, b).v);
        // (x3, y3, z3, 0) from (x2, y2, x3, y3) and (z2, 0, z3, 0).
        return _mm_castps_si128(_mm_movehl_ps(_mm_unpackhi_ps(z, _mm_setzero_ps()), _mm_unpackhi_ps(x, y)));
    }
#else
    static simd::MinBox empty() { return simd::MinBox{}; }
    static auto record(const PrimRef& x) { return simd::MinBox::with_area(x); }
    template <class Rec>  // record()
    void add(int axis, int32_t k, const Rec& rec) {
        at(axis, uint32_t(k)).grow(rec);
        counts[size_t(axis) * stride + uint32_t(k)]++;
    }
    uint32_t count(int axis, uint32_t b) const { return counts[size_t(axis) * stride + b]; }
    void set_count(int axis, uint32_t b, uint32_t n) { counts[size_t(axis) * stride + b] = n; }
#endif

    Box box(int axis, uint32_t b) const { return at(axis, b).box4().box(); }
    // Empties the first `bins` bins of each axis (and up to the next
    // multiple of 4) and sets the stride for them.
    void clear(uint32_t bins) {
        // Four bins at a time: most nodes have 4 bins; std::fill_n became a
        // memset call per axis for the counts and a loop of one box per turn
        // for the boxes.
        static_assert(kMaxBins % 4 == 0);
        stride = (bins + 3) & ~3u;
        const simd::MinBox none = empty();
        simd::MinBox* const b = base;
        for (uint32_t i = 0; i < 3 * stride; i += 4) {
            b[i] = b[i + 1] = b[i + 2] = b[i + 3] = none;
#if !CANOPY_PACKED_COUNTS
            _mm_storeu_si128(reinterpret_cast<__m128i*>(counts + i), _mm_setzero_si128());
#endif
        }
    }
    // The same for the axes `axes` only (the others keep what they hold).
    using AxisSet = std::array<bool, 3>;
    static constexpr AxisSet kAllAxes{true, true, true};
    void clear(uint32_t bins, const AxisSet& axes) {
        stride = (bins + 3) & ~3u;
        const simd::MinBox none = empty();
        simd::MinBox* const b = base;
        for (uint32_t i = 0; i < 3 * stride; i += 4) {
            if (!axes[i / stride]) continue;
            b[i] = b[i + 1] = b[i + 2] = b[i + 3] = none;
#if !CANOPY_PACKED_COUNTS
            _mm_storeu_si128(reinterpret_cast<__m128i*>(counts + i), _mm_setzero_si128());
#endif
        }
    }
    // Exact merge (min/max and integer sums): order-independent. Both sets
    // cleared for the same bins (on `axes`, which alone are merged).
    void merge(const BinArrays& o, uint32_t bins, const AxisSet& axes = kAllAxes) {
        assert(o.stride == stride && bins <= stride);
        for (int a = 0; a < 3; ++a)
            for (uint32_t b = 0; b < bins && axes[a]; ++b) {
#if CANOPY_PACKED_COUNTS
                merge_bin(at(a, b), o.at(a, b));
#else
                at(a, b).grow(o.at(a, b));
                counts[size_t(a) * stride + b] += o.counts[size_t(a) * o.stride + b];
#endif
            }
    }
};

// bin() goes over the records in blocks of this many (see there).
inline constexpr uint32_t kBinBlock = 64;

// The bins a node is binned into, with a second set (odd) that bin() uses as
// scratch for large ranges (see there); only the first set is the result.
// `index` holds the bin indices (one lane per axis) of the last block of
// records that bin() went over: for a node of at most kBinBlock records,
// those of all its records, which partition_binned() reuses. Room for up to
// `max_bins` bins per axis (clear() no more) in each set; the first set's
// bins lie after `index`, the second's right after them (second()), all in
// one block the set owns. Not copyable: the sets point into the block.
// A build makes its sets for the most bins its root uses (bins_for(n,
// bins); 32 by default below kWideBinsMin primitives: 6 KiB of boxes, not
// the 48 KiB of kMaxBins, which with a set per worker were 2 to 3 bytes per
// triangle of the peak memory of 2-thread builds of 33,000 to 50,000
// triangles). With the bins in an allocation of their own, apart from
// `index` (until then both were arrays of the object), 2-thread builds of
// 1M random triangles took 1.02x as long (alternated, 2026-12-05).
struct BinSet : BinArrays {
    BinArrays odd;
    int32_t (*index)[4] = nullptr;  // kBinBlock rows

    explicit BinSet(uint32_t max_bins = kMaxBins)  // clear() before use
        : capacity((std::min(max_bins, kMaxBins) + 3) & ~3u), block(allocate(capacity)) {
        index = reinterpret_cast<int32_t(*)[4]>(block.get());
        base = reinterpret_cast<simd::MinBox*>(block.get() + kIndexBytes);
        std::uninitialized_default_construct_n(base, 6 * size_t(capacity));
        stride = capacity;
#if !CANOPY_PACKED_COUNTS
        counts = reinterpret_cast<uint32_t*>(base + 6 * size_t(capacity));
#endif
    }
    BinSet(const BinSet&) = delete;
    BinSet& operator=(const BinSet&) = delete;
    // The second set, cleared, right after the first set's bins and with
    // their stride (the first set cleared for at least `bins` bins).
    // With `axes`, only those axes' bins are cleared.
    BinArrays& second(uint32_t bins, const AxisSet& axes = kAllAxes) {
        assert(bins <= stride && stride <= capacity);
        (void)bins;
        odd.base = base + 3 * size_t(stride);
#if !CANOPY_PACKED_COUNTS
        odd.counts = counts + 3 * size_t(stride);
#endif
        odd.clear(stride, axes);
        return odd;
    }
    // Bins per axis it has room for (a multiple of 4).
    uint32_t max_bins() const { return capacity; }

private:
    static constexpr size_t kIndexBytes = sizeof(int32_t[kBinBlock][4]);
    static constexpr std::align_val_t kAlign{64};
    struct Free {
        void operator()(std::byte* p) const { ::operator delete(p, kAlign); }
    };
    static std::byte* allocate(uint32_t capacity) {
        size_t bytes = kIndexBytes + 6 * size_t(capacity) * sizeof(simd::MinBox);
#if !CANOPY_PACKED_COUNTS
        bytes += 6 * size_t(capacity) * sizeof(uint32_t);
#endif
        return static_cast<std::byte*>(::operator new(bytes, kAlign));
    }
    uint32_t capacity;
    std::unique_ptr<std::byte, Free> block;
};

// Step 1: bin the centroids of refs[begin, end) on every valid axis, in one
// pass; axes that are not valid are not binned. Accumulates into `out`
// (clear it first).
//
// The bin indices of a block of primitives are computed first and the bins
// updated in a second loop over the same (cache-hot) block. Computed in the
// same loop, each update's store address was known only late, after the
// whole index computation; the next primitive's loads, issued before it,
// were then often found to alias it (neighbours tend to fall in the same
// bin) and replayed. Measured on a 1M-triangle sphere: 40% less time.
//
// Ranges of kTwoBinSetsMin records or more bin every other record into the
// second set (out.odd) and merge it at the end (exact, so the bins are the
// same). Neighbouring records mostly fall in the same bins, and each bin
// update waits for the previous one's store; two sets make two independent
// chains. Measured, sequential builds (alternated runs): 1M sphere 0.94x to
// 0.96x, dragon_vrip_res2 0.98x to 0.99x. Small ranges keep one set:
// clearing and merging a second one would cost more than it saves.
//
// The bins' boxes are simd::MinBox, (lo, -hi): one 256-bit minimum per
// update with AVX instead of a minimum and a maximum on two 128-bit halves.
// Clearing and binning 1M sphere records in ranges of 16, 60, 1,000, 20,000
// and 1M records (a small program against this header, fastest of 30 to 60
// runs, alternated): 0.80x to 0.93x as long; the sequential build of the cow
// runs 4.3% fewer instructions (cachegrind).
inline constexpr uint32_t kTwoBinSetsMin = 256;
// The same for nodes flat on one or two axes (alternate_updates()): their
// records cost less to bin, so the second set's clearing and merging pays
// later (bench/bench_binning, the "AMD EPYC" host, 2026-12-06: at 256
// records two sets took random triangles 1.4 to 1.7 times as long).
inline constexpr uint32_t kTwoBinSetsFlatMin = 1024;
// Nodes binned on one axis from this many records take bin_one_axis().
inline constexpr uint32_t kOneAxisMin = 512;

namespace detail {

// Records r[0], r[S], r[2S], ... as r[0], r[1], r[2]: the hot loops below
// take their records through operator[] (a plain pointer, or this for a
// node's sample, see bin_sample()).
template <uint32_t S>
struct Strided {
    const PrimRef* p;
    const PrimRef& operator[](uint32_t i) const { return p[size_t(i) * S]; }
};

#if CANOPY_PACKED_COUNTS
// Adds record x to bins ki of the three axes of a set (BinArrays::axes()).
inline void update(const BinArrays::Axes& set, const PrimRef& x, const int32_t (&ki)[4]) {
    const auto box = BinArrays::record(x);
    const __m256i one = BinArrays::one();
    BinArrays::add(set.a[0][ki[0]], box, one);
    BinArrays::add(set.a[1][ki[1]], box, one);
    BinArrays::add(set.a[2][ki[2]], box, one);
}
#endif
// Adds record x to set's bins ki on all three axes, through the set (the
// path without AVX2, whose counts are an array of their own).
inline void update(BinArrays& set, const PrimRef& x, const int32_t (&ki)[4]) {
    const auto box = BinArrays::record(x);
    set.add(0, ki[0], box);
    set.add(1, ki[1], box);
    set.add(2, ki[2], box);
}

// What the hot loops hand to update(): the axes' bin pointers as locals with
// AVX2, the set itself otherwise.
#if CANOPY_PACKED_COUNTS
inline BinArrays::Axes hot(BinArrays& set) { return set.axes(); }
#else
inline BinArrays& hot(BinArrays& set) { return set; }
#endif

// The bin updates of a block of records whose indices are in k (bin()'s
// two-set path): record i goes to set s0 for even i and s1 for odd i, except
// that four aligned neighbours (or two) with the same bins on all three axes
// are added as one update (their boxes' minimum, their count), the sets
// alternating. Input in spatial order (scan order, strips, rings) has long
// runs of records in the same bins, and every update of a bin waits for the
// previous one's store: on the 1M sphere 45% of the records binned here
// went in fours and 30% in twos, on dragon_vrip_res2 1% in fours and 14% in
// twos, on random triangles none. Exact (minima and integer sums), so the
// same bins; only the operands' order of a minimum changes, which matters
// for a tie of +0 and -0 alone, and the records hold no -0 (see
// simd::MinBox::counted()). bench/ab/run.sh against one update per record,
// on the Intel Xeon host of 2026-12-04 (9 rounds of 5 warm sequential
// builds, medians of per-round ratios): 1M
// sphere 0.92x (pairs alone 0.955x), 1M stadium 0.90x, 1M random triangles
// 1.00x (in other runs 1.01x to 1.02x: the comparisons), dragon 1.01x, the
// cow 0.98x (the cow and dragon within their noise). The same merging
// in the one-set path (ranges under kTwoBinSetsMin) was slower everywhere
// (1.02x to 1.03x), and eights on top of fours gained nothing (1.00x).
template <class Refs>
inline void merged_updates(BinArrays& set0, BinArrays& set1, Refs r, const int32_t (*k)[4], uint32_t n) {
    uint32_t i = 0;
    auto&& s0 = hot(set0);
    auto&& s1 = hot(set1);
#if CANOPY_PACKED_COUNTS
    const auto row = [&](uint32_t j) { return _mm_load_si128(reinterpret_cast<const __m128i*>(k[j])); };
    const auto add3 = [&](const BinArrays::Axes& set, uint32_t j, __m256 box, uint32_t count) {
        const __m256i inc = _mm256_setr_epi32(0, 0, 0, int(count), 0, 0, 0, 0);
        BinArrays::add(set.a[0][k[j][0]], box, inc);
        BinArrays::add(set.a[1][k[j][1]], box, inc);
        BinArrays::add(set.a[2][k[j][2]], box, inc);
    };
    const auto pair = [&](const BinArrays::Axes& merged, uint32_t j) {
        if (_mm_movemask_epi8(_mm_cmpeq_epi32(row(j), row(j + 1))) == 0xFFFF) {
            add3(merged, j, _mm256_min_ps(BinArrays::record(r[j]), BinArrays::record(r[j + 1])), 2);
        } else {
            update(s0, r[j], k[j]);
            update(s1, r[j + 1], k[j + 1]);
        }
    };
    const BinArrays::Axes* sets[2] = {&s0, &s1};
    uint32_t t = 0;
    for (; i + 3 < n; i += 4) {
        const __m128i a = row(i);
        const __m128i e = _mm_and_si128(_mm_and_si128(_mm_cmpeq_epi32(a, row(i + 1)), _mm_cmpeq_epi32(a, row(i + 2))),
                                        _mm_cmpeq_epi32(a, row(i + 3)));
        if (_mm_movemask_epi8(e) == 0xFFFF) {
            const __m256 box = _mm256_min_ps(_mm256_min_ps(BinArrays::record(r[i]), BinArrays::record(r[i + 1])),
                                             _mm256_min_ps(BinArrays::record(r[i + 2]), BinArrays::record(r[i + 3])));
            add3(*sets[t], i, box, 4);
            t ^= 1;
        } else {
            pair(s0, i);
            pair(s1, i + 2);
        }
    }
#endif
    for (; i + 1 < n; i += 2) {
        update(s0, r[i], k[i]);
        update(s1, r[i + 1], k[i + 1]);
    }
    if (i < n) update(s0, r[i], k[i]);
}

// The bin updates of a block of records on the na < 3 valid axes `axes`
// (bin()'s two-set path for a node flat on the others): record i goes to
// set s0 for even i and s1 for odd i. With one set, each update of a bin
// waited for the previous one's store, and neighbours in spatial order
// share bins: binning the 1M sphere's records in their own order on two
// axes took 3.3 ns a record, on one axis 2.9, where all three axes (two
// sets) took 1.5 (bench/bench_binning, the "AMD EPYC" host, 2026-12-06).
template <int NA, class Refs>
[[gnu::noinline]] void alternate_updates(BinArrays& set0, BinArrays& set1, Refs r, const int32_t (*k)[4],
                                         uint32_t n, const int (&axes)[3]) {
#if CANOPY_PACKED_COUNTS
    simd::MinBox* const b0[2] = {set0.axes().a[axes[0]], set1.axes().a[axes[0]]};
    simd::MinBox* const b1[2] = {set0.axes().a[axes[NA - 1]], set1.axes().a[axes[NA - 1]]};
    const int a0 = axes[0], a1 = axes[NA - 1];
    const __m256i inc = BinArrays::one();
    const auto one = [&](int s, uint32_t i) {
        const __m256 box = BinArrays::record(r[i]);
        BinArrays::add(b0[s][k[i][a0]], box, inc);
        if constexpr (NA == 2) BinArrays::add(b1[s][k[i][a1]], box, inc);
    };
#else
    BinArrays* const sets[2] = {&set0, &set1};
    const auto one = [&](int s, uint32_t i) {
        const auto box = BinArrays::record(r[i]);
        for (int j = 0; j < NA; ++j) sets[s]->add(axes[j], k[i][axes[j]], box);
    };
#endif
    uint32_t i = 0;
    for (; i + 1 < n; i += 2) {
        one(0, i);
        one(1, i + 1);
    }
    if (i < n) one(0, i);
}

// Writes the bin keys (see bin()) of a block of n records whose indices are
// in k to out[0, n).
inline void store_keys(const int32_t (*k)[4], uint32_t n, uint32_t* out) {
    uint32_t i = 0;
#if defined(__AVX2__)
    // Per 128-bit lane: bytes 0, 4 and 8 (the three axes' indices, each
    // below 256) to bytes 0 to 2; then the two lanes' words side by side.
    const __m256i pick = _mm256_setr_epi8(0, 4, 8, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1,  //
                                          0, 4, 8, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
    const __m256i join = _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0);
    for (; i + 1 < n; i += 2) {
        const __m256i v = _mm256_load_si256(reinterpret_cast<const __m256i*>(k[i]));
        const __m256i w = _mm256_permutevar8x32_epi32(_mm256_shuffle_epi8(v, pick), join);
        _mm_storel_epi64(reinterpret_cast<__m128i*>(out + i), _mm256_castsi256_si128(w));
    }
#endif
    for (; i < n; ++i) out[i] = uint32_t(k[i][0]) | uint32_t(k[i][1]) << 8 | uint32_t(k[i][2]) << 16;
}

// The bin indices of records r[0, n) (n <= kBinBlock) on the three axes,
// one row each in k. Pre: see BinMapper::indices4.
template <bool Pre, class Refs = const PrimRef*>
inline void block_indices(Refs r, uint32_t n, const BinMapper& m, int32_t (*k)[4]) {
    uint32_t i0 = 0;
#if defined(__AVX__)
    // Two records at a time in 256-bit vectors, lane for lane the same
    // operations as indices4(centroid()), so the same indices. Against
    // one record per 128-bit step (warm sequential builds, alternated
    // pairs, medians of 7 to 11 pairs): 1M sphere 0.945x as long,
    // dragon_vrip_res2 0.994x, the cow 0.98x.
    {
        const __m256 keep = simd::xyz_mask2();
        const __m256 o = _mm256_set_m128(m.origin4, m.origin4), p = _mm256_set_m128(m.prescale4, m.prescale4);
        const __m256 sc = _mm256_set_m128(m.scale4, m.scale4), last = _mm256_set_m128(m.last4, m.last4);
        for (; i0 + 1 < n; i0 += 2) {
            const __m256 lo = _mm256_and_ps(_mm256_loadu2_m128(&r[i0 + 1].lo.x, &r[i0].lo.x), keep);
            const __m256 hi = _mm256_and_ps(_mm256_loadu2_m128(&r[i0 + 1].hi.x, &r[i0].hi.x), keep);
            __m256 f = _mm256_sub_ps(simd::centroid2(lo, hi), o);
            if constexpr (Pre) f = _mm256_mul_ps(f, p);
            f = _mm256_mul_ps(f, sc);
            f = _mm256_min_ps(_mm256_max_ps(f, _mm256_setzero_ps()), last);
            _mm256_store_si256(reinterpret_cast<__m256i*>(k[i0]), _mm256_cvttps_epi32(f));
        }
    }
#endif
    for (uint32_t i = i0; i < n; ++i)
        _mm_store_si128(reinterpret_cast<__m128i*>(k[i]),
                        m.template indices4<Pre>(simd::centroid(simd::lo(r[i]), simd::hi(r[i]))));
}

// Asks for the records of the block two blocks ahead of the one at r
// (record b0 of a walk ending at `end`) to be cached, when whole.
inline void prefetch_block_ahead(const PrimRef* r, uint32_t b0, uint32_t end) {
    if (b0 + 3 * kBinBlock > end) return;
    const char* p = reinterpret_cast<const char*>(r + 2 * kBinBlock);
    for (uint32_t q = 0; q < kBinBlock * sizeof(PrimRef); q += 64) _mm_prefetch(p + q, _MM_HINT_T0);
}

// bin() over blocks of records; Two: every other record into out.odd;
// Pre: the mapping's prescale is applied (see BinMapper::indices4); keys:
// see bin().
template <bool Two, bool Pre>
inline void bin_blocks(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out,
                       uint32_t* keys) {
    int32_t (*k)[4] = out.index;  // the indices of the current block
    int axes[3], na = 0;
    for (int a = 0; a < 3; ++a)
        if (m.valid[a]) axes[na++] = a;
    for (uint32_t b0 = begin; b0 < end; b0 += kBinBlock) {
        const uint32_t n = std::min(kBinBlock, end - b0);
        const PrimRef* r = refs + b0;
        // Large ranges ask for the block two blocks ahead (4 KiB) to be
        // cached. On this session's Intel Xeon host (bench/ab/run.sh, 9
        // rounds of 5 warm sequential builds): 1M sphere 0.97x as long, 1M
        // random 0.95x, dragon_vrip_res2 0.96x, the 1M stadium 0.99x, the
        // cow 1.00x; one block ahead 1.00x-1.01x and four 1.01x-1.02x
        // against two; prefetching in partition_with() too, 1.01x-1.02x.
        // (On the AMD EPYC host of 2026-12-03 a prefetch in the binning
        // measured 1.01x; its distance was not recorded.)
        if constexpr (Two) prefetch_block_ahead(r, b0, end);
        block_indices<Pre>(r, n, m, k);
        if (keys) store_keys(k, n, keys + b0);
        if constexpr (Two) {
            if (na == 3)
                merged_updates(out, out.odd, r, k, n);
            else if (na == 2)
                alternate_updates<2>(out, out.odd, r, k, n, axes);
            else
                alternate_updates<1>(out, out.odd, r, k, n, axes);
        } else if (na == 3) {
            // The common case, unrolled: the three axes' updates are
            // independent chains.
            auto&& set = hot(out);
            for (uint32_t i = 0; i < n; ++i) update(set, r[i], k[i]);
        } else {
            for (uint32_t i = 0; i < n; ++i) {
                const auto box = BinArrays::record(r[i]);
                for (int j = 0; j < na; ++j) out.add(axes[j], k[i][axes[j]], box);
            }
        }
    }
}

inline bool two_bin_sets(const BinMapper& m, uint32_t begin, uint32_t end) {
    return end - begin >= kTwoBinSetsMin && (end - begin >= kTwoBinSetsFlatMin || m.valid_count() == 3);
}

// Out of line, so that bin() stays small enough to inline into run_node()
// for the many small nodes.
template <bool Pre>
[[gnu::noinline]] void bin_two_sets(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                    BinSet& out, uint32_t* keys) {
    // A node flat on some axis bins and merges only the others.
    out.second(m.bins, m.valid);
    bin_blocks<true, Pre>(refs, begin, end, m, out, keys);
    out.merge(out.odd, m.bins, m.valid);
}

#if CANOPY_PACKED_COUNTS
// bin() of a node with one valid axis, from kOneAxisMin records: what big
// nodes do after choosing their axis from a sample (binning_mapper()), and
// nodes flat on two axes. Its records go round-robin to four sets of that
// axis's bins (the first set's, and the second set's three regions: a
// record waits on the store of the record four back, not two, since one
// axis has the longest runs of neighbours in the same bin), merged into
// the first set at the end. With AVX-512 the indices are computed for that
// axis alone, sixteen records at a time. Binning alone (bench/bench_binning,
// the "AMD EPYC" host, 2026-12-06), ns a record on one axis against all
// three: the 1M sphere in its order 0.90 against 1.49, random triangles
// 0.78 against 1.85, the stadium 0.98 against 1.35 (with two sets and
// all three axes' indices, as flat nodes had: 1.82, 1.25, 2.2).
[[gnu::noinline]] inline void bin_one_axis(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                           BinSet& out, uint32_t* keys) {
    const int a = m.valid[0] ? 0 : m.valid[1] ? 1 : 2;
    BinArrays& odd = out.second(m.bins);
    simd::MinBox* const s0 = out.axes().a[a];
    simd::MinBox* const s1 = odd.axes().a[0];
    simd::MinBox* const s2 = odd.axes().a[1];
    simd::MinBox* const s3 = odd.axes().a[2];
#if !defined(__AVX512F__)
    int32_t (*k)[4] = out.index;
#endif
    const __m256i one = BinArrays::one();
    for (uint32_t b0 = begin; b0 < end; b0 += kBinBlock) {
        const uint32_t n = std::min(kBinBlock, end - b0);
        const PrimRef* r = refs + b0;
        prefetch_block_ahead(r, b0, end);
        uint32_t i = 0;
#if defined(__AVX512F__)
        // Sixteen records at a time: their axis-a corners gathered from
        // eight 512-bit loads by eight permutes, then lane for lane the
        // operations of indices4(centroid()) (so the same indices).
        alignas(64) int32_t idx[kBinBlock];
        for (; i + 16 <= n; i += 16) {
            const __m512i pick = _mm512_setr_epi32(a, 8 + a, 16 + a, 24 + a, 4 + a, 12 + a, 20 + a, 28 + a,  //
                                                   a, 8 + a, 16 + a, 24 + a, 4 + a, 12 + a, 20 + a, 28 + a);
            __m512 w[4];
            for (int j = 0; j < 4; ++j)
                w[j] = _mm512_permutex2var_ps(_mm512_loadu_ps(&r[i + 4 * j].lo.x), pick,
                                              _mm512_loadu_ps(&r[i + 4 * j + 2].lo.x));
            // w[j]: lanes 0-3 the lo of records 4j..4j+3, lanes 4-7 their hi.
            const __m512i join = _mm512_setr_epi32(0, 1, 2, 3, 16, 17, 18, 19, 4, 5, 6, 7, 20, 21, 22, 23);
            const __m512 x0 = _mm512_permutex2var_ps(w[0], join, w[1]);  // lo 0-7, hi 0-7
            const __m512 x1 = _mm512_permutex2var_ps(w[2], join, w[3]);  // lo 8-15, hi 8-15
            const __m512i los = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
            const __m512i his = _mm512_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
            const __m512 lo = _mm512_permutex2var_ps(x0, los, x1), hi = _mm512_permutex2var_ps(x0, his, x1);
            // (Masked forms with a full mask: GCC 12 warns that the
            // unmasked ones start from an uninitialised vector.)
            constexpr __mmask16 all = 0xFFFF;
            const __m512 half = _mm512_set1_ps(0.5f), zero = _mm512_setzero_ps();
            const __m512 c = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(lo, half), _mm512_mul_ps(hi, half)), zero);
            __m512 f = _mm512_mul_ps(_mm512_sub_ps(c, _mm512_set1_ps(m.origin[a])), _mm512_set1_ps(m.scale[a]));
            f = _mm512_mask_max_ps(f, all, f, zero);
            f = _mm512_mask_min_ps(f, all, f, _mm512_set1_ps(float(m.bins - 1)));
            const __m512i ki = _mm512_mask_cvttps_epi32(_mm512_setzero_si512(), all, f);
            _mm512_store_si512(idx + i, ki);
            if (keys) _mm512_storeu_si512(keys + b0 + i, _mm512_mask_slli_epi32(ki, all, ki, unsigned(8 * a)));
        }
        for (uint32_t j = i; j < n; ++j) {
            const __m128i row = m.indices4<false>(simd::centroid(simd::lo(r[j]), simd::hi(r[j])));
            alignas(16) int32_t v[4];
            _mm_store_si128(reinterpret_cast<__m128i*>(v), row);
            idx[j] = v[a];
            if (keys) keys[b0 + j] = uint32_t(v[a]) << (8 * a);
        }
        i = 0;
        for (; i + 3 < n; i += 4) {
            BinArrays::add(s0[idx[i]], BinArrays::record(r[i]), one);
            BinArrays::add(s1[idx[i + 1]], BinArrays::record(r[i + 1]), one);
            BinArrays::add(s2[idx[i + 2]], BinArrays::record(r[i + 2]), one);
            BinArrays::add(s3[idx[i + 3]], BinArrays::record(r[i + 3]), one);
        }
        for (; i < n; ++i) BinArrays::add(s0[idx[i]], BinArrays::record(r[i]), one);
#else
        block_indices<false>(r, n, m, k);
        if (keys) store_keys(k, n, keys + b0);
        for (; i + 3 < n; i += 4) {
            BinArrays::add(s0[k[i][a]], BinArrays::record(r[i]), one);
            BinArrays::add(s1[k[i + 1][a]], BinArrays::record(r[i + 1]), one);
            BinArrays::add(s2[k[i + 2][a]], BinArrays::record(r[i + 2]), one);
            BinArrays::add(s3[k[i + 3][a]], BinArrays::record(r[i + 3]), one);
        }
        for (; i < n; ++i) BinArrays::add(s0[k[i][a]], BinArrays::record(r[i]), one);
#endif
    }
    for (uint32_t b = 0; b < m.bins; ++b) {
        BinArrays::merge_bin(s0[b], s1[b]);
        BinArrays::merge_bin(s0[b], s2[b]);
        BinArrays::merge_bin(s0[b], s3[b]);
    }
}
#endif

// Nodes whose centroid extent is below 2^-64 on some axis (prescaled).
[[gnu::noinline]] inline void bin_prescaled(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m,
                                            BinSet& out, uint32_t* keys) {
    if (two_bin_sets(m, begin, end)) return bin_two_sets<true>(refs, begin, end, m, out, keys);
    bin_blocks<false, true>(refs, begin, end, m, out, keys);
}

}  // namespace detail

// With `keys`, bin() also writes each record's bin indices, its key, beside
// it: keys[i] for refs[i], byte a the index on axis a (at most 255, as
// kMaxBins is 256); keys outside [begin, end) are not touched. partition()
// then reads a record's side from its key (KeyTest) instead of mapping its
// centroid again.
inline void bin(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out,
                uint32_t* keys = nullptr) {
    if (m.prescaled) return detail::bin_prescaled(refs, begin, end, m, out, keys);
#if CANOPY_PACKED_COUNTS
    if (end - begin >= kOneAxisMin && m.valid_count() == 1) return detail::bin_one_axis(refs, begin, end, m, out, keys);
#endif
    if (detail::two_bin_sets(m, begin, end)) return detail::bin_two_sets<false>(refs, begin, end, m, out, keys);
    detail::bin_blocks<false, false>(refs, begin, end, m, out, keys);
}

// Nodes of at least kSampleMin primitives with two or three valid axes
// choose their split axis from a sample: every sample_step()-th record (from
// the node's first) binned on every valid axis and evaluated; then all
// records are binned on that axis alone (bin_one_axis()) and evaluated for
// the split (binning_mapper()). A sample taken by position makes a tree
// depend a little on the order of the records, never on threads.
inline constexpr uint32_t kSampleMin = 512;
inline bool samples_axis(const BinMapper& m, uint32_t n) {
    return n >= kSampleMin && !m.prescaled && m.valid_count() >= 2;
}

// The sample's step for a node of n records (see also sample_step(t) below,
// for nodes with large primitives): 4, doubled while the sample
// keeps at least kSampleTarget records, up to kSampleMaxStep (4 below 8,192
// records, 32 from 32,768). A bigger node's sample is a smaller share of
// it: a quarter of a node that is not in the cache made the sample pass
// cost nearly what the full one-axis pass does (it brought in every line),
// and a thousand records or more choose the axis about as well. Against
// every fourth record throughout (2026-12-06, "AMD EPYC" host, medians of
// 5 alternated rounds' ratios): sequential 1M sphere 0.90x, 1M stadium
// 0.89x, 1M random 0.97x, dragon_vrip_res2 0.93x; tbb at 2 threads 1M
// sphere 0.88x, dragon 0.94x, 1M random 0.96x. SAH within 0.01% on the
// sphere, stadium and random scenes and the dragons, bunny and cow (for
// scenes with a few large primitives, see sample_step(t) below). (Sample
// steps of 8 or 16 throughout gained less on the big scenes and cost more
// SAH.) The chunks of a team's node start at multiples of 64 records from
// its first, so a step divides them.
inline constexpr uint32_t kSampleStep = 4;
inline constexpr uint32_t kSampleMaxStep = 32;
inline constexpr uint32_t kSampleTarget = 1024;
inline uint32_t sample_step(uint32_t n) {
    uint32_t s = kSampleStep;
    while (s < kSampleMaxStep && n / (2 * s) >= kSampleTarget) s *= 2;
    return s;
}
// A node holding a primitive whose box has at least 1/kSampleLargePrim of
// the node's half area keeps every fourth record whatever its size: a few
// large primitives (a room's walls, a cathedral's floor) weigh on the SAH of
// every split far beyond their number, and a sparse sample that misses
// them picks the axis from the small ones. With the step by size alone,
// `gen:room:1000000` went from 12.9996 to 13.2428 (+1.9%; no sample at all
// gives 12.9988) and Sibenik to 26.61 (+2.3%; 27.11 and 27.39 at 64 and
// 128 bins, against 26.50 and 26.56); with this rule both trees are the
// ones every fourth record gave, at every bin count, from 1/16 to 1/1024
// (1/8 left Sibenik at 26.52). The sphere, stadium and random scenes and
// the dragon keep the sparse sample's trees; 1M random triangles build in
// 0.998x the time (sequential; 1/64: 1.033x, its deeper nodes' larger
// triangles counting as large).
inline constexpr double kSampleLargePrim = 32.0;
inline uint32_t sample_step(const NodeTask& t) {
    if (double(t.max_area) * kSampleLargePrim >= t.bounds.half_area()) return kSampleStep;
    return sample_step(t.size());
}

namespace detail {
template <uint32_t S>
inline void bin_sample(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& out) {
    constexpr uint32_t span = S * kBinBlock;
    BinArrays& odd = out.second(m.bins, m.valid);
    int axes[3] = {0, 0, 0}, na = 0;
    for (int a = 0; a < 3; ++a)
        if (m.valid[a]) axes[na++] = a;
    for (uint32_t b0 = begin; b0 < end; b0 += span) {
        const uint32_t e = static_cast<uint32_t>(std::min<uint64_t>(end, uint64_t(b0) + span));
        const uint32_t q = (e - b0 + S - 1) / S;
        const Strided<S> r{refs + b0};
        block_indices<false>(r, q, m, out.index);
        if (na == 3)
            merged_updates(out, odd, r, out.index, q);
        else
            alternate_updates<2>(out, odd, r, out.index, q, axes);
    }
    out.merge(odd, m.bins, m.valid);
}
}  // namespace detail

// Step 1 on the sample: bins records begin, begin + step, ... below end
// into `out` (accumulating); `step` is sample_step(t) of the node. A team's
// chunks start at multiples of the step from the node's first record, so
// their samples are the node's.
inline void bin_sample(const PrimRef* refs, uint32_t begin, uint32_t end, uint32_t step, const BinMapper& m,
                       BinSet& out) {
    static_assert(kSampleStep == 4 && kSampleMaxStep == 32 && kBinBlock % kSampleMaxStep == 0);
    switch (step) {
    case 4: return detail::bin_sample<4>(refs, begin, end, m, out);
    case 8: return detail::bin_sample<8>(refs, begin, end, m, out);
    case 16: return detail::bin_sample<16>(refs, begin, end, m, out);
    default: assert(step == 32); return detail::bin_sample<32>(refs, begin, end, m, out);
    }
}

// The best split found by evaluate() (or by the size split, see below).
struct Split {
    static constexpr int kSizeAxis = 3;  // a size split, not a plane
    int axis = -1;        // -1: no split exists
    uint32_t index = 0;   // bins [0, index) go left, [index, bins) right
    double cost = 0.0;    // C_t + C_i * (A_L n_L + A_R n_R) / A
    uint32_t left_count = 0;
    float size_cut = 0.0f;  // size split: area < size_cut goes left
    bool found() const { return axis >= 0; }
    bool by_size() const { return axis == kSizeAxis; }
};

// The area measure of the SAH. When the node's box has zero half area (all
// primitives on a line), the half area cannot rank splits, and the sum of
// extents is used instead.
inline double area_measure(const Box& b, bool use_length) {
    if (b.is_empty()) return 0.0;
    return use_length ? b.extent(0) + b.extent(1) + b.extent(2) : b.half_area();
}

// A node's SAH measure (simd::Measure: the half area, or the sum of extents
// for a node of zero area) and the cost of a split from its A_L n_L + A_R n_R
// in that measure: C_t + C_i * sum / A. Not `valid` when the node's own
// measure is zero: no split can be costed then (no split is found).
struct NodeCosts {
    simd::Measure measure;
    double inv_parent = 0.0;
    bool valid = false;
    [[gnu::always_inline]] explicit NodeCosts(const Box& node) : measure(node, !(node.half_area() > 0.0)) {
        const float parent = measure(simd::Box4::of(node));
        valid = parent > 0.0f;
        // Taken first, the division runs beside the sweeps instead of after them.
        if (valid) inv_parent = 1.0 / double(parent);
    }
    double cost(float sum, const BuildOptions& opt) const {
        return double(opt.traversal_cost) + double(opt.intersection_cost) * double(sum) * inv_parent;
    }
};

// Step 2: evaluate the bins-1 partitions on every valid axis by a suffix
// sweep (right areas) and a prefix sweep (left areas). Ties go to the lowest
// axis, then the lowest split index.
namespace detail {
// The sweeps for m.bins bins, or for exactly Fixed bins (Fixed > 0): the
// same operations in the same order, with loops of a known trip count that
// the compiler unrolls and whose sweep values stay in registers.
//
// Counts convert to float with the signed conversion, exact below 2^31. A
// node of 2^31 primitives or more (Huge) needs the unsigned one; that is
// found after the sweeps, from the node's count (the sweep's total), and the
// sweeps are then run again with it. (Summing the counts first, to choose
// before sweeping, was about 1% of the cow's build instructions.)
//
// The result is written into `best` field by field (set to Split{} first), not
// returned: a Split returned through memory was copied in 16-byte pieces
// across fields stored one by one, which cannot forward from store to load.
// Returns true for a node of 2^31 primitives or more seen with the signed
// conversion (`best` is then no split).
template <uint32_t Fixed, bool Huge>
bool evaluate_sweeps(const BinSet& bins, const BinMapper& m, const Box& node_bounds, const BuildOptions& opt,
                     Split& best) {
    best = Split{};
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    const uint32_t nb = Fixed ? Fixed : m.bins;
    // The three axes are swept together, one lane each (lane 3 unused).
    // Bin b's counts as one vector: with packed counts gathered from the
    // bins' lanes 3 (BinArrays::count_row()), otherwise transposed four bins
    // at a time (clear() zeroes counts in groups of four, so a group past the
    // last bin reads zeros).
    static_assert(kMaxBins % 4 == 0 && (Fixed % 4 == 0));
    __m128i count_rows[Fixed ? Fixed : kMaxBins];
#if CANOPY_PACKED_COUNTS
    for (uint32_t b = 0; b < nb; ++b) count_rows[b] = bins.count_row(b);
#else
    for (uint32_t b = 0; b < nb; b += 4) {
        const auto row = [&](int a) {
            return _mm_castsi128_ps(
                _mm_loadu_si128(reinterpret_cast<const __m128i*>(bins.counts + size_t(a) * bins.stride + b)));
        };
        __m128 x = row(0), y = row(1), z = row(2), w = _mm_setzero_ps();
        _MM_TRANSPOSE4_PS(x, y, z, w);
        count_rows[b] = _mm_castps_si128(x);
        count_rows[b + 1] = _mm_castps_si128(y);
        count_rows[b + 2] = _mm_castps_si128(z);
        count_rows[b + 3] = _mm_castps_si128(w);
    }
#endif
    const auto counts = [&](uint32_t b) { return count_rows[b]; };
    const __m128i zero = _mm_setzero_si128();
    const auto to_float = [](__m128i c) { return Huge ? simd::to_float(c) : _mm_cvtepi32_ps(c); };
    __m128 right_cost[Fixed ? Fixed : kMaxBins];  // A_R n_R of the split before bin b; -1: empty
    // The sweeps' boxes start as empty bins. With packed counts their lane 3
    // starts at 0, so that the minimum with the bins' counts (small integers,
    // as floats subnormal) stays 0: Measure then computes with no subnormal.
    const simd::MinBox empty = BinArrays::empty();
    const BinArrays::Axes ax = bins.axes();
    simd::MinBox acc[3] = {empty, empty, empty};
    __m128i n = zero;
    for (uint32_t b = nb - 1; b > 0; --b) {
        for (int a = 0; a < 3; ++a) acc[a].grow(ax.a[a][b]);
        n = _mm_add_epi32(n, counts(b));
        const __m128 empty = _mm_castsi128_ps(_mm_cmpeq_epi32(n, zero));
        const __m128 cost = _mm_mul_ps(measure.three(acc), to_float(n));
        right_cost[b] = simd::select(empty, _mm_set1_ps(-1.0f), cost);
    }
    if constexpr (!Huge) {
        // Every lane's total is the node's count (or 0 on an axis not binned).
        if (_mm_movemask_ps(_mm_castsi128_ps(_mm_add_epi32(n, counts(0)))) != 0) {
            return true;
        }
    }
    const __m128 valid = _mm_castsi128_ps(
        _mm_set_epi32(0, m.valid[2] ? -1 : 0, m.valid[1] ? -1 : 0, m.valid[0] ? -1 : 0));
    __m128 best_sum = simd::pos_inf();  // per axis: A_L n_L + A_R n_R of its best split
    __m128 found = _mm_setzero_ps();
    __m128i best_index = zero, best_left = zero;
    for (int a = 0; a < 3; ++a) acc[a] = empty;
    n = zero;
    for (uint32_t s = 1; s < nb; ++s) {
        for (int a = 0; a < 3; ++a) acc[a].grow(ax.a[a][s - 1]);
        n = _mm_add_epi32(n, counts(s - 1));
        const __m128 sum = _mm_add_ps(_mm_mul_ps(measure.three(acc), to_float(n)), right_cost[s]);
        // A candidate: a valid axis, both sides non-empty, and strictly
        // better than the axis's best so far (the lowest index wins ties).
        const __m128 left_empty = _mm_castsi128_ps(_mm_cmpeq_epi32(n, zero));
        const __m128 ok = _mm_andnot_ps(left_empty, _mm_and_ps(valid, _mm_cmpge_ps(right_cost[s], _mm_setzero_ps())));
        const __m128 take = _mm_and_ps(ok, _mm_or_ps(_mm_andnot_ps(found, ok), _mm_cmplt_ps(sum, best_sum)));
        const __m128i takei = _mm_castps_si128(take);
        best_sum = simd::select(take, sum, best_sum);
        best_index = simd::select(takei, _mm_set1_epi32(int32_t(s)), best_index);
        best_left = simd::select(takei, n, best_left);
        found = _mm_or_ps(found, take);
    }
    // Across axes: the lowest cost, the lowest axis on a tie (the sums are
    // finite: measures of at most 3 times counts).
    if (_mm_movemask_ps(found) == 0) return false;
    const __m128 sums = simd::select(found, best_sum, simd::pos_inf());
    __m128 low = _mm_min_ps(sums, _mm_shuffle_ps(sums, sums, _MM_SHUFFLE(2, 3, 0, 1)));
    low = _mm_min_ps(low, _mm_shuffle_ps(low, low, _MM_SHUFFLE(1, 0, 3, 2)));  // the minimum in every lane
    const int a = std::countr_zero(unsigned(_mm_movemask_ps(_mm_and_ps(found, _mm_cmpeq_ps(sums, low)))));
    alignas(16) int32_t idx[4], left[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(idx), best_index);
    _mm_store_si128(reinterpret_cast<__m128i*>(left), best_left);
    best.axis = a;
    best.index = uint32_t(idx[a]);
    best.left_count = uint32_t(left[a]);
    best.cost = costs.cost(_mm_cvtss_f32(low), opt);
    return false;
}
// The sweeps with the signed count conversion, again with the unsigned one
// for a node of 2^31 primitives or more.
template <uint32_t Fixed>
[[gnu::always_inline]] inline Split evaluate_fixed(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                                                   const BuildOptions& opt) {
    Split s;
    if (evaluate_sweeps<Fixed, false>(bins, m, node_bounds, opt, s))
        evaluate_sweeps<Fixed, true>(bins, m, node_bounds, opt, s);
    return s;
}
}  // namespace detail

// Nodes of up to 64 primitives, almost all of the nodes evaluated, have 4,
// 8 or 16 bins (bins_for()), and those of up to 16 primitives (4 bins; up
// to 32 since 2026-12-05) were 4/5 of the evaluations of a 1M sphere: for
// these bin counts the sweeps have a fixed trip count. (The 4-bin case
// with partition_binned(): the sequential build took 0.97x as long on the
// 1M sphere and 0.95x on dragon_vrip_res2, medians of 8 alternated runs, 6%
// fewer instructions.)
[[gnu::always_inline]] inline Split evaluate(const BinSet& bins, const BinMapper& m, const Box& node_bounds,
                                             const BuildOptions& opt) {
    switch (m.bins) {
        case 4: return detail::evaluate_fixed<4>(bins, m, node_bounds, opt);
        case 8: return detail::evaluate_fixed<8>(bins, m, node_bounds, opt);
        case 16: return detail::evaluate_fixed<16>(bins, m, node_bounds, opt);
        default: return detail::evaluate_fixed<0>(bins, m, node_bounds, opt);
    }
}

// Nodes of 4 bins (5 to 32 primitives with the default 32 bins, most of the
// nodes evaluated) binned and evaluated in registers where AVX-512 is
// compiled in: bin() and evaluate() for them, the same Split (axis, index,
// left count and cost, bit for bit) and the same index rows left in
// `bins.index` for partition_binned(); the bins themselves are not written.
//
// The twelve bins (4 on each axis) are the lanes a * 4 + b of seven 16-lane
// vectors, one per component: lo x, y, z, hi x, y, z and the count. A record
// updates its three lanes with masked minima and maxima of its broadcast
// components (exact: the same boxes as the bins' minima of (lo, -hi), as the
// records hold no -0 and no NaN; see simd::MinBox). The sweeps are then
// prefix and suffix minima within each group of four lanes, and the costs
// are formed lane for lane with the float operations of evaluate_sweeps()
// and simd::Measure::three(): negated extents lo * s + (-hi * s) (written
// lo * s - hi * s, the same IEEE result), then (x y + y z) + z x, or the
// negated sum (x + y) + z for lengths; A_L n_L + A_R n_R. The cheapest
// candidate wins, ties to the lowest lane, that is the lowest axis and then
// the lowest index, as evaluate_sweeps() chooses.
#if defined(__AVX512F__) && defined(__AVX512VL__)
#define CANOPY_REGISTER_BINS 1
// Lane i of the result: lane idx[i] of v. (The masked form, with v as the
// source of lanes not taken, as all are: the unmasked intrinsics start from
// an undefined vector, which GCC 12 warns about as maybe uninitialized.)
inline __m512 permute(__m512i idx, __m512 v) { return _mm512_mask_permutexvar_ps(v, 0xFFFF, idx, v); }
inline __m512i permute(__m512i idx, __m512i v) { return _mm512_mask_permutexvar_epi32(v, 0xFFFF, idx, v); }
inline __m512 to_float(__m512i v) { return _mm512_mask_cvtepi32_ps(_mm512_castsi512_ps(v), 0xFFFF, v); }
// The least of the lanes of `ok` in every lane (+inf when none).
inline __m512 min_of(__m512 v, __mmask16 ok) {
    const auto step = [](__m512 x, __m512i idx) { return _mm512_mask_min_ps(x, 0xFFFF, x, permute(idx, x)); };
    v = _mm512_mask_mov_ps(_mm512_set1_ps(std::numeric_limits<float>::infinity()), ok, v);
    v = step(v, _mm512_setr_epi32(8, 9, 10, 11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5, 6, 7));
    v = step(v, _mm512_setr_epi32(4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11));
    v = step(v, _mm512_setr_epi32(2, 3, 0, 1, 6, 7, 4, 5, 10, 11, 8, 9, 14, 15, 12, 13));
    return step(v, _mm512_setr_epi32(1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10, 13, 12, 15, 14));
}
// Boxes as the lanes of six 16-lane vectors, one per component: lo x, y, z
// (minima) and hi x, y, z (maxima); empty to begin with.
struct LaneBoxes {
    __m512 lo[3], hi[3];
    LaneBoxes() {
        const __m512 inf = _mm512_set1_ps(std::numeric_limits<float>::infinity());
        const __m512 ninf = _mm512_sub_ps(_mm512_setzero_ps(), inf);
        for (int c = 0; c < 3; ++c) {
            lo[c] = inf;
            hi[c] = ninf;
        }
    }
    // Grows the boxes of the lanes of `in` by record x's box (exact: the
    // boxes the bins' minima of (lo, -hi) hold, as the records hold no -0
    // and no NaN; see simd::MinBox).
    void add(const PrimRef& x, __mmask16 in) {
        for (int c = 0; c < 3; ++c) {
            lo[c] = _mm512_mask_min_ps(lo[c], in, lo[c], _mm512_set1_ps((&x.lo.x)[c]));
            hi[c] = _mm512_mask_max_ps(hi[c], in, hi[c], _mm512_set1_ps((&x.hi.x)[c]));
        }
    }
    // The measure of every lane's box with the float operations of
    // simd::Measure::three(): negated extents lo * s + (-hi * s) (written
    // lo * s - hi * s, the same IEEE result), then (x y + y z) + z x, or the
    // negated sum (x + y) + z for lengths.
    __m512 measure(const simd::Measure& m) const {
        const __m512 s = _mm512_set1_ps(_mm_cvtss_f32(m.scale));
        const auto neg_extent = [&](int c) { return _mm512_sub_ps(_mm512_mul_ps(lo[c], s), _mm512_mul_ps(hi[c], s)); };
        const __m512 x = neg_extent(0), y = neg_extent(1), z = neg_extent(2);
        if (m.use_length)  // negated by its sign bit, as simd::negate()
            return _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(_mm512_add_ps(_mm512_add_ps(x, y), z)),
                                                        _mm512_set1_epi32(std::numeric_limits<int32_t>::min())));
        return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(x, y), _mm512_mul_ps(y, z)), _mm512_mul_ps(z, x));
    }
};

inline Split bin_evaluate_4(const PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, BinSet& bins,
                            const Box& node_bounds, const BuildOptions& opt) {
    assert(m.bins == 4 && !m.prescaled && end - begin <= kBinBlock);
    const uint32_t n = std::min(end - begin, kBinBlock);
    const PrimRef* r = refs + begin;
    int32_t (*k)[4] = bins.index;
    detail::block_indices<false>(r, n, m, k);

    LaneBoxes bin;
    __m512i count = _mm512_setzero_si512();
    const __m512i one = _mm512_set1_epi32(1);
    // Lane a * 4 + b is bin b of axis a; lanes 12 to 15 match no index.
    const __m512i lane_bin = _mm512_setr_epi32(0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, -1, -1, -1, -1);
    // A record's index row (lanes 0 to 3 of its 128 bits) spread so that
    // lane a * 4 + b holds its index on axis a.
    const __m512i spread = _mm512_setr_epi32(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3);
    for (uint32_t i = 0; i < n; ++i) {
        const __m512i row = _mm512_castsi128_si512(_mm_load_si128(reinterpret_cast<const __m128i*>(k[i])));
        const __mmask16 in = _mm512_cmpeq_epi32_mask(permute(spread, row), lane_bin);
        bin.add(r[i], in);
        count = _mm512_mask_add_epi32(count, in, count, one);
    }

    Split best;
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return best;
    const simd::Measure& measure = costs.measure;

    // Inclusive prefix (bins 0..b) and suffix (bins b..3) within each axis's
    // four lanes, in two steps each.
    const __m512i back1 = _mm512_setr_epi32(0, 0, 1, 2, 4, 4, 5, 6, 8, 8, 9, 10, 12, 12, 13, 14);
    const __m512i back2 = _mm512_setr_epi32(0, 1, 0, 1, 4, 5, 4, 5, 8, 9, 8, 9, 12, 13, 12, 13);
    const __m512i ahead1 = _mm512_setr_epi32(1, 2, 3, 3, 5, 6, 7, 7, 9, 10, 11, 11, 13, 14, 15, 15);
    const __m512i ahead2 = _mm512_setr_epi32(2, 3, 2, 3, 6, 7, 6, 7, 10, 11, 10, 11, 14, 15, 14, 15);
    constexpr __mmask16 b_ge1 = 0xEEEE, b_ge2 = 0xCCCC, b_le2 = 0x7777, b_le1 = 0x3333;
    const auto vmin = [](__m512 v, __mmask16 k, __m512 w) { return _mm512_mask_min_ps(v, k, v, w); };
    const auto vmax = [](__m512 v, __mmask16 k, __m512 w) { return _mm512_mask_max_ps(v, k, v, w); };
    // Two steps of op, from the lanes one and then two bins back (or ahead).
    const auto sweep = [&](__m512 v, auto op, bool back) {
        v = op(v, back ? b_ge1 : b_le2, permute(back ? back1 : ahead1, v));
        return op(v, back ? b_ge2 : b_le1, permute(back ? back2 : ahead2, v));
    };
    // Candidate a * 4 + j (j = 1..3: bins [0, j) left): its left side is the
    // prefix of lane a * 4 + j - 1, its right side the suffix of its own lane.
    LaneBoxes left, right;
    for (int c = 0; c < 3; ++c) {
        left.lo[c] = permute(back1, sweep(bin.lo[c], vmin, true));
        left.hi[c] = permute(back1, sweep(bin.hi[c], vmax, true));
        right.lo[c] = sweep(bin.lo[c], vmin, false);
        right.hi[c] = sweep(bin.hi[c], vmax, false);
    }
    const __m512 left_measure = left.measure(measure), right_measure = right.measure(measure);
    __m512i left_count = _mm512_mask_add_epi32(count, b_ge1, count, permute(back1, count));
    left_count = _mm512_mask_add_epi32(left_count, b_ge2, left_count, permute(back2, left_count));
    left_count = permute(back1, left_count);
    __m512i right_count = _mm512_mask_add_epi32(count, b_le2, count, permute(ahead1, count));
    right_count = _mm512_mask_add_epi32(right_count, b_le1, right_count, permute(ahead2, right_count));
    const __m512 sum = _mm512_add_ps(_mm512_mul_ps(left_measure, to_float(left_count)),
                                     _mm512_mul_ps(right_measure, to_float(right_count)));
    // Candidates: split index 1 to 3 of a valid axis, both sides non-empty.
    const __mmask16 valid =
        __mmask16((m.valid[0] ? 0x000E : 0) | (m.valid[1] ? 0x00E0 : 0) | (m.valid[2] ? 0x0E00 : 0));
    const __m512i zero = _mm512_setzero_si512();
    const __mmask16 ok =
        _mm512_mask_cmpneq_epi32_mask(_mm512_mask_cmpneq_epi32_mask(valid, left_count, zero), right_count, zero);
    if (ok == 0) return best;
    const __m512 low = min_of(sum, ok);
    const uint32_t lane = uint32_t(std::countr_zero(unsigned(_mm512_mask_cmpeq_ps_mask(ok, sum, low))));
    alignas(64) int32_t lefts[16];
    _mm512_store_si512(lefts, left_count);
    best.axis = int(lane / 4);
    best.index = lane % 4;
    best.left_count = uint32_t(lefts[lane]);
    best.cost = costs.cost(_mm512_cvtss_f32(low), opt);
    return best;
}
#else
#define CANOPY_REGISTER_BINS 0
#endif

// The size split. Binning orders primitives by where their centroids are. A
// node holding a few primitives far larger than the rest (a room's walls and
// light around a detailed object, as in the Cornell box scenes) is often best
// split by size instead: the large primitives in one child, all others in the
// other. Their centroids lie among the small ones', so no plane between bins
// separates them, at any bin count (CBcoil was 22% above the exact sweep at
// 32 bins, 15% at 256).
//
// A node is offered this split when it has at least kSizeSplitMinPrims
// primitives and its largest primitive box has at least a quarter of the
// node's half area (NodeTask::max_area, which the partitions carry down at no
// cost). One extra pass then sorts its primitives into three classes by area
// (at least half the node's, at least a quarter, smaller), and the two cuts
// between the classes are costed with the same SAH as the planes; the
// cheapest of the best plane and the cuts wins, the plane on a tie. On
// ordinary meshes the condition holds only in small nodes, where the pass is
// short. Like binning, the classes depend only on the primitives, so every
// scheduler makes the same choice.
inline constexpr uint32_t kSizeSplitMinPrims = 16;

struct SizeCuts {
    float half = 0.0f, quarter = 0.0f;  // float(A / 2), float(A / 4), at most the largest float

    static SizeCuts of(const Box& node) {
        const double a = node.half_area();
        const double top = double(std::numeric_limits<float>::max());
        SizeCuts c;
        if (!(a > 0.0)) return c;
        c.half = static_cast<float>(std::min(a / 2.0, top));
        c.quarter = static_cast<float>(std::min(a / 4.0, top));
        return c;
    }
    bool applies(const NodeTask& t) const {
        return t.size() >= kSizeSplitMinPrims && quarter > 0.0f && t.max_area >= quarter;
    }
    // 0: area >= half, 1: quarter <= area < half, 2: smaller.
    uint32_t size_class(float area) const { return uint32_t(area < half) + uint32_t(area < quarter); }
};

// Per size class: the box of the primitives and their count.
struct SizeBins {
    simd::Box4 box[3];
    uint32_t count[3] = {0, 0, 0};
    void merge(const SizeBins& o) {  // exact, order-independent
        for (int k = 0; k < 3; ++k) {
            box[k].grow(o.box[k]);
            count[k] += o.count[k];
        }
    }
};

// Sorts refs[b, e) into size classes, accumulating into `out`.
inline void bin_sizes(const PrimRef* refs, uint32_t b, uint32_t e, const SizeCuts& cuts, SizeBins& out) {
    for (uint32_t i = b; i < e; ++i) {
        const uint32_t k = cuts.size_class(refs[i].area);
        out.box[k].grow(simd::lo(refs[i]), simd::hi(refs[i]));
        ++out.count[k];
    }
}

// Replaces `best` by the cheaper cut between size classes, if one is cheaper
// (or `best` found no split). Cut c sends classes below c (the large
// primitives) right.
inline void consider_size_split(const SizeBins& sb, const SizeCuts& cuts, const Box& node_bounds,
                                const BuildOptions& opt, Split& best) {
    const double area = node_bounds.half_area();
    if (!(area > 0.0)) return;
    for (uint32_t c = 1; c < 3; ++c) {
        simd::Box4 left, right;
        uint32_t nl = 0, nr = 0;
        for (uint32_t k = 0; k < 3; ++k) {
            if (k < c) {
                right.grow(sb.box[k]);
                nr += sb.count[k];
            } else {
                left.grow(sb.box[k]);
                nl += sb.count[k];
            }
        }
        if (nl == 0 || nr == 0) continue;
        const double cost = double(opt.traversal_cost) +
                            double(opt.intersection_cost) *
                                (left.box().half_area() * nl + right.box().half_area() * nr) / area;
        // Taken only when cheaper beyond rounding: the planes' costs are
        // computed in scaled float, and a cut that forms the same two sets
        // as a plane must not win on rounding alone.
        if (best.found() && !(cost < best.cost * (1.0 - 0x1p-12))) continue;
        best = Split{};
        best.axis = Split::kSizeAxis;
        best.cost = cost;
        best.left_count = nl;
        best.size_cut = c == 1 ? cuts.half : cuts.quarter;
    }
}

// The largest area a box grown with simd::hi_area() has seen (0 if none).
inline float max_area_of(const simd::Box4& b) { return std::max(0.0f, simd::lane3(b.hi)); }

// Child bounds, centroid bounds and largest areas, accumulated while
// partitioning. `hi_area` is simd::hi_area() of the record.
struct ChildBounds4 {
    simd::Box4 bounds[2], cbounds[2];  // [0] left, [1] right
    void add(int side, __m128 lo, __m128 hi_area, __m128 c) {
        bounds[side].grow(lo, hi_area);
        cbounds[side].grow(c, c);
    }
    void merge(const ChildBounds4& o) {
        for (int k = 0; k < 2; ++k) {
            bounds[k].grow(o.bounds[k]);
            cbounds[k].grow(o.cbounds[k]);
        }
    }
};

// What a partition (or a middle split) leaves: where the right child starts,
// and both children's bounds and centroid bounds, accumulated on the way.
// Kept as the accumulators' vectors until emit() writes the children: a
// partition returns this through memory, and vectors stored and loaded
// whole forward from store to load, where boxes of three-float corners
// copied in 16-byte pieces did not (a stall after every partition).
struct PartitionResult {
    ChildBounds4 acc;
    uint32_t mid = 0;

    Box left_bounds() const { return acc.bounds[0].box(); }
    Box right_bounds() const { return acc.bounds[1].box(); }
    Box left_cbounds() const { return acc.cbounds[0].box(); }
    Box right_cbounds() const { return acc.cbounds[1].box(); }
    float left_max_area() const { return max_area_of(acc.bounds[0]); }
    float right_max_area() const { return max_area_of(acc.bounds[1]); }
    void merge(const PartitionResult& o) { acc.merge(o.acc); }  // for blocked partitions
};

// The bin index of a centroid coordinate on one axis never decreases as the
// coordinate grows (a subtraction, two multiplications by positive numbers,
// a clamp and a truncation, each monotone in IEEE arithmetic). So the
// centroids below split index k on an axis are exactly those whose
// coordinate is below one float: the smallest float whose index is at
// least k. Found from an estimate by stepping to neighbouring floats with
// the mapping itself, or, should the estimate be far off, by a bisection
// over the floats in their order.
inline float split_threshold(const BinMapper& m, int axis, uint32_t k) {
    const auto index = [&](float c) {
        Vec3 v = m.origin;
        v[axis] = c;
        return m.index(v, axis);
    };
    // Floats in their order as unsigned integers (-0 just below +0), and
    // back: neighbouring floats are neighbouring keys.
    const auto key = [](float f) {
        const uint32_t u = std::bit_cast<uint32_t>(f);
        return (u >> 31) ? ~u : (u | 0x80000000u);
    };
    const auto from_key = [](uint32_t q) { return std::bit_cast<float>((q >> 31) ? (q & 0x7FFFFFFFu) : ~q); };
    constexpr float kMax = std::numeric_limits<float>::max();
    const double step = double(m.scale[axis]) * double(m.prescale[axis]);
    const double estimate = double(m.origin[axis]) + double(k) / step;
    if (std::abs(estimate) < double(kMax)) {
        uint32_t q = key(static_cast<float>(estimate));
        for (int i = 0; i < 8; ++i) {
            if (index(from_key(q)) < k) {
                ++q;
            } else if (index(from_key(q - 1)) >= k) {
                --q;
            } else {
                return from_key(q);
            }
        }
    }
    // Bisection over the finite floats.
    uint32_t lo = key(-kMax), hi = key(kMax);
    while (lo < hi) {  // the smallest key in [lo, hi] whose float has index >= k
        const uint32_t mid = lo + (hi - lo) / 2;
        if (index(from_key(mid)) >= k)
            hi = mid;
        else
            lo = mid + 1;
    }
    return from_key(lo);
}

// The side test of a plane split in registers: the centroid's bin indices on
// all axes compared with the split index at once, the split axis's lane
// taken from the sign mask (no trip through memory). Pre: the mapping's
// prescale is applied (needed only when m.prescaled, see BinMapper).
template <bool Pre = true>
struct SideIndexTest {
    const BinMapper& m;
    __m128i index4;
    int axis;
    SideIndexTest(const BinMapper& mapper, const Split& s)
        : m(mapper), index4(_mm_set1_epi32(int32_t(s.index))), axis(s.axis) {}
    bool left(__m128 c, __m128 /*hi_area*/) const {
        const __m128i lt = _mm_cmplt_epi32(m.template indices4<Pre>(c), index4);
        return (_mm_movemask_ps(_mm_castsi128_ps(lt)) >> axis) & 1;
    }
#if defined(__AVX2__)
    // left() of eight records, from their centroids' coordinates on the
    // split axis (the same operations on that lane): bit k for c[k].
    uint32_t left8(__m256 c) const {
        const auto lane = [&](__m128 v) { return _mm256_set1_ps(simd::lane(v, axis)); };
        __m256 f = _mm256_sub_ps(c, lane(m.origin4));
        if constexpr (Pre) f = _mm256_mul_ps(f, lane(m.prescale4));
        f = _mm256_mul_ps(f, lane(m.scale4));
        f = _mm256_min_ps(_mm256_max_ps(f, _mm256_setzero_ps()), lane(m.last4));
        const __m256i lt = _mm256_cmpgt_epi32(_mm256_set1_epi32(_mm_cvtsi128_si32(index4)), _mm256_cvttps_epi32(f));
        return uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(lt)));
    }
#endif
};

// The same side as SideIndexTest, found by comparing the centroid's
// coordinate on the split axis with split_threshold(): one comparison
// instead of the index computation, for a few steps of the mapping per
// node, so partition() uses it from kThresholdTestMin records on. Measured
// (sequential, alternated runs, medians of 5 to 7): 1M sphere 0.96x to 0.98x
// as long, dragon_vrip_res2 the same within noise (used from 65 records
// on, it was 1.03x on the dragon, which has many mid-sized nodes).
inline constexpr uint32_t kThresholdTestMin = 256;
struct SideTest {
    __m128 threshold4;
    int axis;
    SideTest(const BinMapper& m, const Split& s)
        : threshold4(_mm_set1_ps(split_threshold(m, s.axis, s.index))), axis(s.axis) {}
    bool left(__m128 c, __m128 /*hi_area*/) const {
        return (_mm_movemask_ps(_mm_cmplt_ps(c, threshold4)) >> axis) & 1;
    }
#if defined(__AVX2__)
    uint32_t left8(__m256 c) const {
        return uint32_t(_mm256_movemask_ps(_mm256_cmp_ps(c, _mm256_set1_ps(_mm_cvtss_f32(threshold4)), _CMP_LT_OQ)));
    }
#endif
};

// The side of a plane split read from the bin keys bin() wrote (keys[i]
// for refs[i]): the split axis's byte compared with the split index. The
// same indices as evaluate() counted, so the same sides as SideIndexTest
// and SideTest. Eight records a step from 32 bytes of keys, where SideTest
// gathers the split axis's coordinates from 512 bytes of records and forms
// their centroids. A partition by keys (partition_by_keys(), and the
// team-parallel node's) reads no record but the misplaced ones it swaps:
// the children's bounds come from the bins (bounds_from_bins()).
// run_node() and the team-parallel node keep the keys in the permutation's
// slots of the node's range (free until the node's leaves write them).
struct KeyTest {
    const uint32_t* keys;
    const PrimRef* refs;
    uint32_t shift;  // 8 * the split axis
    uint32_t index;
    KeyTest(const uint32_t* k, const PrimRef* r, const Split& s)
        : keys(k), refs(r), shift(8 * uint32_t(s.axis)), index(s.index) {}
    bool left_at(const uint32_t* q) const { return ((*q >> shift) & 0xFFu) < index; }
};

// The side test of a size split: primitives whose area is below the cut go
// left, the large ones right.
struct SizeTest {
    __m128 cut4;
    explicit SizeTest(const Split& s) : cut4(_mm_set1_ps(s.size_cut)) {}
    bool left(__m128 /*c*/, __m128 hi_area) const {
        return (_mm_movemask_ps(_mm_cmplt_ps(hi_area, cut4)) >> 3) & 1;
    }
};

// Calls f with the split's side test (one dispatch per node, not per record).
// With keys (bin() wrote them for refs), a plane split's sides are read from
// them (KeyTest, which grows no bounds: the caller takes the children's
// bounds from the bins).
template <class F>
decltype(auto) with_side_test(const BinMapper& m, const Split& s, const uint32_t* keys, const PrimRef* refs,
                              F&& f) {
    if (s.by_size()) return f(SizeTest(s));
    if (keys) return f(KeyTest(keys, refs, s));
    return f(SideTest(m, s));
}
// Without keys. (Not a call of the one above with null keys: that would
// instantiate f for KeyTest too, which callers like goes_left() cannot take.)
template <class F>
decltype(auto) with_side_test(const BinMapper& m, const Split& s, F&& f) {
    if (s.by_size()) return f(SizeTest(s));
    return f(SideTest(m, s));
}

inline bool goes_left(const PrimRef& r, const BinMapper& m, const Split& s) {
    return with_side_test(m, s, [&](const auto& side) {
        return side.left(simd::centroid(simd::lo(r), simd::hi(r)), simd::hi_area(r));
    });
}

// Step 3: the partition, in place. With mid = begin + the split's
// left_count, the records of [begin, mid) that go right and the records of
// [mid, end) that go left are equally many; the k-th of the first (in
// position order) trades places with the k-th of the second, and every other
// record stays where it is. Child bounds are accumulated in the same pass.
// The result depends only on which side each record goes to, not on the
// order in which the sides are found, so a team-parallel node reproduces it
// bit for bit from side bits found by chunks (see mark_sides() and
// swap_misplaced() below).
//
// In place, the records need one buffer: until 2026-12-02 the partition was
// the stable one, written to a second buffer of the same size (32 more bytes
// per primitive at the peak of a build). In alternated sequential runs the
// in-place version took the same time on the 1M sphere and up to 3% longer
// on `dragon_vrip_res2` and the bunny; it writes only the misplaced records.
//
// Sides are found 64 records at a time, as a bit mask, without a branch; the
// child bounds are then grown over the mask's set bits and over its clear
// bits, and the misplaced pairs swapped. A branch per record on its side,
// as the first version had, mispredicts wherever neighbouring records go
// different ways: on `dragon_vrip_res2` an estimated 15% of the build went
// to them, and the mask made the sequential build 0.81x as long (bunny
// 0.77x, 1M random triangles 0.71x; the 1M sphere 1.02x).
inline constexpr uint32_t kSideBlock = 64;

// Bit k set: record r[k] goes left (n <= kSideBlock). No branch. With
// KeyTest from the records' keys, eight at a time (the records are not read).
//
// With AVX2, a whole block of a plane split takes the split axis's
// coordinates of eight records at a time (their lo and hi lanes loaded into
// one vector each), forms those centroid coordinates with the operations of
// simd::centroid() and tests eight at once (left8). Against one record's
// full centroid per step (warm sequential builds, alternated pairs, medians
// of 9): dragon_vrip_res2 0.984x as long. Gathers instead of the loads were
// slower (1M sphere 1.036x).
template <class Test>
uint64_t left_mask(const PrimRef* r, uint32_t n, const Test& side) {
    if constexpr (std::is_same_v<Test, KeyTest>) {
        const uint32_t* q = side.keys + (r - side.refs);
        uint64_t mask = 0;
        uint32_t k = 0;
#if defined(__AVX2__)
        const __m128i shift = _mm_cvtsi32_si128(int(side.shift));
        const __m256i byte = _mm256_set1_epi32(0xFF), index = _mm256_set1_epi32(int32_t(side.index));
        for (; k + 8 <= n; k += 8) {
            const __m256i v = _mm256_and_si256(
                _mm256_srl_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(q + k)), shift), byte);
            mask |= uint64_t(uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(index, v))))) << k;
        }
#endif
        for (; k < n; ++k) mask |= uint64_t(side.left_at(q + k)) << k;
        return mask;
    } else {
#if defined(__AVX2__)
        if constexpr (!std::is_same_v<Test, SizeTest>) {
            if (n == kSideBlock) {
                const __m256 half = _mm256_set1_ps(0.5f);
                const float* base = &r[0].lo.x + side.axis;
                uint64_t mask = 0;
                for (uint32_t j = 0; j < kSideBlock / 8; ++j) {
                    const float* q = base + 64 * j;
                    const __m256 lo = _mm256_setr_ps(q[0], q[8], q[16], q[24], q[32], q[40], q[48], q[56]);
                    const __m256 hi = _mm256_setr_ps(q[4], q[12], q[20], q[28], q[36], q[44], q[52], q[60]);
                    const __m256 c = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(lo, half), _mm256_mul_ps(hi, half)),
                                                   _mm256_setzero_ps());
                    mask |= uint64_t(side.left8(c)) << (8 * j);
                }
                return mask;
            }
        }
#endif
        uint64_t mask = 0;
        for (uint32_t k = 0; k < n; ++k)
            mask |= uint64_t(side.left(simd::centroid(simd::lo(r[k]), simd::hi(r[k])), simd::hi_area(r[k]))) << k;
        return mask;
    }
}
inline uint64_t block_bits(uint32_t n) { return n >= 64 ? ~uint64_t(0) : (uint64_t(1) << n) - 1; }

// Grows side `Side` of `acc` (a constant side, so the accumulators stay in
// registers) with the records of block r whose bits are set.
//
// Every other record goes into a second pair of accumulators, merged at the
// end, so that each minimum and maximum waits on the one two records back,
// not on the previous one. The result is the same bits: minima and maxima
// do not depend on order here (the records hold no NaN, and prepare made
// every -0 +0). Warm sequential builds, alternated pairs, medians of 7:
// 1M sphere 0.979x as long, dragon_vrip_res2 0.980x.
//
// With AVX2, two records at a time: each record is one 256-bit load (lo, id,
// hi, area), two records' lo halves and hi halves are paired into one
// vector each, and one minimum or maximum grows both records' boxes and
// centroid boxes (lane for lane the operations of simd::centroid(), so the
// same bits; the halves are folded at the end). About 7 vector operations
// a record instead of 12. bench/ab/run.sh on the Intel Xeon host of
// 2026-12-04, against the loop below (9 rounds of 5 warm sequential builds,
// two runs): 1M sphere 0.955x as long, 1M stadium 0.97x, 1M random 0.97x,
// dragon_vrip_res2 0.965x and 0.98x, the cow 0.99x. (An AVX-512 version,
// two records per 512-bit vector with masked minima, took 1.00x-1.04x as long
// on the AMD EPYC host on 2026-12-04 morning; this one was not measured
// there.)
template <int Side>
inline void grow_side(const PrimRef* r, uint64_t bits, ChildBounds4& acc) {
    const auto one = [&](const PrimRef& x, ChildBounds4& into) {
        const __m128 lo = simd::lo(x);
        into.add(Side, lo, simd::hi_area(x), simd::centroid(lo, simd::hi(x)));
    };
#if defined(__AVX2__)
    const __m256 keep = simd::xyz_mask2();
    __m256 bmin = _mm256_set1_ps(std::numeric_limits<float>::infinity());
    __m256 bmax = _mm256_set1_ps(-std::numeric_limits<float>::infinity());
    __m256 cmin = bmin, cmax = bmax;
    for (; bits & (bits - 1); bits &= bits - 1) {
        const __m256 va = _mm256_load_ps(&r[std::countr_zero(bits)].lo.x);
        bits &= bits - 1;
        const __m256 vb = _mm256_load_ps(&r[std::countr_zero(bits)].lo.x);
        const __m256 lo2 = _mm256_and_ps(_mm256_permute2f128_ps(va, vb, 0x20), keep);  // (lo a, lo b)
        const __m256 ha2 = _mm256_permute2f128_ps(va, vb, 0x31);                        // (hi a, hi b), areas
        const __m256 c2 = simd::centroid2(lo2, _mm256_and_ps(ha2, keep));
        bmin = _mm256_min_ps(bmin, lo2);
        bmax = _mm256_max_ps(bmax, ha2);
        cmin = _mm256_min_ps(cmin, c2);
        cmax = _mm256_max_ps(cmax, c2);
    }
    if (bits) one(r[std::countr_zero(bits)], acc);
    const auto lo128 = [](__m256 v) { return _mm256_castps256_ps128(v); };
    const auto hi128 = [](__m256 v) { return _mm256_extractf128_ps(v, 1); };
    acc.bounds[Side].grow(_mm_min_ps(lo128(bmin), hi128(bmin)), _mm_max_ps(lo128(bmax), hi128(bmax)));
    acc.cbounds[Side].grow(_mm_min_ps(lo128(cmin), hi128(cmin)), _mm_max_ps(lo128(cmax), hi128(cmax)));
#else
    ChildBounds4 second;
    for (; bits; bits &= bits - 1) {
        one(r[std::countr_zero(bits)], acc);
        bits &= bits - 1;
        if (!bits) break;
        one(r[std::countr_zero(bits)], second);
    }
    acc.merge(second);
#endif
}

// The side mask of a block of n <= kSideBlock records, with their bounds
// grown into the side each goes to.
// (KeyTest: the mask alone, see there.)
template <class Test>
inline uint64_t mark_block(const PrimRef* r, uint32_t n, const Test& side, ChildBounds4& acc) {
    if constexpr (std::is_same_v<Test, KeyTest>) {
        return left_mask(r, n, side);
    } else {
        const uint64_t left = left_mask(r, n, side);
        grow_side<0>(r, left, acc);
        grow_side<1>(r, ~left & block_bits(n), acc);
        return left;
    }
}

inline void swap_refs(PrimRef& a, PrimRef& b) {
    const __m128 a0 = _mm_load_ps(&a.lo.x), a1 = _mm_load_ps(&a.hi.x);
    const __m128 b0 = _mm_load_ps(&b.lo.x), b1 = _mm_load_ps(&b.hi.x);
    _mm_store_ps(&a.lo.x, b0);
    _mm_store_ps(&a.hi.x, b1);
    _mm_store_ps(&b.lo.x, a0);
    _mm_store_ps(&b.hi.x, a1);
}

inline PartitionResult result_of(const ChildBounds4& acc, uint32_t mid) { return PartitionResult{acc, mid}; }

// The partition of one block refs[b, e) (at most kSideBlock records) whose
// sides are `left`, with left part [b, mid): the left part is the mask's
// low bits.
inline PartitionResult partition_block(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e, uint64_t left) {
    ChildBounds4 acc;
    PrimRef* r = refs + b;
    grow_side<0>(r, left, acc);
    grow_side<1>(r, ~left & block_bits(e - b), acc);
    const uint64_t low = block_bits(mid - b);
    for (uint64_t mi = ~left & low, mj = left & ~low; mi; mi &= mi - 1, mj &= mj - 1)
        swap_refs(r[std::countr_zero(mi)], r[std::countr_zero(mj)]);
    return result_of(acc, mid);
}

// A keyed partition (KeyTest) reads a block's keys, not its records, and
// then swaps its misplaced records: nothing brings those records' lines in
// ahead of the swaps, and the lines of a big node are in no cache of this
// core when another core read them last (the team's binning of a node, or
// the parent's partition on another thread). In a 2-thread build of the 1M
// sphere (the "AMD EPYC" host, 2026-12-05) the root's partition by halves
// took 1.6 to 1.7 ms where the same partition on one thread right after its
// own binning took 0.6; the same partition run a second time in place took
// 0.55. So the partitions of such nodes ask for the lines of the block
// kPrefetchBlocks ahead, to write: the team's partition by halves always,
// and in a parallel build (KernelContext::shared) every node of
// kPrefetchMin records or more (smaller ones are mostly in this core's
// caches: every keyed partition prefetching made the sequential 1M sphere
// 1.011x as long, those of kPrefetchMin and more 1.003x to 1.006x). The
// root's partition then took 1.3 ms.
inline constexpr uint32_t kPrefetchBlocks = 2;
inline constexpr uint32_t kPrefetchMin = 1u << 16;
inline void prefetch_for_write(const PrimRef* refs, uint32_t n) {
    for (uint32_t k = 0; k < n; k += 2) __builtin_prefetch(refs + k, 1, 3);  // two records a line
}
// The block kPrefetchBlocks ahead of a walk over blocks of kSideBlock
// records, when whole inside it: going up, the next block starting at
// `next` and the walk ending at `end`; going down, the next block ending at
// `next_end` and the walk starting at `begin`.
inline constexpr uint32_t kPrefetchAhead = (kPrefetchBlocks - 1) * kSideBlock;
inline void prefetch_up(const PrimRef* refs, uint32_t next, uint32_t end) {
    if (next + kPrefetchAhead + kSideBlock <= end) prefetch_for_write(refs + next + kPrefetchAhead, kSideBlock);
}
inline void prefetch_down(const PrimRef* refs, uint32_t next_end, uint32_t begin) {
    if (next_end >= begin + kPrefetchAhead + kSideBlock)
        prefetch_for_write(refs + next_end - kPrefetchAhead - kSideBlock, kSideBlock);
}

// The partition loop over refs[b, e) with left part [b, mid).
template <class Test>
PartitionResult partition_with(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e, const Test& side,
                               bool shared = false) {
    // One block (most nodes): one mask.
    if (e - b <= kSideBlock) return partition_block(refs, b, mid, e, left_mask(refs + b, e - b, side));
    ChildBounds4 acc;
    // A cursor in each part, i in [b, mid) and j in [mid, e), each with the
    // misplaced records of its current block as bits (mi: going right, mj:
    // going left); pairs are swapped in order while both have some.
    uint32_t i = b, j = mid;
    uint64_t mi = 0, mj = 0;
    const bool prefetch = std::is_same_v<Test, KeyTest> && shared && e - b >= kPrefetchMin;
    PrimRef* ri = refs + b;
    PrimRef* rj = refs + mid;
    for (;;) {
        if (!mi) {
            if (i >= mid) break;
            const uint32_t n = std::min(kSideBlock, mid - i);
            ri = refs + i;
            mi = ~mark_block(ri, n, side, acc) & block_bits(n);
            i += n;
            if (prefetch) prefetch_up(refs, i, mid);
        }
        if (!mj) {
            if (j >= e) break;
            const uint32_t n = std::min(kSideBlock, e - j);
            rj = refs + j;
            mj = mark_block(rj, n, side, acc);
            j += n;
            if (prefetch) prefetch_up(refs, j, e);
        }
        for (; mi && mj; mi &= mi - 1, mj &= mj - 1) swap_refs(ri[std::countr_zero(mi)], rj[std::countr_zero(mj)]);
    }
    // What is left of either part has no misplaced record: bounds only.
    for (; i < mid; i += kSideBlock) mark_block(refs + i, std::min(kSideBlock, mid - i), side, acc);
    for (; j < e; j += kSideBlock) mark_block(refs + j, std::min(kSideBlock, e - j), side, acc);
    return result_of(acc, mid);
}

// Size splits are rare; their loop stays out of line, so that the plane
// partition inlines into run_node.
[[gnu::noinline]] inline PartitionResult partition_by_size(PrimRef* refs, uint32_t b, uint32_t mid, uint32_t e,
                                                           const Split& s) {
    return partition_with(refs, b, mid, e, SizeTest(s));
}

inline PartitionResult partition(PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, const Split& s) {
    const uint32_t mid = begin + s.left_count;
    if (s.by_size()) return partition_by_size(refs, begin, mid, end, s);
    if (end - begin < kThresholdTestMin)
        return m.prescaled ? partition_with(refs, begin, mid, end, SideIndexTest<true>(m, s))
                           : partition_with(refs, begin, mid, end, SideIndexTest<false>(m, s));
    return partition_with(refs, begin, mid, end, SideTest(m, s));
}

// The records of partition() of plane split s, the sides read from the keys
// bin() wrote (KeyTest): the result has the right child's start but no
// bounds (bounds_from_bins() gives them).
inline PartitionResult partition_by_keys(PrimRef* refs, uint32_t begin, uint32_t end, const Split& s,
                                         const uint32_t* keys, bool shared = false) {
    return partition_with(refs, begin, begin + s.left_count, end, KeyTest(keys, refs, s), shared);
}

// partition() of a plane split of a node of at most kBinBlock records right
// after bin() went over it: the sides are read from the bin indices bin()
// left in `bins.index` instead of being computed again from the centroids
// (the same indices, so the same sides and the same result).
inline PartitionResult partition_binned(PrimRef* refs, uint32_t begin, uint32_t end, const Split& s,
                                        const BinSet& bins) {
    static_assert(kBinBlock <= kSideBlock);
    assert(end - begin <= kBinBlock);
    const uint32_t n = std::min(end - begin, kBinBlock);  // for the compiler's bounds analysis
    uint64_t left = 0;
    for (uint32_t i = 0; i < n; ++i) left |= uint64_t(uint32_t(bins.index[i][s.axis]) < s.index) << i;
    return partition_block(refs, begin, begin + s.left_count, end, left);
}

// The partition of a node by a team, in two parallel passes (after binning):
//  1. mark_sides() over ranges of the node that start at multiples of 64
//     records from its begin, in any order: each range's side bits (bit
//     i - begin of `sides` set: record i goes left; whole words, zero past
//     the range's end) and its share of the child bounds (merged exactly);
//  2. plan_swaps() (one thread, a popcount walk over the words) cuts the
//     misplaced pairs into pieces by rank, and swap_misplaced() swaps one
//     piece's pairs; pieces touch disjoint records, in any order.
// The pairs are the ones partition() swaps, so the records end the same.
inline PartitionResult mark_sides(const PrimRef* refs, uint32_t b, uint32_t e, uint32_t node_begin,
                                  const BinMapper& m, const Split& s, uint64_t* sides,
                                  const uint32_t* keys = nullptr) {
    return with_side_test(m, s, keys, refs, [&](const auto& side) {
        ChildBounds4 acc;
        for (uint32_t i = b; i < e; i += kSideBlock)
            sides[(i - node_begin) / kSideBlock] = mark_block(refs + i, std::min(kSideBlock, e - i), side, acc);
        return result_of(acc, 0);
    });
}

// The partition of a node by two threads, each reading half of the records
// once (a team of two or three; see ParallelNode). The same pairs as
// partition(): with M misplaced records in each part, the k-th going right
// in [b, mid) trades places with the k-th going left in [mid, e). The front
// half (side 0) pairs ranks upward from 0 over [b, ql) and [mid, qr), in
// position order as partition() does; the back half (side 1) pairs ranks
// downward from M - 1 over [ql, mid) and [qr, e), walking its blocks from
// the end and taking the highest bits first. A half whose two parts held
// unequal numbers of misplaced records (a and a', a > a') keeps a - a' of
// them unpaired in one part: ranks a'..a-1 of that part. The other half
// then keeps the same ranks of the other part (the counts of both parts sum
// to M), so the leftovers of the two halves pair with each other, rank for
// rank, in swap_leftovers(). Child bounds are grown as the records are read
// and merged exactly, as in mark_sides().
struct HalfLeftovers {
    // Unpaired misplaced records, ascending rank: blocks as (first record,
    // bits relative to it).
    std::vector<std::pair<uint32_t, uint64_t>> blocks;
    uint32_t count = 0;

    void clear() {
        blocks.clear();
        count = 0;
    }
    void add(uint32_t first, uint64_t bits) {
        if (!bits) return;
        blocks.push_back({first, bits});
        count += uint32_t(std::popcount(bits));
    }
};

// One part's share in partition_half(): its blocks of up to kSideBlock
// records, read from lo up (side 0) or from hi down (side 1), each leaving
// its misplaced records as bits.
template <int Side>
struct HalfCursor {
    uint32_t lo, hi;
    uint32_t at = Side == 0 ? lo : hi;  // the next block's bound
    uint32_t first = 0;                 // the current block's first record
    uint64_t bits = 0;                  // its misplaced records not yet paired
    // Reads the next block (false when none is left); `right_part`: the
    // misplaced records are those going left, else those going right.
    template <class Test>
    bool next(const PrimRef* refs, const Test& side, ChildBounds4& acc, bool right_part) {
        if (Side == 0 ? at >= hi : at <= lo) return false;
        const uint32_t n = std::min(kSideBlock, Side == 0 ? hi - at : at - lo);
        first = Side == 0 ? at : at - n;
        const uint64_t left = mark_block(refs + first, n, side, acc);
        bits = right_part ? left : ~left & block_bits(n);
        at = Side == 0 ? at + n : at - n;
        if constexpr (std::is_same_v<Test, KeyTest>) {
            // (see prefetch_for_write(): a team's node is one whose lines
            // the other cores read last)
            if constexpr (Side == 0)
                prefetch_up(refs, at, hi);
            else
                prefetch_down(refs, at, lo);
        }
        return true;
    }
    // The next pair's bit: the lowest going up, the highest going down.
    uint32_t take() {
        const uint32_t k = Side == 0 ? uint32_t(std::countr_zero(bits)) : 63u - uint32_t(std::countl_zero(bits));
        bits &= ~(uint64_t(1) << k);
        return first + k;
    }
};

// Side 0: [b, ql) and [mid, qr); side 1: [ql, mid) and [qr, e).
template <int Side, class Test>
PartitionResult partition_half(PrimRef* refs, uint32_t b, uint32_t ql, uint32_t mid, uint32_t qr, uint32_t e,
                               const Test& side, HalfLeftovers& left_over) {
    ChildBounds4 acc;
    left_over.clear();
    HalfCursor<Side> li{Side == 0 ? b : ql, Side == 0 ? ql : mid};   // going right in the left part
    HalfCursor<Side> rj{Side == 0 ? mid : qr, Side == 0 ? qr : e};   // going left in the right part
    for (;;) {
        if (!li.bits && !li.next(refs, side, acc, false)) break;
        if (!rj.bits && !rj.next(refs, side, acc, true)) break;
        while (li.bits && rj.bits) swap_refs(refs[li.take()], refs[rj.take()]);
    }
    // At most one part has misplaced records left: its pending block and
    // the blocks not read yet (the other part's are all read).
    left_over.add(li.first, li.bits);
    while (li.next(refs, side, acc, false)) left_over.add(li.first, li.bits);
    left_over.add(rj.first, rj.bits);
    while (rj.next(refs, side, acc, true)) left_over.add(rj.first, rj.bits);
    if (Side == 1) std::reverse(left_over.blocks.begin(), left_over.blocks.end());  // found from the highest rank down
    return result_of(acc, 0);
}

// Pairs the two halves' leftovers rank for rank (equally many).
inline void swap_leftovers(PrimRef* refs, const HalfLeftovers& front, const HalfLeftovers& back) {
    assert(front.count == back.count);
    size_t fb = 0, bb = 0;
    uint64_t fm = 0, bm = 0;
    for (uint32_t k = 0; k < front.count; ++k) {
        if (!fm) fm = front.blocks[fb++].second;
        if (!bm) bm = back.blocks[bb++].second;
        swap_refs(refs[front.blocks[fb - 1].first + uint32_t(std::countr_zero(fm))],
                  refs[back.blocks[bb - 1].first + uint32_t(std::countr_zero(bm))]);
        fm &= fm - 1;
        bm &= bm - 1;
    }
}

// One half of the two-ended partition of refs[begin, end) split at mid, with
// the split's side test; the halves' shares of the parts are cut at their
// middles.
template <int Side>
PartitionResult partition_half(PrimRef* refs, uint32_t begin, uint32_t end, const BinMapper& m, const Split& s,
                               HalfLeftovers& left_over, const uint32_t* keys = nullptr) {
    const uint32_t mid = begin + s.left_count;
    const uint32_t ql = begin + (mid - begin) / 2, qr = mid + (end - mid) / 2;
    return with_side_test(m, s, keys, refs, [&](const auto& side) {
        return partition_half<Side>(refs, begin, ql, mid, qr, end, side, left_over);
    });
}

// A run of misplaced pairs: the first pair's positions in the left part and
// in the right part, and how many pairs.
struct SwapPiece {
    uint32_t left_at = 0, right_at = 0, count = 0;
};

// Word w of the side bits with the bits equal to `want` set.
inline uint64_t side_word(const uint64_t* sides, uint32_t w, bool want) { return want ? sides[w] : ~sides[w]; }

// The first position at or after `at` whose side bit is `want` (one exists).
inline uint32_t next_side(const uint64_t* sides, uint32_t node_begin, uint32_t at, bool want) {
    uint32_t w = (at - node_begin) / 64;
    uint64_t bits = side_word(sides, w, want) & (~uint64_t(0) << ((at - node_begin) % 64));
    while (!bits) bits = side_word(sides, ++w, want);
    return node_begin + w * 64 + uint32_t(std::countr_zero(bits));
}

// Cuts the misplaced pairs of the node [begin, end) split at mid into
// pieces of `per_piece` pairs (the last may have fewer), in rank order.
inline void plan_swaps(const uint64_t* sides, uint32_t begin, uint32_t mid, uint32_t per_piece,
                       std::vector<SwapPiece>& pieces) {
    pieces.clear();
    // Finds the positions of increasing ranks among one part's `want` bits,
    // from word w on (first_mask: the bits of the part's first word that
    // belong to it).
    struct Walk {
        const uint64_t* sides;
        uint32_t begin;
        bool want;
        uint32_t w, first_word;
        uint64_t first_mask;
        uint32_t seen = 0;  // wanted bits before word w
        uint64_t bits(uint32_t k) const {
            const uint64_t v = side_word(sides, k, want);
            return k == first_word ? v & first_mask : v;
        }
        uint32_t find(uint32_t rank) {
            for (;; seen += uint32_t(std::popcount(bits(w))), ++w) {
                uint64_t v = bits(w);
                if (seen + uint32_t(std::popcount(v)) <= rank) continue;
                for (uint32_t r = rank - seen; r; --r) v &= v - 1;
                return begin + w * 64 + uint32_t(std::countr_zero(v));
            }
        }
    };
    const uint32_t nl = mid - begin;
    uint32_t stay = 0;  // left-going records in [begin, mid)
    for (uint32_t w = 0; w < nl / 64; ++w) stay += uint32_t(std::popcount(sides[w]));
    if (nl % 64) stay += uint32_t(std::popcount(sides[nl / 64] & block_bits(nl % 64)));
    const uint32_t misplaced = nl - stay;
    Walk left{sides, begin, false, 0, 0, ~uint64_t(0)};
    Walk right{sides, begin, true, nl / 64, nl / 64, ~block_bits(nl % 64)};
    for (uint32_t k = 0; k < misplaced; k += per_piece) {
        SwapPiece p;
        p.left_at = left.find(k);
        p.right_at = right.find(k);
        p.count = std::min(per_piece, misplaced - k);
        pieces.push_back(p);
    }
}

inline void swap_misplaced(PrimRef* refs, const uint64_t* sides, uint32_t node_begin, const SwapPiece& p) {
    uint32_t i = p.left_at, j = p.right_at;
    for (uint32_t c = 0; c < p.count; ++c, ++i, ++j) {
        i = next_side(sides, node_begin, i, false);
        j = next_side(sides, node_begin, j, true);
        swap_refs(refs[i], refs[j]);
    }
}

// Bounds of refs[b, e) as one side of a middle split.
inline void grow_range(const PrimRef* refs, uint32_t b, uint32_t e, ChildBounds4& acc, int side) {
    for (uint32_t i = b; i < e; ++i) {
        const __m128 lo = simd::lo(refs[i]);
        acc.add(side, lo, simd::hi_area(refs[i]), simd::centroid(lo, simd::hi(refs[i])));
    }
}

// The middle split: [begin, mid) and [mid, end) in their current order, for
// nodes with no SAH split and for the depth cap. Bounds by one pass.
inline PartitionResult middle_split(const PrimRef* refs, uint32_t begin, uint32_t end) {
    ChildBounds4 acc;
    const uint32_t mid = begin + (end - begin) / 2;
    grow_range(refs, begin, mid, acc, 0);
    grow_range(refs, mid, end, acc, 1);
    return result_of(acc, mid);
}

// After a partition by keys of node t by plane split s (mapping m), the
// children's bounds from the node's bins: each child's box and largest area
// from the bins of the split axis (bins [0, s.index) hold the left child's
// records, the others the right child's), bit for bit as a partition grows
// them from the records. Each child's centroid bounds are a box holding its
// centroids: its box, within the node's centroid bounds, and on the split
// axis within the child's non-empty bins there (widened by a margin above
// the mapping's roundings). Not the tight box of the centroids a partition
// grows, so the children's mappings differ by up to half a primitive's
// extent on the other axes, and by less than a bin width on the split axis;
// on the meshes of ../shared/scenes the trees' SAH moved by -0.19% to
// +0.12%. (Taking the children's bounds on the split axis as loosely as on
// the others, Šibenik's tree was 3.9% worse.) Should a centroid round
// outside, BinMapper clamps it into the first or last bin.
inline void bounds_from_bins(const BinArrays& bins, const BinMapper& m, const NodeTask& t, const Split& s,
                             PartitionResult& p) {
    const int axis = s.axis;
    simd::MinBox side[2] = {BinArrays::empty(), BinArrays::empty()};
    for (uint32_t b = 0; b < m.bins; ++b) side[b >= s.index].grow(bins.at(axis, b));
    Box c[2];
    for (int k = 0; k < 2; ++k) {
        p.acc.bounds[k] = side[k].box4();
        const Box b = p.acc.bounds[k].box();
        c[k] = Box{glm::max(b.lo, t.cbounds.lo), glm::min(b.hi, t.cbounds.hi)};
    }
    // The non-empty bins of each side: [first, lmax] left, [rmin, last]
    // right (both sides hold records).
    uint32_t first = 0, lmax = s.index - 1, rmin = s.index, last = m.bins - 1;
    while (bins.count(axis, first) == 0) ++first;
    while (bins.count(axis, lmax) == 0) --lmax;
    while (bins.count(axis, rmin) == 0) ++rmin;
    while (bins.count(axis, last) == 0) --last;
    const double w = 1.0 / double(m.scale[axis]);  // a bin's width
    const double o = double(m.origin[axis]);
    const double big = std::max(std::abs(o), std::abs(o + double(m.bins) * w));
    // Bins k..l span [o + k w, o + (l + 1) w], give or take the mapping's
    // roundings: a few float ulps of the coordinates and of the extent, well
    // inside `margin` where bins are wide against the coordinates (not
    // narrowed otherwise, nor for a prescaled mapping).
    if (m.prescale[axis] == 1.0f && w >= 0x1p-20 * big) {
        const double margin = 0x1p-21 * (big + double(m.bins) * w);
        const uint32_t from[2] = {first, rmin}, to[2] = {lmax, last};
        for (int k = 0; k < 2; ++k) {
            c[k].lo[axis] = std::max(c[k].lo[axis], float(o + double(from[k]) * w - margin));
            c[k].hi[axis] = std::min(c[k].hi[axis], float(o + double(to[k] + 1) * w + margin));
        }
    }
    for (int k = 0; k < 2; ++k) {
        for (int a = 0; a < 3; ++a)
            if (!(c[k].lo[a] <= c[k].hi[a])) {  // cannot happen while the boxes hold the centroids
                const Box b = p.acc.bounds[k].box();
                c[k].lo[a] = b.lo[a];
                c[k].hi[a] = b.hi[a];
            }
        p.acc.cbounds[k] = simd::Box4::of(c[k]);
    }
}

// Step 4: the two child tasks of a split node.
inline void emit(const NodeTask& t, const PartitionResult& p, NodeTask out[2]) {
    out[0].begin = t.begin;
    out[0].end = p.mid;
    out[0].bounds = p.left_bounds();
    out[0].cbounds = p.left_cbounds();
    out[1].begin = p.mid;
    out[1].end = t.end;
    out[1].bounds = p.right_bounds();
    out[1].cbounds = p.right_cbounds();
    out[0].max_area = p.left_max_area();
    out[1].max_area = p.right_max_area();
    for (int k = 0; k < 2; ++k) {
        out[k].depth = t.depth + 1;
        out[k].parent_begin = t.begin;
        out[k].is_right = k == 1;
        out[k].rights = static_cast<uint8_t>(t.rights + k);
    }
}

inline uint32_t ceil_log2(uint32_t n) { return n <= 1 ? 0 : 32 - std::countl_zero(n - 1); }

// What to do with a node before any binning.
enum class Plan { Leaf, Middle, Sah };

inline Plan plan(const NodeTask& t, const BuildOptions& opt, SkipCounts& skip) {
    const uint32_t n = t.size();
    if (n <= 1) {
        ++skip.single_leaves;
        return Plan::Leaf;
    }
    const uint32_t budget = opt.max_depth > t.depth ? opt.max_depth - t.depth : 0;
    if (budget <= ceil_log2(n)) {
        if (n <= opt.max_leaf) return Plan::Leaf;
        ++skip.depth_cap_splits;
        return Plan::Middle;
    }
    return Plan::Sah;
}

// The SAH verdict on a node that was binned and evaluated: leaf when the
// node fits in a leaf and no split is cheaper than intersecting everything.
inline bool sah_says_leaf(bool found, double cost, uint32_t n, const BuildOptions& opt) {
    if (n > opt.max_leaf) return false;
    return !found || cost >= double(opt.intersection_cost) * double(n);
}
inline bool sah_says_leaf(const Split& s, uint32_t n, const BuildOptions& opt) {
    return sah_says_leaf(s.found(), s.cost, n, opt);
}

// A node that fits in a leaf becomes one when no split is cheaper. Every
// split costs at least C_t + C_i * (sum of the primitives' own half areas) / A,
// because each side's box contains the boxes of its primitives
// (A_L n_L >= sum over the left primitives of their areas, and so on). When
// that lower bound already reaches the leaf's cost C_i * n, binning and
// evaluating would only confirm the leaf, so they are skipped: the tree is the
// same. The bound is taken with a relative margin of 2^-12, far above the
// rounding of the scaled float areas evaluate() compares (a few float ulps),
// and only for nodes whose area is not tiny against their squared extent
// (where those float areas are normal numbers); otherwise the node is
// evaluated as usual.
inline bool leaf_by_bound(const PrimRef* refs, const NodeTask& t, const BuildOptions& opt) {
    const double area = t.bounds.half_area();
    const double ext = std::max({t.bounds.extent(0), t.bounds.extent(1), t.bounds.extent(2)});
    if (!(area > ext * ext * 0x1p-40)) return false;
    // The records' stored areas (prim_area()): each within a float rounding
    // (2^-24, relative) of the box's exact half area, or below it (0 under
    // the smallest normal float, saturated at the largest), so the sum stays
    // a lower bound within the margin.
    double sum = 0.0;
    for (uint32_t i = t.begin; i < t.end; ++i) sum += double(refs[i].area);
    // C_t + C_i * (sum / A) * (1 - 2^-12) >= C_i * n, multiplied out by A > 0
    // (no division: its latency sat on the path to the node's next step).
    return double(opt.intersection_cost) * sum * (1.0 - 0x1p-12) >=
           (double(opt.intersection_cost) * double(t.size()) - double(opt.traversal_cost)) * area;
}

// Small nodes are split exactly. A node of at most kExactMaxPrims
// primitives that got past the bound above is not binned: every partition of
// its records into two non-empty sets is costed with the SAH, with the same
// measure as the bins' sweeps (simd::Measure, in the same float operations),
// and the cheapest wins. The planes between bins realise only some of those
// partitions, and the others are often cheaper (two walls and two small
// objects between them: no plane puts the walls together); the cost of a
// partition the bins also see is bit for bit the one evaluate() computes, so
// the exact choice is never worse than the binned one. Such nodes are 43% of
// the evaluations on `dragon_vrip_res2`, and most of them split (3 in 4): with
// 4 records there are 7 partitions, from the boxes of the 15 subsets of
// records, each one minimum of a smaller subset's box and one record's;
// cheaper than mapping, binning, sweeping and partitioning by bins.
// (Measured, sequential builds, instructions per build: the cow 10.85 ->
// 10.00 million, the dragon 460.0 -> 429.7 million. A first version of this
// code ran 10.07 and 432.0 at 4 records, 10.51 and 447.0 at 5, 11.31 and
// 472.1 at 6: the subsets double with each record.)
inline constexpr uint32_t kExactMaxPrims = 4;

// The cheapest split of the records r[0, n), 2 <= n <= kExactMaxPrims, inside
// `node_bounds`: `left` gets the bit mask (bit i: r[i]) of the set holding
// r[0], which becomes the left child, and `cost` the split's SAH cost (as
// Split::cost). Ties go to the lowest mask. False when the node's measure is
// zero, so that no split is cheaper than another (as evaluate() finds none).
inline bool exact_split_in_memory(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                                  uint32_t& left, double& cost) {
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    const uint32_t full = (1u << n) - 1;
    // sub[mask]: the box of the records in mask; sub[0] is empty.
    simd::MinBox sub[1u << kExactMaxPrims];
    for (uint32_t mask = 1; mask <= full; ++mask) {
        sub[mask] = sub[mask & (mask - 1)];
        sub[mask].grow(simd::MinBox::of(r[std::countr_zero(mask)]));
    }
    // measures[mask] for 0 < mask < full, three at a time (the last three
    // may run up to sub[full]; measures past it are not read).
    alignas(16) float measures[(1u << kExactMaxPrims) + 4] = {};
    for (uint32_t mask = 1; mask < full; mask += 3)
        _mm_storeu_ps(measures + mask, measure.three(sub[mask], sub[mask + 1], sub[mask + 2]));
    // Each partition once: the masks holding record 0 (odd), but the full one.
    float best = 0.0f;
    uint32_t best_mask = 0;
    for (uint32_t mask = 1; mask < full; mask += 2) {
        const uint32_t rest = full & ~mask;
        // A_L n_L + A_R n_R as evaluate() forms it (the sum is commutative).
        const float sum = measures[mask] * float(std::popcount(mask)) + measures[rest] * float(std::popcount(rest));
        if (best_mask == 0 || sum < best) {
            best = sum;
            best_mask = mask;
        }
    }
    left = best_mask;
    cost = costs.cost(best, opt);
    return true;
}

#if CANOPY_REGISTER_BINS
// exact_split() in AVX-512 registers: lane `mask` of LaneBoxes holds the
// box of the records in mask (record j grows the lanes whose number has bit
// j set: the constant lane masks 0xAAAA, 0xCCCC, 0xF0F0, 0xFF00), every
// lane's measure is formed with the float operations of
// simd::Measure::three(), and A_L n_L + A_R n_R as exact_split_in_memory()
// forms it (the rest's lane found by xor with the full mask); the cheapest
// odd mask below the full one wins, the lowest on a tie. The same result
// bit for bit.
inline bool exact_split_in_registers(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                                     uint32_t& left, double& cost) {
    assert(n >= 2 && n <= kExactMaxPrims);
    static_assert(kExactMaxPrims <= 4);
    const NodeCosts costs(node_bounds);
    if (!costs.valid) return false;
    const simd::Measure& measure = costs.measure;
    constexpr __mmask16 has[4] = {0xAAAA, 0xCCCC, 0xF0F0, 0xFF00};  // lanes whose mask holds record j
    LaneBoxes sub;
    for (uint32_t j = 0; j < n; ++j) sub.add(r[j], has[j]);
    const __m512 measures = sub.measure(measure);
    // measure * popcount per lane, and the same of the rest (lane full ^ mask).
    const __m512 counts = _mm512_setr_ps(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
    const __m512 weighted = _mm512_mul_ps(measures, counts);
    const uint32_t full = (1u << n) - 1;
    const __m512i rest = _mm512_xor_si512(_mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                                          _mm512_set1_epi32(int32_t(full)));
    const __m512 sum = _mm512_add_ps(weighted, permute(rest, weighted));
    const __mmask16 candidates = __mmask16(0xAAAA & ((1u << full) - 1));  // odd masks below full
    const __m512 low = min_of(sum, candidates);
    left = uint32_t(std::countr_zero(unsigned(_mm512_mask_cmpeq_ps_mask(candidates, sum, low))));
    cost = costs.cost(_mm512_cvtss_f32(low), opt);
    return true;
}
#endif

// The cheapest split of the records r[0, n), 2 <= n <= kExactMaxPrims: see
// exact_split_in_memory(); in registers where AVX-512 is compiled in, for
// nodes of 3 or 4 records (sequential builds, alternated, medians of 5 to 7
// rounds: 1M sphere 0.984x-0.986x as long, dragon_vrip_res2 0.970x-0.975x,
// 1M stadium 0.989x; for 2 records too, 1M random triangles took 1.019x:
// their single partition costs less in memory than 16 lanes).
inline bool exact_split(const PrimRef* r, uint32_t n, const Box& node_bounds, const BuildOptions& opt,
                        uint32_t& left, double& cost) {
#if CANOPY_REGISTER_BINS
    if (n >= 3) return exact_split_in_registers(r, n, node_bounds, opt, left, cost);
#endif
    return exact_split_in_memory(r, n, node_bounds, opt, left, cost);
}

// The partition of a small node by a mask from exact_split(): the records of
// the mask first, then the others, each in their earlier order; child bounds
// accumulated as partition() does (each side's records grown in the same
// order, so the same boxes). All records are loaded before any is stored,
// each as one 256-bit vector, and the accumulators are locals grown with
// blends: copied through an array first and grown through an indexed
// ChildBounds4, both stayed in memory, and a profile of the 1M sphere had
// 7% of the node task's samples on the reload after those stores.
#if defined(__AVX__)
inline PartitionResult partition_by_mask(PrimRef* refs, uint32_t begin, uint32_t end, uint32_t left) {
    const uint32_t n = end - begin;
    __m256 rec[kExactMaxPrims];
    for (uint32_t i = 0; i < n; ++i) rec[i] = _mm256_loadu_ps(&refs[begin + i].lo.x);
    const uint32_t mid = begin + uint32_t(std::popcount(left));
    uint32_t at_left = begin, at_right = mid;
    simd::Box4 b0, b1, c0, c1;
    const __m128 keep = simd::xyz_mask();
    for (uint32_t i = 0; i < n; ++i) {
        const uint32_t goes_left = (left >> i) & 1;
        _mm256_storeu_ps(&refs[goes_left ? at_left : at_right].lo.x, rec[i]);
        at_left += goes_left;
        at_right += goes_left ^ 1u;
        const __m128 lo = _mm_and_ps(_mm256_castps256_ps128(rec[i]), keep);
        const __m128 hi_area = _mm256_extractf128_ps(rec[i], 1);
        const __m128 c = simd::centroid(lo, _mm_and_ps(hi_area, keep));
        // All ones where the record goes left.
        const __m128 m = _mm_castsi128_ps(_mm_set1_epi32(-int32_t(goes_left)));
        const __m128 inf = simd::pos_inf(), ninf = simd::neg_inf();
        b0.grow(_mm_blendv_ps(inf, lo, m), _mm_blendv_ps(ninf, hi_area, m));
        c0.grow(_mm_blendv_ps(inf, c, m), _mm_blendv_ps(ninf, c, m));
        b1.grow(_mm_blendv_ps(lo, inf, m), _mm_blendv_ps(hi_area, ninf, m));
        c1.grow(_mm_blendv_ps(c, inf, m), _mm_blendv_ps(c, ninf, m));
    }
    PartitionResult r;
    r.acc.bounds[0] = b0;
    r.acc.bounds[1] = b1;
    r.acc.cbounds[0] = c0;
    r.acc.cbounds[1] = c1;
    r.mid = mid;
    return r;
}
#else
inline PartitionResult partition_by_mask(PrimRef* refs, uint32_t begin, uint32_t end, uint32_t left) {
    const uint32_t n = end - begin;
    PrimRef copy[kExactMaxPrims];
    std::copy(refs + begin, refs + end, copy);
    ChildBounds4 acc;
    uint32_t at = begin;
    for (int side = 0; side < 2; ++side)
        for (uint32_t i = 0; i < n; ++i) {
            if (((left >> i) & 1) == uint32_t(side)) continue;  // side 0 takes the mask's records
            const PrimRef& x = copy[i];
            const __m128 lo = simd::lo(x);
            acc.add(side, lo, simd::hi_area(x), simd::centroid(lo, simd::hi(x)));
            refs[at++] = x;
        }
    return PartitionResult{acc, begin + uint32_t(std::popcount(left))};
}
#endif

// From a node's sample binned into `sample`: m.only() the axis of its
// cheapest split, or `m` when it shows none (run_node() and a team's
// choose_axis() alike).
inline BinMapper mapper_from_sample(const BinSet& sample, const BinMapper& m, const Box& node_bounds,
                                    const BuildOptions& opt, SkipCounts& skip) {
    const Split guess = evaluate(sample, m, node_bounds, opt);
    if (!guess.found()) return m;
    ++skip.sampled_axes;
    return m.only(guess.axis);
}
// The mapping a node is binned with: `m` itself, or for a node that
// samples (samples_axis()) the one mapper_from_sample() gives.
inline BinMapper binning_mapper(const PrimRef* refs, const NodeTask& t, const BinMapper& m, BinSet& bins,
                                const BuildOptions& opt, SkipCounts& skip) {
    if (!samples_axis(m, t.size())) return m;
    bins.clear(m.bins);
    bin_sample(refs, t.begin, t.end, sample_step(t), m, bins);
    return mapper_from_sample(bins, m, t.bounds, opt, skip);
}

class TraceLog;

// Everything a node task needs besides its own range.
struct KernelContext {
    PrimRef* refs;           // the records, partitioned in place
    uint32_t* permutation;   // leaves write their ids here
    const BuildOptions* options;
    TraceLog* trace;         // null unless the build is traced (see trace.h)
    // Other threads work on the records too: a big node's lines may be in
    // other cores' caches (see prefetch_for_write()). Speed only.
    bool shared = false;
};

// Writes a leaf's primitive ids to the permutation.
inline void write_leaf(const KernelContext& ctx, const NodeTask& t) {
    for (uint32_t i = t.begin; i < t.end; ++i) ctx.permutation[i] = ctx.refs[i].id;
}

// The whole node task, sequentially: returns false for a leaf (whose ids it
// wrote to the permutation), true when it wrote two child tasks to
// `children`. `bins` is per-worker scratch.
inline bool run_node(const KernelContext& ctx, const NodeTask& t, NodeTask children[2],
                     BinSet& bins, SkipCounts& skip) {
    // Each split emits straight from the partition's result, which the
    // partition writes in place (no PartitionResult assigned across the
    // branches: GCC copied it with 64-byte moves, which cannot forward from
    // the partition's 16-byte stores, and emit()'s 4-byte loads then stalled
    // on the copy; about a tenth of run_node()'s own samples).
    const auto split = [&](const PartitionResult& part) {
        emit(t, part, children);
        return true;
    };
    const BuildOptions& opt = *ctx.options;
    const Plan p = plan(t, opt, skip);
    if (p == Plan::Middle) return split(middle_split(ctx.refs, t.begin, t.end));
    if (p != Plan::Sah) {
        write_leaf(ctx, t);
        return false;
    }
    if (t.size() <= opt.max_leaf && leaf_by_bound(ctx.refs, t, opt)) {
        ++skip.bound_leaves;
        write_leaf(ctx, t);
        return false;
    }
    if (t.size() <= kExactMaxPrims) {
        ++skip.exact_nodes;
        uint32_t left = 0;
        double cost = 0.0;
        const bool found = exact_split(ctx.refs + t.begin, t.size(), t.bounds, opt, left, cost);
        if (sah_says_leaf(found, cost, t.size(), opt)) {
            write_leaf(ctx, t);
            return false;
        }
        return found ? split(partition_by_mask(ctx.refs, t.begin, t.end, left))
                     : split(middle_split(ctx.refs, t.begin, t.end));
    }
    const BinMapper full = BinMapper::make(t.cbounds, bins_for(t.size(), opt.bins));
    if (!full.any_valid()) {
        ++skip.coincident_nodes;
        if (t.size() <= opt.max_leaf) {
            write_leaf(ctx, t);
            return false;
        }
        return split(middle_split(ctx.refs, t.begin, t.end));
    }
    skip.axes_not_binned += 3 - full.valid_count();
    assert(full.bins <= bins.max_bins());
    const BinMapper m = binning_mapper(ctx.refs, t, full, bins, opt, skip);
    // Nodes partitioned by their keys (larger than kBinBlock) get them in
    // the permutation's slots of their range, which only their leaves
    // write, later.
    uint32_t* const keys = t.size() > kBinBlock ? ctx.permutation : nullptr;
    Split s;
#if CANOPY_REGISTER_BINS
    if (m.bins == 4 && !m.prescaled && t.size() <= kBinBlock) {
        s = bin_evaluate_4(ctx.refs, t.begin, t.end, m, bins, t.bounds, opt);
    } else
#endif
    {
        bins.clear(m.bins);
        bin(ctx.refs, t.begin, t.end, m, bins, keys);
        s = evaluate(bins, m, t.bounds, opt);
    }
    if (t.size() >= kSizeSplitMinPrims) {
        const SizeCuts cuts = SizeCuts::of(t.bounds);
        if (cuts.applies(t)) {
            SizeBins sizes;
            bin_sizes(ctx.refs, t.begin, t.end, cuts, sizes);
            consider_size_split(sizes, cuts, t.bounds, opt, s);
            skip.size_splits += s.by_size();
        }
    }
    if (sah_says_leaf(s, t.size(), opt)) {
        write_leaf(ctx, t);
        return false;
    }
    if (!s.found()) return split(middle_split(ctx.refs, t.begin, t.end));
    if (s.by_size()) return split(partition(ctx.refs, t.begin, t.end, m, s));
    if (t.size() <= kBinBlock) return split(partition_binned(ctx.refs, t.begin, t.end, s, bins));
    PartitionResult part = partition_by_keys(ctx.refs, t.begin, t.end, s, keys, ctx.shared);
    bounds_from_bins(bins, m, t, s, part);
    return split(part);
}

}  // namespace canopy
