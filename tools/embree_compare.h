// canopy tool: Embree 3 as the yardstick of `canopy bench` (compiled only
// when Meson found Embree; CANOPY_HAVE_EMBREE is then 1).
//
// Two Embree builds are measured, both on the device's thread count:
//  - the scene build: one triangle geometry over shared vertex and index
//    buffers, RTC_BUILD_QUALITY_MEDIUM, rtcCommitScene. Embree builds its own
//    wide BVH with its own leaves, so it has no SAH comparable to canopy's;
//  - the generic builder rtcBuildBVH (binned SAH, RTC_BUILD_QUALITY_MEDIUM)
//    over the triangle boxes, binary, leaves of 1..max_leaf primitives. Its
//    tree is converted into canopy's layout (outside the timing), so it can
//    be validated and its SAH computed with canopy's formula.
// Failures throw canopy::Error with Embree's message.
#pragma once

#include "core/bvh.h"
#include "core/mesh.h"

#include <cstdint>
#include <memory>
#include <string>

namespace canopy::embree {

// "3.13.5": the Embree version compiled against.
std::string version();

// rtcBuildBVH cannot make leaves larger than this.
inline constexpr uint32_t kMaxBuilderLeaf = 32;

// An Embree device created with the config "threads=T". With Embree's TBB
// tasking the limit is process-wide (a tbb::global_control), so keep one
// device alive at a time: a device with fewer threads would also throttle
// canopy's tbb scheduler.
class Device {
public:
    explicit Device(uint32_t threads);
    ~Device();
    Device(const Device&) = delete;
    Device& operator=(const Device&) = delete;

    uint32_t threads() const;
    struct Impl;
    Impl& impl() { return *impl_; }

private:
    std::unique_ptr<Impl> impl_;
};

// What both Embree builds read, prepared once per scene outside any timing:
// a copy of the vertices padded by one float4 (Embree's shared vertex
// buffers must be readable 16 bytes past the last vertex), and the triangle
// boxes as build primitives (rtcBuildBVH overwrites its primitive array, so
// every build starts from a fresh copy of them).
class Input {
public:
    explicit Input(const TriangleView& mesh);
    ~Input();
    Input(const Input&) = delete;
    Input& operator=(const Input&) = delete;

    size_t triangle_count() const;
    struct Impl;
    Impl& impl() { return *impl_; }

private:
    std::unique_ptr<Impl> impl_;
};

// (a) Milliseconds of rtcNewScene, geometry setup, rtcCommitGeometry,
// rtcAttachGeometry and rtcCommitScene; the scene is released after the
// timing.
double scene_build_ms(Device& device, Input& input);

// (b) Milliseconds of rtcBuildBVH alone (the primitive array is refilled
// before it, the BVH converted and released after it). When `tree` is not
// null it receives Embree's tree in canopy's canonical layout (boxes as
// Embree reported them, leaves' primitive ids as the permutation).
double builder_ms(Device& device, Input& input, uint32_t max_leaf, uint32_t max_depth, Bvh* tree);

}  // namespace canopy::embree
