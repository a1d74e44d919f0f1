// Tests for core/scene: generators, generator specs, OBJ loading, check_mesh.
#include "scene.h"

#include "error.h"

#include <glm/geometric.hpp>
#include <glm/vec3.hpp>
#include "test_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace canopy {
namespace {

namespace fs = std::filesystem;

using canopy::test_util::expect_input_error;

void expect_valid(const TriangleMesh& mesh) {
    ASSERT_EQ(mesh.indices.size() % 3, 0u);
    for (uint32_t i : mesh.indices) ASSERT_LT(i, mesh.vertices.size());
    for (const Vec3& v : mesh.vertices) {
        ASSERT_TRUE(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z));
    }
    EXPECT_NO_THROW(check_mesh(mesh, "test"));
}

double twice_area(const TriangleMesh& m, size_t t) {
    const glm::dvec3 a(m.vertex(t, 0)), b(m.vertex(t, 1)), c(m.vertex(t, 2));
    const glm::dvec3 e1 = b - a, e2 = c - a;
    const glm::dvec3 n(e1.y * e2.z - e1.z * e2.y, e1.z * e2.x - e1.x * e2.z, e1.x * e2.y - e1.y * e2.x);
    return std::sqrt(n.x * n.x + n.y * n.y + n.z * n.z);
}

bool same_arrays(const TriangleMesh& a, const TriangleMesh& b) {
    if (a.indices != b.indices || a.vertices.size() != b.vertices.size()) return false;
    for (size_t i = 0; i < a.vertices.size(); ++i) {
        // Bitwise equality of the floats.
        for (int k = 0; k < 3; ++k) {
            const float x = a.vertices[i][k], y = b.vertices[i][k];
            if (std::memcmp(&x, &y, sizeof x) != 0) return false;
        }
    }
    return true;
}

// ---------------------------------------------------------------------------
// Generators

TEST(SceneGenerators, NamesAndSpecs) {
    const std::vector<std::string> names = generator_names();
    const std::vector<std::string> expected = {"sphere", "random", "stadium", "plane", "coincident", "room"};
    EXPECT_EQ(std::set<std::string>(names.begin(), names.end()),
              std::set<std::string>(expected.begin(), expected.end()));
    EXPECT_TRUE(is_generator_spec("gen:sphere:100"));
    EXPECT_TRUE(is_generator_spec("gen:random:10:3"));
    EXPECT_FALSE(is_generator_spec("bunny.obj"));
    EXPECT_FALSE(is_generator_spec("/tmp/gen:sphere.obj"));
    EXPECT_FALSE(is_generator_spec(""));
}

TEST(SceneGenerators, RoughCountsValidAndDeterministic) {
    for (const std::string& name : generator_names()) {
        for (uint64_t count : {uint64_t{1}, uint64_t{7}, uint64_t{100}, uint64_t{1000}, uint64_t{20000}}) {
            SCOPED_TRACE(name + " " + std::to_string(count));
            const TriangleMesh mesh = generate(name, count);
            expect_valid(mesh);
            ASSERT_GE(mesh.triangle_count(), 1u);
            const double ratio = double(mesh.triangle_count()) / double(count);
            if (count >= 1000) {
                EXPECT_GT(ratio, 0.9);
                EXPECT_LT(ratio, 1.1);
            } else {
                EXPECT_LE(mesh.triangle_count(), std::max<uint64_t>(4 * count, 40));
            }
            EXPECT_TRUE(same_arrays(mesh, generate(name, count))) << "not deterministic";
            EXPECT_TRUE(same_arrays(generate(name, count, 12345), generate(name, count, 12345)));
        }
    }
}

TEST(SceneGenerators, RandomSeedMatters) {
    const TriangleMesh a = generate("random", 1000, 1);
    const TriangleMesh b = generate("random", 1000, 2);
    EXPECT_EQ(a.triangle_count(), 1000u);
    EXPECT_FALSE(same_arrays(a, b));
    EXPECT_TRUE(same_arrays(a, generate("random", 1000)));  // default seed is 1
}

