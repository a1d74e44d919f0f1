// canopy: scene input: a spec is a generator spec (generators.cpp) or a file
// read by its extension (obj.cpp, ply.cpp, off.cpp, assimp_mesh.cpp).
#include "scene.h"

#include "assimp_mesh.h"
#include "error.h"
#include "generators.h"
#include "off.h"
#include "ply.h"
#include "reader_util.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <random>
#include <string_view>
#include <utility>

namespace canopy {
namespace {

using input::format_vec;
using input::is_finite;

constexpr const char* kDefaultSceneSpec = "gen:sphere:100000";

struct FileFormat {
    std::string_view extension;  // lower case, with the dot
    std::string_view format;     // Scene::format
    TriangleMesh (*load)(const std::string& path);
};

// To add a format, add a row here.
constexpr FileFormat kFileFormats[] = {
    {".obj", "obj", &load_obj},
    {".ply", "ply", &load_ply},
    {".dae", "dae", &load_with_assimp},
    {".gltf", "gltf", &load_with_assimp},
    {".glb", "glb", &load_with_assimp},
    {".off", "off", &load_off},
};

std::string lower(std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

std::string supported_extensions() {
    std::string list;
    for (const FileFormat& f : kFileFormats) {
        if (!list.empty()) list += ", ";
        list += f.extension;
    }
    return list;
}

}  // namespace

Scene load_scene(const std::string& spec) {
    if (is_generator_spec(spec)) return load_generator_spec(spec);
    const std::string ext = lower(std::filesystem::path(spec).extension().string());
    for (const FileFormat& f : kFileFormats) {
        if (ext == f.extension) return Scene{f.load(spec), spec, std::string(f.format)};
    }
    const std::string supported = "supported: " + supported_extensions() + ", or a generator spec gen:NAME:COUNT[:SEED]";
    if (ext.empty()) throw InputError(spec + ": unknown scene format: no file extension (" + supported + ")");
    throw InputError(spec + ": scene format '" + ext + "' is not supported yet (" + supported + ")");
}

void shuffle_triangles(TriangleMesh& mesh, uint64_t seed) {
    std::mt19937_64 engine(seed);
    const uint64_t n = mesh.triangle_count();
    uint32_t* t = mesh.indices.data();
    for (uint64_t i = n; i > 1; --i) {
        // j in [0, i); the modulo's bias is below i / 2^64 < 2^-32.
        const uint64_t j = engine() % i;
        std::swap_ranges(t + 3 * (i - 1), t + 3 * i, t + 3 * j);
    }
}

Scene default_scene() { return load_scene(kDefaultSceneSpec); }

void check_mesh(const TriangleMesh& mesh, const std::string& where) {
    if (mesh.indices.size() % 3 != 0)
        throw InputError(where + ": index array length " + std::to_string(mesh.indices.size()) +
                         " is not a multiple of 3");
    for (size_t i = 0; i < mesh.vertices.size(); ++i) {
        if (!is_finite(mesh.vertices[i]))
            throw InputError(where + ": vertex " + std::to_string(i) + " has a non-finite coordinate " +
                             format_vec(mesh.vertices[i]));
    }
    const size_t n = mesh.vertices.size();
    for (size_t k = 0; k < mesh.indices.size(); ++k) {
        if (mesh.indices[k] >= n)
            throw InputError(where + ": triangle " + std::to_string(k / 3) + ": index " +
                             std::to_string(mesh.indices[k]) + " out of range (" + std::to_string(n) + " vertices)");
    }
}

}  // namespace canopy
