// A tiny program built against an installed canopy through pkg-config.
// Builds the scene named by its argument (a file or gen:NAME:COUNT[:SEED]),
// checks that every scheduler builds the same tree here, and prints the
// tree's hash, which check_install.sh compares with the canopy tool's: the
// inline kernel compiled in a consumer must build the trees the library's
// own build does.
#include <core/scene.h>  // installed under include/canopy; canopy.pc adds it
#include <schedulers/registry.h>

#include <cstdio>

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s SCENE\n", argv[0]);
        return 2;
    }
    const canopy::TriangleMesh mesh = canopy::load_scene(argv[1]).mesh;
    const canopy::Bvh a = canopy::build<canopy::Sequential>(mesh.view());
    bool same = true;
    for (const canopy::SchedulerEntry& s : canopy::schedulers()) same = same && s.build_triangles(mesh.view()) == a;
    std::printf("consumer: %zu nodes, %zu schedulers agree: %s\n", a.nodes.size(), canopy::schedulers().size(),
                same ? "yes" : "no");
    std::printf("tree_hash %s\n", canopy::tree_hash_hex(a).c_str());
    return same ? 0 : 1;
}