TEST(SceneGenerators, RandomSmallTrianglesInUnitCube) {
    const uint64_t count = 8000;
    const TriangleMesh mesh = generate("random", count, 99);
    ASSERT_EQ(mesh.triangle_count(), count);
    const double s = 1.0 / std::cbrt(double(count));  // 0.05
    for (const Vec3& v : mesh.vertices) {
        for (int k = 0; k < 3; ++k) {
            EXPECT_GE(v[k], 0.0f);
            EXPECT_LE(v[k], 1.0f);
        }
    }
    double total_edge = 0.0;
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        for (int c = 0; c < 3; ++c) {
            const double e = glm::length(glm::dvec3(mesh.vertex(t, c)) - glm::dvec3(mesh.vertex(t, (c + 1) % 3)));
            EXPECT_LE(e, std::sqrt(3.0) * s * 1.0001);
            total_edge += e;
        }
        EXPECT_GT(twice_area(mesh, t), 0.0);
    }
    const double mean_edge = total_edge / (3.0 * double(count));
    EXPECT_GT(mean_edge, 0.3 * s);
    EXPECT_LT(mean_edge, 1.5 * s);
    // Spread over the whole cube, not clumped.
    Box box;
    for (const Vec3& v : mesh.vertices) box.extend(v);
    for (int k = 0; k < 3; ++k) {
        EXPECT_LT(box.lo[k], 0.05f);
        EXPECT_GT(box.hi[k], 0.95f);
    }
}

TEST(SceneGenerators, SphereIsClosedUnitSphereWithoutDegenerateTriangles) {
    const TriangleMesh mesh = generate("sphere", 5000);
    expect_valid(mesh);
    for (const Vec3& v : mesh.vertices) EXPECT_NEAR(glm::length(glm::dvec3(v)), 1.0, 1e-6);
    // Shared vertices: a closed 2-manifold, every edge in exactly two triangles
    // (once in each direction), Euler characteristic 2.
    std::map<std::pair<uint32_t, uint32_t>, int> directed;
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        const uint32_t* tri = &mesh.indices[3 * t];
        EXPECT_TRUE(tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2]);
        EXPECT_GT(twice_area(mesh, t), 0.0);
        for (int c = 0; c < 3; ++c) ++directed[{tri[c], tri[(c + 1) % 3]}];
        // Outward winding: the normal points away from the centre.
        const glm::dvec3 a(mesh.vertex(t, 0)), b(mesh.vertex(t, 1)), c(mesh.vertex(t, 2));
        const glm::dvec3 e1 = b - a, e2 = c - a;
        const glm::dvec3 n(e1.y * e2.z - e1.z * e2.y, e1.z * e2.x - e1.x * e2.z, e1.x * e2.y - e1.y * e2.x);
        EXPECT_GT(glm::dot(n, a + b + c), 0.0);
    }
    for (const auto& [edge, n] : directed) {
        EXPECT_EQ(n, 1);
        EXPECT_EQ(directed.count({edge.second, edge.first}), 1u);
    }
    const long long V = (long long)mesh.vertices.size(), E = (long long)directed.size() / 2,
                    F = (long long)mesh.triangle_count();
    EXPECT_EQ(V - E + F, 2);
}

TEST(SceneGenerators, StadiumIsDenseSphereInHugeBox) {
    const uint64_t count = 100000;
    const TriangleMesh mesh = generate("stadium", count);
    expect_valid(mesh);
    size_t on_sphere = 0, on_box = 0;
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        bool sphere = true, box = true;
        for (int c = 0; c < 3; ++c) {
            const Vec3 v = mesh.vertex(t, c);
            sphere = sphere && std::abs(glm::length(glm::dvec3(v)) - 1.0) < 1e-6;
            const float m = std::max({std::abs(v.x), std::abs(v.y), std::abs(v.z)});
            box = box && m == 500.0f;
        }
        EXPECT_TRUE(sphere != box) << "triangle " << t;
        on_sphere += sphere;
        on_box += box;
        EXPECT_GT(twice_area(mesh, t), 0.0);
    }
    const double fraction = double(on_sphere) / double(mesh.triangle_count());
    EXPECT_GT(fraction, 0.95);
    EXPECT_LT(fraction, 0.99);
    EXPECT_GT(on_box, 0u);
    EXPECT_EQ(on_box % 12, 0u);  // a grid of quads on each of the six faces
    Box bounds;
    for (const Vec3& v : mesh.vertices) bounds.extend(v);
    EXPECT_EQ(bounds.lo, Vec3(-500.0f));
    EXPECT_EQ(bounds.hi, Vec3(500.0f));
}

