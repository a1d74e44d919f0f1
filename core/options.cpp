#include "options.h"

#include "error.h"

#include <cmath>
#include <string>

namespace canopy {

void BuildOptions::check() const {
    if (bins < kMinBins || bins > kMaxBins)
        throw OptionError("bins must be between " + std::to_string(kMinBins) + " and " +
                          std::to_string(kMaxBins) + ", got " + std::to_string(bins));
    if (max_leaf < 1 || max_leaf > kMaxLeafSize)
        throw OptionError("max_leaf must be between 1 and " + std::to_string(kMaxLeafSize) + ", got " +
                          std::to_string(max_leaf));
    if (!(std::isfinite(traversal_cost) && traversal_cost >= 0.0f))
        throw OptionError("traversal_cost must be finite and non-negative");
    if (!(std::isfinite(intersection_cost) && intersection_cost > 0.0f))
        throw OptionError("intersection_cost must be finite and positive");
    if (max_depth < 1 || max_depth > kMaxDepthCap)
        throw OptionError("max_depth must be between 1 and " + std::to_string(kMaxDepthCap) + ", got " +
                          std::to_string(max_depth));
    if (rotate_min != 0 && rotate_min < kRotateMinPrims)
        throw OptionError("rotate_min must be 0 (no rotations) or at least " + std::to_string(kRotateMinPrims) +
                          ", got " + std::to_string(rotate_min));
    if (threads > 4096) throw OptionError("threads must be at most 4096, got " + std::to_string(threads));
}

}  // namespace canopy
