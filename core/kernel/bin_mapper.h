// canopy: the mapping of a centroid to its bin on each axis, the one
// mapping that binning and partitioning share.
#pragma once

#include "simd.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace canopy {

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

}  // namespace canopy