TEST(SceneGenerators, PlaneIsPlanar) {
    const TriangleMesh mesh = generate("plane", 3000);
    expect_valid(mesh);
    for (const Vec3& v : mesh.vertices) EXPECT_EQ(v.z, 0.0f);
    for (size_t t = 0; t < mesh.triangle_count(); ++t) EXPECT_GT(twice_area(mesh, t), 0.0);
}

TEST(SceneGenerators, CoincidentTrianglesAreIdentical) {
    const TriangleMesh mesh = generate("coincident", 777);
    expect_valid(mesh);
    ASSERT_EQ(mesh.triangle_count(), 777u);
    EXPECT_GT(twice_area(mesh, 0), 0.0);
    for (size_t t = 1; t < mesh.triangle_count(); ++t) {
        for (int c = 0; c < 3; ++c) EXPECT_EQ(mesh.vertex(t, c), mesh.vertex(0, c));
    }
}

TEST(SceneGenerators, RoomHasTwelveLargeTrianglesAroundASphere) {
    const TriangleMesh mesh = generate("room", 5000);
    expect_valid(mesh);
    const size_t n = mesh.triangle_count();
    ASSERT_GT(n, 4900u);
    ASSERT_LT(n, 5100u);
    // The last twelve: five walls of [-1, 1]^3 and the light, each half a
    // quad; every other triangle is a small one of the sphere inside.
    for (size_t t = 0; t < n; ++t) {
        if (t >= n - 12) {
            EXPECT_GE(twice_area(mesh, t), t >= n - 2 ? 0.48 - 1e-6 : 4.0 - 1e-6) << t;
        } else {
            EXPECT_LT(twice_area(mesh, t), 0.01) << t;
            for (int c = 0; c < 3; ++c) EXPECT_LT(glm::length(mesh.vertex(t, c) - Vec3(0.05f, -0.1f, -0.15f)), 0.3001f);
        }
    }
}

TEST(SceneGenerators, RejectsBadArguments) {
    expect_input_error([] { generate("sphere", 0); }, {"count 0", "sphere", "random"});
    expect_input_error([] { generate("plane", 100'000'001); }, {"100000001"});
    expect_input_error([] { generate("nosuch", 10); }, {"nosuch", "sphere", "coincident"});
}

// ---------------------------------------------------------------------------
// Scene specs

// shuffle_triangles: a permutation of whole triangles (each keeps its corners
// in order, the vertices are untouched), a pure function of the seed, and
// really a reordering.
TEST(ShuffleTriangles, PermutesWholeTrianglesDeterministically) {
    const TriangleMesh original = generate("sphere", 2000);
    TriangleMesh a = original, b = original, c = original;
    shuffle_triangles(a, 7);
    shuffle_triangles(b, 7);
    shuffle_triangles(c, 8);
    EXPECT_TRUE(same_arrays(a, b)) << "not a function of the seed";
    EXPECT_FALSE(same_arrays(a, c)) << "the seed changed nothing";
    EXPECT_EQ(a.vertices, original.vertices);
    ASSERT_EQ(a.indices.size(), original.indices.size());
    const auto triangles = [](const TriangleMesh& m) {
        std::vector<std::array<uint32_t, 3>> t(m.triangle_count());
        for (size_t i = 0; i < t.size(); ++i) t[i] = {m.indices[3 * i], m.indices[3 * i + 1], m.indices[3 * i + 2]};
        return t;
    };
    std::vector<std::array<uint32_t, 3>> ta = triangles(a), to = triangles(original);
    size_t moved = 0;
    for (size_t i = 0; i < ta.size(); ++i) moved += ta[i] != to[i];
    EXPECT_GT(moved, ta.size() / 2) << "few triangles moved";
    std::sort(ta.begin(), ta.end());
    std::sort(to.begin(), to.end());
    EXPECT_EQ(ta, to) << "not the same triangles";
    // Edge cases: no triangle, one triangle.
    TriangleMesh empty;
    shuffle_triangles(empty, 1);
    EXPECT_TRUE(empty.indices.empty());
    TriangleMesh one = generate("coincident", 1);
    const TriangleMesh one_before = one;
    shuffle_triangles(one, 3);
    EXPECT_TRUE(same_arrays(one, one_before));
}

