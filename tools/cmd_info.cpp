// canopy info: describe a scene.
#include "cli.h"
#include "core/scene.h"

#include <cstdio>

namespace canopy::cli {

namespace {

int run_info(const std::string& spec) {
    Scene scene = spec.empty() ? default_scene() : load_scene(spec);
    const TriangleMesh& m = scene.mesh;
    Box b;
    for (const Vec3& v : m.vertices) b.extend(v);
    size_t degenerate = 0;
    for (size_t t = 0; t < m.triangle_count(); ++t) {
        const Vec3 e1 = m.vertex(t, 1) - m.vertex(t, 0), e2 = m.vertex(t, 2) - m.vertex(t, 0);
        const double cx = double(e1.y) * e2.z - double(e1.z) * e2.y;
        const double cy = double(e1.z) * e2.x - double(e1.x) * e2.z;
        const double cz = double(e1.x) * e2.y - double(e1.y) * e2.x;
        degenerate += (cx == 0.0 && cy == 0.0 && cz == 0.0);
    }
    std::printf("scene      %s\nformat     %s\n", scene.name.c_str(), scene.format.c_str());
    std::printf("triangles  %zu\nvertices   %zu\n", m.triangle_count(), m.vertices.size());
    std::printf("bounds     (%g, %g, %g) - (%g, %g, %g)\n", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
    std::printf("zero-area  %zu\nnon-finite 0 (loading rejects them)\n", degenerate);
    return kOk;
}

}  // namespace

Runner add_info(CLI::App& app) {
    auto scene = std::make_shared<std::string>();
    CLI::App* info = app.add_subcommand("info", "Describe a scene: counts, bounds, degenerate triangles");
    info->add_option("scene", *scene, "Mesh file (.obj .ply .off .dae .gltf .glb) or gen:NAME:COUNT[:SEED]");
    return [scene, info]() { return *info ? run_info(*scene) : -1; };
}

}  // namespace canopy::cli
