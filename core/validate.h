// canopy: structural validation of a BVH.
#pragma once

#include "bvh.h"
#include "mesh.h"
#include "options.h"

#include <span>
#include <string>
#include <vector>

namespace canopy {

// Everything found wrong with a tree; empty when the tree is valid. Checks:
// every primitive referenced exactly once; every node's box contains its
// children's boxes and its primitives' boxes (exact float comparisons, no
// epsilon); leaf sizes within options.max_leaf; depth within
// options.max_depth; the layout canonical (see bvh.h).
struct ValidationReport {
    std::vector<std::string> problems;
    bool ok() const { return problems.empty(); }
    std::string summary(size_t max_lines = 20) const;
};

ValidationReport validate(const Bvh& bvh, const TriangleView& mesh, const BuildOptions& options = {});
ValidationReport validate(const Bvh& bvh, std::span<const Box> boxes, const BuildOptions& options = {});

}  // namespace canopy