TEST(SceneSpecs, GeneratorSpecs) {
    const Scene s = load_scene("gen:sphere:1000");
    EXPECT_EQ(s.format, "generated");
    EXPECT_EQ(s.name, "gen:sphere:1000");
    EXPECT_TRUE(same_arrays(s.mesh, generate("sphere", 1000, 1)));

    const Scene r = load_scene("gen:random:500:7");
    EXPECT_TRUE(same_arrays(r.mesh, generate("random", 500, 7)));
    EXPECT_TRUE(same_arrays(load_scene("gen:random:500").mesh, generate("random", 500, 1)));
    EXPECT_NO_THROW(load_scene("gen:random:3:18446744073709551615"));
}

TEST(SceneSpecs, MalformedGeneratorSpecs) {
    for (const std::string spec :
         {"gen:sphere", "gen:sphere:", "gen:sphere:abc", "gen:sphere:-5", "gen:sphere:1e5", "gen:nosuch:10",
          "gen::10", "gen:sphere:0", "gen:sphere:100000001", "gen:sphere:99999999999999999999999",
          "gen:sphere:10:x", "gen:sphere:10:-1", "gen:sphere:10:1:2"}) {
        SCOPED_TRACE(spec);
        expect_input_error([&] { load_scene(spec); }, {"'" + spec + "'", "sphere", "random", "stadium", "plane",
                                                       "coincident"});
    }
}

TEST(SceneSpecs, DefaultScene) {
    const Scene s = default_scene();
    EXPECT_EQ(s.name, "gen:sphere:100000");
    EXPECT_EQ(s.format, "generated");
    EXPECT_GT(s.mesh.triangle_count(), 95000u);
    EXPECT_LT(s.mesh.triangle_count(), 105000u);
}

TEST(SceneSpecs, UnsupportedFormats) {
    expect_input_error([] { load_scene("/nonexistent/bunny.stl"); }, {"/nonexistent/bunny.stl", "not supported"});
    expect_input_error([] { load_scene("scene.3DS"); }, {"scene.3DS", "not supported"});
    expect_input_error([] { load_scene("noextension"); }, {"noextension"});
    // .obj goes to the OBJ loader, which then reports the missing file.
    expect_input_error([] { load_scene("/nonexistent/dir/missing.OBJ"); },
                       {"/nonexistent/dir/missing.OBJ", "cannot open"});
}

// ---------------------------------------------------------------------------
// check_mesh

TEST(CheckMesh, ReportsFirstProblem) {
    TriangleMesh mesh;
    mesh.vertices = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};
    mesh.indices = {0, 1, 2, 2, 1, 0};
    EXPECT_NO_THROW(check_mesh(mesh, "ok"));

    TriangleMesh bad_index = mesh;
    bad_index.indices[4] = 7;
    expect_input_error([&] { check_mesh(bad_index, "where"); },
                       {"where: triangle 1: index 7 out of range (3 vertices)"});

    TriangleMesh bad_vertex = mesh;
    bad_vertex.vertices[1].y = std::numeric_limits<float>::quiet_NaN();
    bad_vertex.vertices[2].z = std::numeric_limits<float>::infinity();
    expect_input_error([&] { check_mesh(bad_vertex, "here"); },
                       {"here: vertex 1 has a non-finite coordinate (1, nan, 0)"});

    TriangleMesh ragged = mesh;
    ragged.indices.push_back(0);
    expect_input_error([&] { check_mesh(ragged, "there"); }, {"there:", "multiple of 3"});
}

// ---------------------------------------------------------------------------
// OBJ

class ObjFiles : public canopy::test_util::TempDirTest {};

TEST_F(ObjFiles, QuadIsTriangulated) {
    const std::string path = write("quad.obj",
                                   "# a unit quad\n"
                                   "o quad\n"
                                   "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                                   "vn 0 0 1\n"
                                   "f 1//1 2//1 3//1 4//1\n");
    const TriangleMesh mesh = load_obj(path);
    ASSERT_EQ(mesh.triangle_count(), 2u);
    ASSERT_EQ(mesh.vertices.size(), 4u);
    EXPECT_EQ(mesh.vertices[2], Vec3(1, 1, 0));
    expect_valid(mesh);
    EXPECT_EQ(std::set<uint32_t>(mesh.indices.begin(), mesh.indices.end()), (std::set<uint32_t>{0, 1, 2, 3}));
    EXPECT_NEAR(0.5 * (twice_area(mesh, 0) + twice_area(mesh, 1)), 1.0, 1e-6);

    const Scene s = load_scene(path);
    EXPECT_EQ(s.format, "obj");
    EXPECT_EQ(s.name, path);
    EXPECT_EQ(s.mesh.indices, mesh.indices);
}

