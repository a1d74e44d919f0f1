// canopy: COLLADA, glTF / GLB: through Assimp.
//
// Only aiProcess_Triangulate (and the structure validation) runs; the node
// graph is walked here, each node's transform accumulated in double from the
// root (which holds the COLLADA unit scale) and applied to the positions of
// the meshes it instances, rounded to float once. COLLADA's up axis is
// ignored, so coordinates keep the file's own axes. Assimp gives every face
// corner its own vertex; within each placed mesh, vertices with bitwise
// equal positions are shared again (so the counts are the file's), never
// across meshes. Triangles keep Assimp's order. Points and lines are
// skipped. Assimp's logger is never created, so it prints nothing.
#include "assimp_mesh.h"

#include "error.h"
#include "file_read.h"
#include "reader_util.h"

#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <cstring>
#include <limits>
#include <unordered_map>
#include <vector>

namespace canopy {
namespace {

using input::format_vec;
using input::is_finite;
using input::make_vec;
using input::push_triangle;
using input::trim_message;

struct Matrix {
    double m[4][4];  // row-major; p' = M p for column vectors, as aiMatrix4x4

    static Matrix from(const aiMatrix4x4& a) {
        const ai_real* r[4] = {a[0], a[1], a[2], a[3]};
        Matrix out{};
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j) out.m[i][j] = static_cast<double>(r[i][j]);
        return out;
    }
    Matrix operator*(const Matrix& b) const {
        Matrix out{};
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j)
                for (int k = 0; k < 4; ++k) out.m[i][j] += m[i][k] * b.m[k][j];
        return out;
    }
    Vec3 apply(const aiVector3D& p) const {
        const double x = p.x, y = p.y, z = p.z;
        double r[3];
        for (int i = 0; i < 3; ++i) r[i] = m[i][0] * x + m[i][1] * y + m[i][2] * z + m[i][3];
        return make_vec(r[0], r[1], r[2]);
    }
};

struct PositionKey {
    uint32_t bits[3];
    bool operator==(const PositionKey&) const = default;
};

struct PositionHash {
    size_t operator()(const PositionKey& k) const {
        uint64_t h = 0xcbf29ce484222325ull;
        for (uint32_t b : k.bits) h = (h ^ b) * 0x100000001b3ull;
        return static_cast<size_t>(h ^ (h >> 29));
    }
};

}  // namespace

TriangleMesh load_with_assimp(const std::string& path) {
    open_for_reading(path);  // a clear error for missing files before Assimp's own
    Assimp::Importer importer;
    importer.SetPropertyBool(AI_CONFIG_IMPORT_COLLADA_IGNORE_UP_DIRECTION, true);
    const aiScene* scene = importer.ReadFile(path, aiProcess_Triangulate | aiProcess_ValidateDataStructure);
    if (scene == nullptr) {
        const std::string error = trim_message(importer.GetErrorString());
        throw InputError(path + ": Assimp: " + (error.empty() ? "cannot import the file" : error));
    }
    if (scene->mRootNode == nullptr || scene->mNumMeshes == 0)
        throw InputError(path + ": no triangles (the file has no meshes)");

    TriangleMesh mesh;
    std::unordered_map<PositionKey, uint32_t, PositionHash> shared;
    std::vector<uint32_t> remap;
    uint64_t faces = 0, skipped = 0;
    struct Item {
        const aiNode* node;
        Matrix world;
    };
    std::vector<Item> stack{{scene->mRootNode, Matrix::from(scene->mRootNode->mTransformation)}};
    while (!stack.empty()) {
        const Item item = stack.back();
        stack.pop_back();
        const aiNode* node = item.node;
        for (unsigned c = node->mNumChildren; c-- > 0;) {  // children in order, first on top
            const aiNode* child = node->mChildren[c];
            stack.push_back({child, item.world * Matrix::from(child->mTransformation)});
        }
        for (unsigned mi = 0; mi < node->mNumMeshes; ++mi) {
            if (node->mMeshes[mi] >= scene->mNumMeshes)
                throw InputError(path + ": node '" + node->mName.C_Str() + "' refers to mesh " +
                                 std::to_string(node->mMeshes[mi]) + " of " + std::to_string(scene->mNumMeshes));
            const aiMesh* m = scene->mMeshes[node->mMeshes[mi]];
            const std::string where = path + ": mesh '" + m->mName.C_Str() + "' (node '" + node->mName.C_Str() + "')";
            if (m->mVertices == nullptr && m->mNumVertices > 0) throw InputError(where + ": no positions");
            remap.assign(m->mNumVertices, std::numeric_limits<uint32_t>::max());
            shared.clear();
            const auto vertex = [&](unsigned v) {
                if (v >= m->mNumVertices)
                    throw InputError(where + ": vertex index " + std::to_string(v) + " out of range (" +
                                     std::to_string(m->mNumVertices) + " vertices)");
                if (remap[v] != std::numeric_limits<uint32_t>::max()) return remap[v];
                const Vec3 p = item.world.apply(m->mVertices[v]);
                if (!is_finite(p))
                    throw InputError(where + ": vertex " + std::to_string(v) + " has a non-finite coordinate " +
                                     format_vec(p) + " (after the node transforms)");
                PositionKey key{};
                std::memcpy(key.bits, &p[0], sizeof(float));
                std::memcpy(key.bits + 1, &p[1], sizeof(float));
                std::memcpy(key.bits + 2, &p[2], sizeof(float));
                const auto [it, inserted] = shared.try_emplace(key, static_cast<uint32_t>(mesh.vertices.size()));
                if (inserted) {
                    if (mesh.vertices.size() >= std::numeric_limits<uint32_t>::max())
                        throw InputError(path + ": more vertices than 32-bit indices can address");
                    mesh.vertices.push_back(p);
                }
                return remap[v] = it->second;
            };
            for (unsigned f = 0; f < m->mNumFaces; ++f) {
                const aiFace& face = m->mFaces[f];
                ++faces;
                if (face.mNumIndices < 3) {  // a point or a line
                    ++skipped;
                    continue;
                }
                const uint32_t first = vertex(face.mIndices[0]);
                uint32_t prev = vertex(face.mIndices[1]);
                for (unsigned k = 2; k < face.mNumIndices; ++k) {
                    const uint32_t cur = vertex(face.mIndices[k]);
                    push_triangle(mesh, first, prev, cur);
                    prev = cur;
                }
            }
        }
    }
    if (mesh.indices.empty())
        throw InputError(path + ": no triangles (" + std::to_string(scene->mNumMeshes) + " meshes, " +
                         std::to_string(faces) + " faces placed in the scene, " + std::to_string(skipped) +
                         " of them points or lines)");
    return mesh;
}

}  // namespace canopy
