// canopy: one node of a BVH (32 bytes; the layout is in core/bvh.h).
#pragma once

#include "geometry.h"

#include <cstdint>

namespace canopy {

struct Node {
    // Like a float, a default-constructed Node is uninitialised, `Node{}`
    // included: node arrays are grown (std::vector::resize, emplace_back)
    // and then written, and zero-filling them first was a serial pass over
    // fresh memory in every parallel build (resizing the final array took
    // 3.5 to 4.8 ms of a 2-thread 1M-sphere build). Set every field before
    // reading one.
    Node() noexcept {}  // user-provided on purpose: value-initialisation does not zero
    float min[3];
    float max[3];
    uint32_t index;  // inner: first child; leaf: first permutation slot
    uint32_t count;  // 0 for an inner node, primitive count for a leaf

    bool is_leaf() const { return count != 0; }
    Box box() const { return Box{Vec3(min[0], min[1], min[2]), Vec3(max[0], max[1], max[2])}; }
    void set_box(const Box& b) {
        for (int a = 0; a < 3; ++a) {
            min[a] = b.lo[a];
            max[a] = b.hi[a];
        }
    }
};
static_assert(sizeof(Node) == 32, "Node must be 32 bytes");

}  // namespace canopy