TEST_F(ObjFiles, UpperCaseExtensionAndCrlfAndPolygons) {
    const std::string path = write("PENTAGON.OBJ",
                                   "v 0 0 0\r\nv 2 0 0\r\nv 2 2 0\r\nv 1 3 0\r\nv 0 2 0\r\n"
                                   "vt 0 0\r\nvt 1 0\r\nvt 1 1\r\n"
                                   "g part\r\n"
                                   "f 1/1 2/2 3/3 4/1 5/2\r\n"
                                   "usemtl whatever\r\n"
                                   "f 1/1/1 2/2/1 3/3/1\r\n");
    const Scene s = load_scene(path);
    EXPECT_EQ(s.format, "obj");
    EXPECT_EQ(s.mesh.triangle_count(), 4u);
    EXPECT_EQ(s.mesh.vertices.size(), 5u);
    expect_valid(s.mesh);
    // The last triangle keeps file order.
    EXPECT_EQ(std::vector<uint32_t>(s.mesh.indices.end() - 3, s.mesh.indices.end()),
              (std::vector<uint32_t>{0, 1, 2}));
}

TEST_F(ObjFiles, NegativeRelativeIndices) {
    const std::string path = write("relative.obj",
                                   "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n"
                                   "v 5 5 5\nf -4 -1 -2\n");
    const TriangleMesh mesh = load_obj(path);
    ASSERT_EQ(mesh.triangle_count(), 2u);
    EXPECT_EQ(mesh.indices, (std::vector<uint32_t>{0, 1, 2, 0, 3, 2}));
}

