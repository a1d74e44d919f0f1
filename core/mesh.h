// canopy: the input of a build, as views over the caller's arrays.
#pragma once

#include "geometry.h"

#include <cstdint>
#include <span>
#include <vector>

namespace canopy {

// An indexed triangle mesh: triangle t has the vertices
// vertices[indices[3t]], vertices[indices[3t+1]], vertices[indices[3t+2]].
// The view does not own the arrays.
struct TriangleView {
    std::span<const Vec3> vertices;
    std::span<const uint32_t> indices;
    size_t triangle_count() const { return indices.size() / 3; }
};

// An owning mesh, as scene loaders and generators produce it.
struct TriangleMesh {
    std::vector<Vec3> vertices;
    std::vector<uint32_t> indices;

    size_t triangle_count() const { return indices.size() / 3; }
    TriangleView view() const { return {vertices, indices}; }
    Vec3 vertex(size_t tri, int corner) const { return vertices[indices[3 * tri + corner]]; }
};

}  // namespace canopy
