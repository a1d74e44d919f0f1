// canopy: COLLADA (.dae) and glTF (.gltf, .glb) scenes, read through Assimp.
#pragma once

#include "mesh.h"

#include <string>

namespace canopy {

// The scene's triangles, each placed mesh's positions transformed by its
// node's world transform; InputError naming the file and the mesh, node or
// vertex that is wrong.
TriangleMesh load_with_assimp(const std::string& path);

}  // namespace canopy