TEST_F(ObjFiles, ForwardReferencesAreAccepted) {
    const std::string path = write("forward.obj", "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    const TriangleMesh mesh = load_obj(path);
    EXPECT_EQ(mesh.indices, (std::vector<uint32_t>{0, 1, 2}));
}

TEST_F(ObjFiles, MissingFile) {
    const std::string path = (dir_ / "does_not_exist.obj").string();
    expect_input_error([&] { load_obj(path); }, {path, "cannot open"});
    expect_input_error([&] { load_obj(dir_.string()); }, {dir_.string(), "cannot open"});
}

TEST_F(ObjFiles, EmptyAndFacelessFiles) {
    const std::string empty = write("empty.obj", "");
    expect_input_error([&] { load_obj(empty); }, {empty, "no triangles"});
    const std::string blank = write("blank.obj", "\n  \n\r\n");
    expect_input_error([&] { load_obj(blank); }, {blank, "no triangles"});
    const std::string comments = write("comments.obj", "# nothing here\n# at all\n");
    expect_input_error([&] { load_obj(comments); }, {comments, "no triangles"});
    const std::string vertices = write("vertices.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    expect_input_error([&] { load_obj(vertices); }, {vertices, "no triangles", "3 vertices"});
    const std::string lines = write("lines.obj", "v 0 0 0\nv 1 0 0\nl 1 2\n");
    expect_input_error([&] { load_obj(lines); }, {lines, "no triangles"});
}

TEST_F(ObjFiles, MalformedFaces) {
    const std::string vs = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    const std::string truncated = write("truncated.obj", vs + "f 1 2 3\nf 1 2\n");
    expect_input_error([&] { load_obj(truncated); }, {truncated, "line 5", "face 2", "2 vertices"});
    const std::string lone = write("lone.obj", vs + "f\n");
    expect_input_error([&] { load_obj(lone); }, {lone, "line 4", "face 1"});
    const std::string word = write("word.obj", vs + "f 1 x 3\n");
    expect_input_error([&] { load_obj(word); }, {word, "line 4", "face 1", "'x'"});
    const std::string zero = write("zero.obj", vs + "f 0 1 2\n");
    expect_input_error([&] { load_obj(zero); }, {zero, "line 4", "index 0"});
    const std::string slashes = write("slashes.obj", vs + "f 1/ 2/ 3/\n");
    expect_input_error([&] { load_obj(slashes); }, {slashes, "line 4", "'1/'"});
    const std::string comment = write("comment.obj", vs + "f 1 2 3 # trailing\n");
    expect_input_error([&] { load_obj(comment); }, {comment, "line 4"});
}

TEST_F(ObjFiles, IndexOutOfRange) {
    const std::string vs = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    const std::string big = write("big.obj", vs + "f 1 2 3\nf 1 2 4\n");
    expect_input_error([&] { load_obj(big); }, {big, "line 5", "face 2", "index 4 out of range", "3 vertices"});
    const std::string quad = write("quad_big.obj", vs + "f 1 2 3 9\n");
    expect_input_error([&] { load_obj(quad); }, {quad, "line 4", "face 1", "index 9"});
    const std::string rel = write("relative_big.obj", vs + "f -1 -2 -4\n");
    expect_input_error([&] { load_obj(rel); }, {rel, "line 4", "face 1", "-4"});
    const std::string huge = write("huge.obj", vs + "f 1 2 99999999999999999999\n");
    expect_input_error([&] { load_obj(huge); }, {huge, "line 4", "face 1"});
}

TEST_F(ObjFiles, NonFiniteAndMalformedVertices) {
    const std::string tail = "v 0 1 0\nf 1 2 3\n";
    const std::string nan = write("nan.obj", "v 0 0 0\nv nan 0 0\n" + tail);
    expect_input_error([&] { load_obj(nan); }, {nan, "line 2", "vertex 2", "non-finite", "nan"});
    const std::string inf = write("inf.obj", "# header\nv 0 0 0\nv 1 -inf 0\n" + tail);
    expect_input_error([&] { load_obj(inf); }, {inf, "line 3", "vertex 2", "inf"});
    const std::string overflow = write("overflow.obj", "v 0 0 1e39\nv 1 0 0\n" + tail);
    expect_input_error([&] { load_obj(overflow); }, {overflow, "line 1", "vertex 1", "inf"});
    const std::string overflow2 = write("overflow2.obj", "v 0 0 1e999\nv 1 0 0\n" + tail);
    expect_input_error([&] { load_obj(overflow2); }, {overflow2, "line 1", "vertex 1"});
    const std::string short_v = write("short.obj", "v 0 0\nv 1 0 0\n" + tail);
    expect_input_error([&] { load_obj(short_v); }, {short_v, "line 1", "vertex 1", "2 coordinates"});
    const std::string word = write("word_v.obj", "v 0 0 0\nv 1 zero 0\n" + tail);
    expect_input_error([&] { load_obj(word); }, {word, "line 2", "vertex 2", "'zero'"});
    // Underflow to zero, a leading '+', extra w / colour values are fine.
    const std::string odd = write("odd.obj", "v 1e-999 +0 0 1\nv 1 0 0 0.5 0.5 0.5\n" + tail);
    const TriangleMesh mesh = load_obj(odd);
    EXPECT_EQ(mesh.vertices[0], Vec3(0, 0, 0));
}

TEST_F(ObjFiles, BinaryGarbage) {
    std::mt19937_64 rng(42);
    std::string bytes(4096, '\0');
    for (char& c : bytes) c = static_cast<char>(rng() & 0xff);
    const std::string garbage = write("garbage.obj", bytes);
    expect_input_error([&] { load_obj(garbage); }, {garbage});

    // Garbage without NUL bytes is still not a mesh.
    for (char& c : bytes)
        if (c == '\0') c = 'x';
    const std::string text_garbage = write("text_garbage.obj", bytes);
    expect_input_error([&] { load_obj(text_garbage); }, {text_garbage});

    // A PNG header under an .obj name.
    const std::string png = write("image.obj", std::string("\x89PNG\r\n\x1a\n\0\0\0\rIHDR", 16));
    expect_input_error([&] { load_obj(png); }, {png});
}

TEST(ObjSharedScenes, Cow) {
    const fs::path cow = fs::path(CANOPY_SCENES_DIR) / "cow.obj";
    if (!fs::exists(cow))
        GTEST_SKIP() << "shared scenes absent: " << cow << " does not exist (CANOPY_SCENES_DIR="
                     << CANOPY_SCENES_DIR << ")";
    const Scene s = load_scene(cow.string());
    EXPECT_EQ(s.format, "obj");
    EXPECT_EQ(s.mesh.triangle_count(), 5856u);
    EXPECT_EQ(s.mesh.vertices.size(), 2930u);
    expect_valid(s.mesh);
    Box box;
    for (const Vec3& v : s.mesh.vertices) box.extend(v);
    EXPECT_NEAR(box.lo.x, -0.40649, 1e-5);
    EXPECT_NEAR(box.hi.y, 0.933719, 1e-5);
}

}  // namespace
}  // namespace canopy
