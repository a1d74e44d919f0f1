// One side of bench/ab/run.sh: a source tree's builder behind two C
// functions, compiled with -Dcanopy=canopy_<side> so that two trees' kernels
// (same names, different code) live in one program. AB_SIDE is a or b.
#include "build.h"
#include "bvh.h"
#include "scene.h"
#include "sequential.h"

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <iostream>

#define AB_CAT2(x, y) x##y
#define AB_CAT(x, y) AB_CAT2(x, y)
#define AB_LOAD AB_CAT(ab_load_, AB_SIDE)
#define AB_RUN AB_CAT(ab_run_, AB_SIDE)

namespace {
canopy::Builder<canopy::Sequential> builder;
canopy::Bvh bvh;
}  // namespace

// Loads a scene (file or gen: spec) into malloc'd arrays; false on an error
// (printed).
extern "C" bool AB_LOAD(const char* spec, float** v, size_t* nv, uint32_t** idx, size_t* ni) {
    try {
        const canopy::Scene s = canopy::load_scene(spec);
        *nv = s.mesh.vertices.size();
        *ni = s.mesh.indices.size();
        *v = static_cast<float*>(std::malloc(*nv * 3 * sizeof(float) + 1));
        *idx = static_cast<uint32_t*>(std::malloc(*ni * sizeof(uint32_t) + 1));
        for (size_t i = 0; i < *nv; ++i)
            for (int k = 0; k < 3; ++k) (*v)[3 * i + k] = s.mesh.vertices[i][k];
        std::memcpy(*idx, s.mesh.indices.data(), *ni * sizeof(uint32_t));
        return true;
    } catch (const std::exception& e) {
        std::cerr << spec << ": " << e.what() << "\n";
        return false;
    }
}

// One sequential build with default options, warm (the builder keeps its
// memory) or cold; returns its milliseconds and the tree's hash.
extern "C" double AB_RUN(const float* v, size_t nv, const uint32_t* idx, size_t ni, bool warm, uint64_t* hash) {
    const canopy::TriangleView view{{reinterpret_cast<const glm::vec3*>(v), nv}, {idx, ni}};
    const auto t0 = std::chrono::steady_clock::now();
    if (warm)
        builder.build(view, bvh);
    else
        bvh = canopy::build<canopy::Sequential>(view);
    const auto t1 = std::chrono::steady_clock::now();
    *hash = canopy::tree_hash(bvh);
    return std::chrono::duration<double, std::milli>(t1 - t0).count();
}
