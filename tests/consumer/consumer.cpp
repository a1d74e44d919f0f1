// A tiny program built against an installed canopy through pkg-config.
#include <core/scene.h>  // installed under include/canopy; canopy.pc adds it
#include <schedulers/registry.h>

#include <cstdio>

int main() {
    const canopy::TriangleMesh mesh = canopy::generate("sphere", 5000, 1);
    const canopy::Bvh a = canopy::build<canopy::Sequential>(mesh.view());
    bool same = true;
    for (const canopy::SchedulerEntry& s : canopy::schedulers()) same = same && s.build_triangles(mesh.view()) == a;
    std::printf("consumer: %zu nodes, %zu schedulers agree: %s\n", a.nodes.size(), canopy::schedulers().size(),
                same ? "yes" : "no");
    return same ? 0 : 1;
}
