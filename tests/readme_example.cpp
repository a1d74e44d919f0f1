// The README's library example, compiled and run as a test so that it cannot
// rot (tests/check_readme_example.sh checks that the README shows exactly
// the lines between the markers).
#include <cstdio>
// README-BEGIN
#include "core/scene.h"
#include "core/traversal.h"
#include "schedulers/registry.h"

int main() {
    canopy::TriangleMesh mesh = canopy::load_scene("gen:sphere:20000").mesh;
    canopy::BuildOptions options;  // 32 bins, leaves of at most 4, all threads
    canopy::Bvh bvh = canopy::build<canopy::Sequential>(mesh.view(), options);
    canopy::Ray ray{{0, 0, -5}, {0, 0, 1}};
    canopy::Hit hit = canopy::intersect_closest(bvh, mesh.view(), ray);
    std::printf("%zu nodes; hit triangle %u at t = %g\n", bvh.nodes.size(), hit.prim, hit.t);
    return hit.found() && hit.t > 3.9f && hit.t < 4.1f ? 0 : 1;
}
// README-END
