// canopy: scene input. Mesh files and seeded generators.
//
// A scene spec is either a file path or a generator spec
// "gen:NAME:COUNT[:SEED]" where COUNT is an approximate triangle count (the
// exact count depends on the generator's tessellation) and SEED a 64-bit
// integer (default 1). Generators:
//   sphere     a tessellated unit sphere (latitude/longitude grid)
//   random     small random triangles in the unit cube
//   stadium    a dense sphere inside a huge box of large triangles
//   plane      a planar grid (all z = 0)
//   coincident COUNT identical triangles
//   room       a dense sphere on the floor of a five-wall room of ten large
//              triangles (like the Cornell box scenes)
// Every loader throws InputError whose message starts with the file name and
// names the line or element that is wrong.
#pragma once

#include "mesh.h"

#include <cstdint>
#include <string>
#include <vector>

namespace canopy {

struct Scene {
    TriangleMesh mesh;
    std::string name;    // file name or generator spec
    std::string format;  // "obj", "generated", ...
};

bool is_generator_spec(const std::string& spec);
std::vector<std::string> generator_names();

// Loads a file (by extension) or runs a generator.
Scene load_scene(const std::string& spec);

// OBJ through tinyobjloader: polygons triangulated, positions only.
TriangleMesh load_obj(const std::string& path);

// Throws InputError for an unknown name or a zero / absurd count.
TriangleMesh generate(const std::string& name, uint64_t count, uint64_t seed = 1);

// Puts the triangles of `mesh` in a seeded random order (the vertices and
// each triangle's corners stay as they are): the same triangles, as a file
// written in no particular order would give them. For measuring how a
// builder's time depends on the input order (`canopy bench --shuffle`). A
// pure function of (mesh, seed): the permutation is a Fisher-Yates shuffle
// driven by std::mt19937_64, whose sequence the standard fixes.
void shuffle_triangles(TriangleMesh& mesh, uint64_t seed);

// The scene `canopy build` uses with no SCENE: gen:sphere:100000.
Scene default_scene();

// Throws InputError naming the first vertex with a non-finite coordinate or
// the first triangle with an index out of range, prefixed by `where`.
void check_mesh(const TriangleMesh& mesh, const std::string& where);

}  // namespace canopy
