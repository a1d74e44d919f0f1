// Tests for mesh file formats: PLY (canopy's own reader: ASCII, binary
// little and big endian), OFF (canopy's own reader), and COLLADA, glTF and
// GLB through Assimp.
#include "error.h"
#include "ply.h"
#include "scene.h"

#include "test_util.h"

#include <gtest/gtest.h>

#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

namespace canopy {
namespace {

namespace fs = std::filesystem;

using canopy::test_util::expect_input_error;

Box bounds(const TriangleMesh& mesh) {
    Box b;
    for (const Vec3& v : mesh.vertices) b.extend(v);
    return b;
}

class FormatFiles : public canopy::test_util::TempDirTest {
protected:
    // Writes `text` to `name` and expects `load` (called with its path) to
    // throw an InputError naming the file and containing every needle.
    template <class Load>
    void expect_rejected(const std::string& name, const std::string& text, std::vector<std::string> needles,
                         Load&& load) {
        SCOPED_TRACE(name);
        const std::string path = write(name, text);
        needles.push_back(path + ": ");
        expect_input_error([&] { load(path); }, needles);
    }
    static void load_any(const std::string& path) { load_scene(path); }
    static void load_ply_file(const std::string& path) { load_ply(path); }
};

// ---------------------------------------------------------------------------
// Writing binary PLY data.

class Bytes {
public:
    explicit Bytes(bool big_endian) : big_(big_endian) {}
    template <class T>
    Bytes& put(T value) {
        static_assert(std::is_arithmetic_v<T>);
        unsigned char b[sizeof(T)];
        std::memcpy(b, &value, sizeof(T));
        const bool swap = big_ != (std::endian::native == std::endian::big);
        for (size_t i = 0; i < sizeof(T); ++i) data_ += static_cast<char>(b[swap ? sizeof(T) - 1 - i : i]);
        return *this;
    }
    const std::string& str() const { return data_; }

private:
    bool big_;
    std::string data_;
};

// The 2 triangles (0 1 2) and (0 2 3) as the quad 0 1 2 3 and the triangle
// 1 4 2 give in a fan triangulation, with vertices of exact floats.
const std::vector<Vec3> kVertices = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(1, 1, 0), Vec3(0, 1, 0), Vec3(2.5f, -0.25f, 3)};
const std::vector<std::vector<uint32_t>> kFaces = {{0, 1, 2, 3}, {1, 4, 2}};
const std::vector<uint32_t> kIndices = {0, 1, 2, 0, 2, 3, 1, 4, 2};

void expect_mesh(const TriangleMesh& mesh) {
    EXPECT_EQ(mesh.vertices, kVertices);
    EXPECT_EQ(mesh.indices, kIndices);
}

const char* kAsciiQuad =
    "ply\n"
    "format ascii 1.0\n"
    "comment a quad and a triangle\n"
    "element vertex 5\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "element face 2\n"
    "property list uchar int vertex_indices\n"
    "end_header\n"
    "0 0 0\n"
    "1 0 0\n"
    "1 1 0\n"
    "0 1 0\n"
    "2.5 -0.25 3\n"
    "4 0 1 2 3\n"
    "3 1 4 2\n";

// A binary file with properties of every type around x, y, z and the
// indices, list properties in the vertex and face elements, and elements
// before and after them.
std::string binary_with_extras(bool big_endian) {
    std::string header = std::string("ply\nformat ") + (big_endian ? "binary_big_endian" : "binary_little_endian") +
                         " 1.0\n"
                         "obj_info made by hand\n"
                         "element camera 2\n"
                         "property float view_px\n"
                         "property list uchar char name\n"
                         "element vertex 5\n"
                         "property uchar red\n"
                         "property double x\n"
                         "property list ushort float normal\n"
                         "property float y\n"
                         "property short s\n"
                         "property int8 t\n"
                         "property float64 w\n"
                         "property float32 z\n"
                         "property uint16 u\n"
                         "element face 2\n"
                         "property int flags\n"
                         "property list uint uint vertex_indices\n"
                         "property list int double weights\n"
                         "property uint32 tag\n"
                         "element material 1\n"
                         "property list uchar uchar name\n"
                         "property double shininess\n"
                         "end_header\n";
    Bytes b(big_endian);
    for (int c = 0; c < 2; ++c) {
        b.put(1.5f).put(uint8_t{3});
        b.put(int8_t{'c'}).put(int8_t{'a'}).put(int8_t{'m'});
    }
    for (size_t i = 0; i < kVertices.size(); ++i) {
        const Vec3& v = kVertices[i];
        b.put(uint8_t(200)).put(double(v.x)).put(uint16_t(i % 3));
        for (size_t k = 0; k < i % 3; ++k) b.put(float(k));
        b.put(v.y).put(int16_t(-7)).put(int8_t(-1)).put(1e300).put(v.z).put(uint16_t(65535));
    }
    for (const std::vector<uint32_t>& f : kFaces) {
        b.put(int32_t{-1}).put(uint32_t(f.size()));
        for (uint32_t i : f) b.put(i);
        b.put(int32_t{2}).put(0.25).put(0.75);
        b.put(uint32_t{0xdeadbeef});
    }
    b.put(uint8_t{2}).put(uint8_t{'m'}).put(uint8_t{'1'}).put(0.5);
    return header + b.str();
}

// The mesh with the face list as `count_type index_type` in `encoding`.
std::string ply_with_list_types(const std::string& encoding, const std::string& count_type,
                                const std::string& index_type) {
    std::string header = "ply\nformat " + encoding +
                         " 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
                         "element face 2\nproperty list " +
                         count_type + " " + index_type + " vertex_index\nend_header\n";
    if (encoding == "ascii") {
        std::string body = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2.5 -0.25 3\n4 0 1 2 3\n3 1 4 2\n";
        return header + body;
    }
    Bytes b(encoding == "binary_big_endian");
    for (const Vec3& v : kVertices) b.put(v.x).put(v.y).put(v.z);
    auto put = [&](const std::string& type, uint32_t value) {
        if (type == "char" || type == "int8") b.put(static_cast<int8_t>(value));
        if (type == "uchar" || type == "uint8") b.put(static_cast<uint8_t>(value));
        if (type == "short" || type == "int16") b.put(static_cast<int16_t>(value));
        if (type == "ushort" || type == "uint16") b.put(static_cast<uint16_t>(value));
        if (type == "int" || type == "int32") b.put(static_cast<int32_t>(value));
        if (type == "uint" || type == "uint32") b.put(static_cast<uint32_t>(value));
    };
    for (const std::vector<uint32_t>& f : kFaces) {
        put(count_type, static_cast<uint32_t>(f.size()));
        for (uint32_t i : f) put(index_type, i);
    }
    return header + b.str();
}

// A minimal binary little-endian triangle file: `vertices` float x y z,
// `faces` "list uchar int" triangles, with the given data.
std::string binary_triangles(size_t vertex_count, size_t face_count, const std::vector<Vec3>& vertices,
                             const std::vector<std::vector<int32_t>>& faces) {
    std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(vertex_count) +
                         "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                         std::to_string(face_count) + "\nproperty list uchar int vertex_indices\nend_header\n";
    Bytes b(false);
    for (const Vec3& v : vertices) b.put(v.x).put(v.y).put(v.z);
    for (const std::vector<int32_t>& f : faces) {
        b.put(static_cast<uint8_t>(f.size()));
        for (int32_t i : f) b.put(i);
    }
    return header + b.str();
}

const std::vector<Vec3> kTriangle = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};

// ---------------------------------------------------------------------------
// PLY: what loads.

TEST_F(FormatFiles, PlyAsciiQuadIsFanTriangulated) {
    const std::string path = write("quad.ply", kAsciiQuad);
    expect_mesh(load_ply(path));
    const Scene s = load_scene(path);
    EXPECT_EQ(s.format, "ply");
    EXPECT_EQ(s.name, path);
    expect_mesh(s.mesh);
    EXPECT_NO_THROW(check_mesh(s.mesh, path));
}

TEST_F(FormatFiles, PlyAsciiCrlfBlankLinesAndSpacing) {
    std::string text = kAsciiQuad;
    std::string crlf;
    for (char c : text) {
        if (c == '\n') crlf += '\r';
        crlf += c;
    }
    const std::string path = write("CRLF.PLY", crlf);
    const Scene s = load_scene(path);
    EXPECT_EQ(s.format, "ply");
    expect_mesh(s.mesh);

    const std::string spaced = write("spaced.ply",
                                     "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
                                     "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
                                     "end_header\n"
                                     "\t0 0 0  \n+1 0.0 0\n\n1e0 1 0\n0 1 -0\n2.5 -0.25 3\n  4 0\t1 2 3 \n3 1 4 2");
    const TriangleMesh m = load_ply(spaced);
    EXPECT_EQ(m.indices, kIndices);
    EXPECT_EQ(m.vertices, kVertices);
}

TEST_F(FormatFiles, PlyBinaryWithExtraPropertiesAndElements) {
    for (bool big : {false, true}) {
        SCOPED_TRACE(big ? "big endian" : "little endian");
        const std::string path = write(big ? "extras_be.ply" : "extras_le.ply", binary_with_extras(big));
        expect_mesh(load_ply(path));
    }
}

TEST_F(FormatFiles, PlyListCountAndIndexTypes) {
    // One file through load_scene; the combinations parsed from memory.
    expect_mesh(load_scene(write("types.ply", ply_with_list_types("binary_big_endian", "ushort", "short"))).mesh);
    for (const std::string encoding : {"ascii", "binary_little_endian", "binary_big_endian"}) {
        for (const std::string count : {"uchar", "ushort", "uint", "char", "int", "uint8", "int16"}) {
            for (const std::string index : {"int", "uint", "short", "ushort", "char", "uchar", "int32", "uint16"}) {
                SCOPED_TRACE(encoding + " list " + count + " " + index);
                expect_mesh(parse_ply(ply_with_list_types(encoding, count, index), "types.ply"));
            }
        }
    }
}

TEST_F(FormatFiles, PlyVertexTypesAndBigFaces) {
    // Integer and double coordinates; a hexagon; a face element whose only
    // list has another name; vertices after faces.
    const std::string header =
        "ply\nformat binary_big_endian 1.0\nelement face 1\nproperty uchar flags\nproperty list uchar ushort idx\n"
        "element vertex 6\nproperty int x\nproperty short y\nproperty double z\nend_header\n";
    Bytes b(true);
    b.put(uint8_t{9}).put(uint8_t{6});
    for (uint16_t i = 0; i < 6; ++i) b.put(i);
    for (int i = 0; i < 6; ++i) b.put(int32_t{i - 3}).put(int16_t(2 * i)).put(0.5 * i);
    const TriangleMesh m = load_ply(write("hexagon.ply", header + b.str()));
    EXPECT_EQ(m.indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 0, 3, 4, 0, 4, 5}));
    ASSERT_EQ(m.vertices.size(), 6u);
    for (int i = 0; i < 6; ++i) EXPECT_EQ(m.vertices[i], Vec3(float(i - 3), float(2 * i), 0.5f * float(i)));
}

TEST_F(FormatFiles, PlyParseFromMemory) {
    expect_mesh(parse_ply(kAsciiQuad, "in-memory"));
    expect_input_error([] { parse_ply("", "in-memory"); }, {"in-memory: empty file"});
}

// ---------------------------------------------------------------------------
// PLY: what is rejected, and the message says what and where.

TEST_F(FormatFiles, PlyHeaderErrors) {
    struct Case {
        std::string name, text;
        std::vector<std::string> needles;
    };
    const std::string v3 = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    const std::string f1 = "element face 1\nproperty list uchar int vertex_indices\n";
    const std::string body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    const std::vector<Case> cases = {
        {"empty.ply", "", {"empty file"}},
        {"notply.ply", "solid cube\nfacet normal 0 0 1\n", {"not a PLY file", "line 1"}},
        {"onlymagic.ply", "ply\n", {"end_header"}},
        {"noend.ply", "ply\nformat ascii 1.0\n" + v3, {"no end_header"}},
        {"format.ply", "ply\nformat binary_middle_endian 1.0\n" + v3 + f1 + "end_header\n",
         {"header line 2", "unsupported format 'binary_middle_endian'"}},
        {"version.ply", "ply\nformat ascii 2.0\n" + v3 + f1 + "end_header\n" + body,
         {"header line 2", "version '2.0'"}},
        {"noformat.ply", "ply\n" + v3 + f1 + "end_header\n" + body, {"header line 8", "no format line"}},
        {"type.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty flaot x\n", {"header line 4", "'flaot'"}},
        {"orphan.ply", "ply\nformat ascii 1.0\nproperty float x\n", {"header line 3", "before any element"}},
        {"keyword.ply", "ply\nformat ascii 1.0\n" + v3 + "elemnt face 1\n", {"header line 7", "'elemnt'"}},
        {"count.ply", "ply\nformat ascii 1.0\nelement vertex -3\n", {"header line 3", "'-3'"}},
        {"again.ply", "ply\nformat ascii 1.0\n" + v3 + "property float x\n", {"header line 7", "'x' declared again"}},
        {"noz.ply",
         "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n" + f1 + "end_header\n",
         {"header line 3", "no property 'z'"}},
        {"novertex.ply", "ply\nformat ascii 1.0\n" + f1 + "end_header\n3 0 1 2\n", {"no 'vertex' element"}},
        {"noface.ply", "ply\nformat ascii 1.0\n" + v3 + "end_header\n0 0 0\n1 0 0\n0 1 0\n",
         {"no triangles", "no 'face' element"}},
        {"zerofaces.ply", "ply\nformat ascii 1.0\n" + v3 + "element face 0\nproperty list uchar int vertex_indices\n" +
                              "end_header\n0 0 0\n1 0 0\n0 1 0\n",
         {"no triangles", "0 faces"}},
        {"floatindex.ply",
         "ply\nformat ascii 1.0\n" + v3 + "element face 1\nproperty list uchar float vertex_indices\nend_header\n" +
             body,
         {"header line 8", "must be integers"}},
        {"floatcount.ply",
         "ply\nformat ascii 1.0\n" + v3 + "element face 1\nproperty list float int vertex_indices\nend_header\n",
         {"header line 8", "not an integer type"}},
        {"noindices.ply", "ply\nformat ascii 1.0\n" + v3 + "element face 1\nproperty int a\nend_header\n",
         {"header line 7", "no property 'vertex_indices'"}},
        {"binaryheader.ply", std::string("ply\nformat ascii 1.0\n") + v3 + std::string("\x01\x02\x03\n", 4),
         {"header line 7", "binary data in the header"}},
    };
    for (const Case& c : cases) expect_rejected(c.name, c.text, c.needles, load_any);
}

TEST_F(FormatFiles, PlyBinaryTruncatedAndInconsistentSizes) {
    const std::string good = binary_triangles(3, 2, kTriangle, {{0, 1, 2}, {2, 1, 0}});
    ASSERT_NO_THROW(load_ply(write("good.ply", good)));
    const size_t header = good.size() - 3 * 12 - 2 * 13;

    // Cut inside the second face: names face 1.
    const std::string cut_face = write("cut_face.ply", good.substr(0, good.size() - 5));
    expect_input_error([&] { load_ply(cut_face); }, {cut_face, "truncated", "face 1 ", "starts at byte"});
    // Counts that need more data than the file has: names the element's
    // header line and the sizes.
    const std::string cut_vertex = write("cut_vertex.ply", good.substr(0, header + 20));
    expect_input_error([&] { load_ply(cut_vertex); },
                       {cut_vertex, "header line 3", "element 'vertex' count 3", "inconsistent with the file size"});
    const std::string many = write("many.ply", binary_triangles(1000000, 2, kTriangle, {{0, 1, 2}, {2, 1, 0}}));
    expect_input_error([&] { load_ply(many); }, {many, "count 1000000", "inconsistent with the file size"});
    const std::string huge =
        write("huge.ply", binary_triangles(3, 18446744073709551615ull, kTriangle, {{0, 1, 2}, {2, 1, 0}}));
    expect_input_error([&] { load_ply(huge); }, {huge, "header line 7", "inconsistent with the file size"});
    // Too few faces declared: data left over.
    const std::string extra = write("extra.ply", binary_triangles(3, 1, kTriangle, {{0, 1, 2}, {2, 1, 0}}));
    expect_input_error([&] { load_ply(extra); }, {extra, "13 bytes of data after the last element"});
    // Lists make the sizes variable: a face longer than the data left.
    const std::string long_face = write("long_face.ply", binary_triangles(3, 2, kTriangle, {{0, 1, 2}, {0, 1}}) +
                                                             std::string(2, '\0'));
    expect_input_error([&] { load_ply(long_face); }, {long_face, "face 1 has 2 vertices"});
    std::string big_count = binary_triangles(3, 1, kTriangle, {{0, 1, 2}});
    big_count[header + 36] = static_cast<char>(200);  // the face's count byte
    const std::string big = write("big_count.ply", big_count);
    expect_input_error([&] { load_ply(big); }, {big, "truncated", "face 0 "});
    // Extra-property elements are checked too.
    const std::string skipped =
        write("skipped.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                             "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                             "element junk 2\nproperty list int double values\nend_header\n" +
                                 binary_triangles(3, 1, kTriangle, {{0, 1, 2}}).substr(header) +
                                 std::string("\x05\0\0\0", 4) + std::string(8, '\0'));
    expect_input_error([&] { load_ply(skipped); }, {skipped, "truncated", "junk 0 "});
}

TEST_F(FormatFiles, PlyBadIndicesCoordinatesAndFaces) {
    const float inf = std::numeric_limits<float>::infinity();
    const std::string out_of_range =
        write("range.ply", binary_triangles(3, 2, kTriangle, {{0, 1, 2}, {0, 1, 3}}));
    expect_input_error([&] { load_ply(out_of_range); },
                       {out_of_range, "face 1: vertex index 3 out of range (3 vertices)"});
    const std::string negative = write("negative.ply", binary_triangles(3, 2, kTriangle, {{0, 1, 2}, {0, -1, 2}}));
    expect_input_error([&] { load_ply(negative); }, {negative, "face 1: vertex index -1 out of range"});
    const std::string nonfinite =
        write("inf.ply", binary_triangles(3, 1, {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, inf, 0)}, {{0, 1, 2}}));
    expect_input_error([&] { load_ply(nonfinite); }, {nonfinite, "vertex 2 has a non-finite coordinate (0, inf, 0)"});
    const std::string two = write("two.ply", binary_triangles(3, 1, kTriangle, {{0, 1}}) + std::string(4, '\0'));
    expect_input_error([&] { load_ply(two); }, {two, "face 0 has 2 vertices (needs at least 3)"});

    // The same in ASCII, with the line.
    const std::string head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";
    const std::string verts = "0 0 0\n1 0 0\n0 1 0\n";
    struct Case {
        std::string name, body;
        std::vector<std::string> needles;
    };
    const std::vector<Case> cases = {
        {"a_range.ply", verts + "3 0 1 2\n3 0 1 7\n", {"line 14: face 1: vertex index 7 out of range (3 vertices)"}},
        {"a_negative.ply", verts + "3 0 1 2\n3 -2 1 0\n", {"line 14: face 1: vertex index -2 out of range"}},
        {"a_nan.ply", "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n3 0 1 2\n",
         {"line 11: vertex 1 has a non-finite coordinate (1, nan, 0)"}},
        {"a_overflow.ply", "0 0 0\n1 0 0\n0 1 1e39\n3 0 1 2\n3 0 1 2\n",
         {"line 12: vertex 2 has a non-finite coordinate (0, 1, inf)"}},
        {"a_short.ply", verts + "3 0 1 2\n2 0 1\n", {"line 14: face 1 has 2 vertices (needs at least 3)"}},
        {"a_empty_face.ply", verts + "0\n3 0 1 2\n", {"line 13: face 0 has 0 vertices"}},
        {"a_word.ply", "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", {"line 11: vertex 1", "'zero' is not a number"}},
        {"a_few.ply", "0 0 0\n1 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", {"line 11: vertex 1: too few values"}},
        {"a_more.ply", verts + "3 0 1 2 5\n3 0 1 2\n", {"line 13: face 0: more values"}},
        {"a_list.ply", verts + "3 0 1 2\n4 0 1 2\n", {"line 14: face 1: list 'vertex_indices' has 3 values"}},
        {"a_index.ply", verts + "3 0 1 2\n3 0 1.5 2\n", {"line 14: face 1: vertex index '1.5' is not an integer"}},
        {"a_count.ply", verts + "3 0 1 2\n-3 0 1 2\n", {"line 14: face 1: list 'vertex_indices': count '-3'"}},
        {"a_truncated.ply", verts + "3 0 1 2\n", {"file ends after line 13, before face 1"}},
        {"a_trailing.ply", verts + "3 0 1 2\n3 0 1 2\n\n3 0 1 2\n", {"line 16: data after the last element"}},
    };
    for (const Case& c : cases) expect_rejected(c.name, head + c.body, c.needles, load_ply_file);

    // Binary negative list count (a signed count type).
    const std::string signed_count =
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list char int vertex_indices\nend_header\n";
    Bytes b(false);
    for (const Vec3& v : kTriangle) b.put(v.x).put(v.y).put(v.z);
    b.put(int8_t{-3}).put(int32_t{0}).put(int32_t{1}).put(int32_t{2});
    const std::string neg = write("neg_count.ply", signed_count + b.str());
    expect_input_error([&] { load_ply(neg); }, {neg, "face 0", "negative count -3"});
}

TEST_F(FormatFiles, MissingFiles) {
    for (const std::string name : {"missing.ply", "missing.dae", "missing.gltf", "missing.glb", "missing.off"}) {
        const std::string path = (dir_ / name).string();
        expect_input_error([&] { load_scene(path); }, {path, "cannot open"});
    }
    expect_input_error([&] { load_ply(dir_.string()); }, {dir_.string(), "cannot open"});
}

// ---------------------------------------------------------------------------
// OFF (canopy's reader); glTF, GLB, COLLADA (Assimp).

std::string base64(const std::string& bytes) {
    static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    size_t i = 0;
    for (; i + 2 < bytes.size(); i += 3) {
        const uint32_t v = (uint32_t(uint8_t(bytes[i])) << 16) | (uint32_t(uint8_t(bytes[i + 1])) << 8) |
                           uint32_t(uint8_t(bytes[i + 2]));
        for (int k = 3; k >= 0; --k) out += table[(v >> (6 * k)) & 63];
    }
    if (i + 1 == bytes.size()) {
        const uint32_t v = uint32_t(uint8_t(bytes[i])) << 16;
        out += table[(v >> 18) & 63];
        out += table[(v >> 12) & 63];
        out += "==";
    } else if (i + 2 == bytes.size()) {
        const uint32_t v = (uint32_t(uint8_t(bytes[i])) << 16) | (uint32_t(uint8_t(bytes[i + 1])) << 8);
        out += table[(v >> 18) & 63];
        out += table[(v >> 12) & 63];
        out += table[(v >> 6) & 63];
        out += '=';
    }
    return out;
}

// A unit quad (two triangles, 4 vertices) placed twice: node 0 translated by
// (10, 20, 30); node 1 translated by (0, 0, -5) with a child scaled by 2.
// `buffer_uri` empty: the buffer is the GLB binary chunk.
std::string gltf_json(const std::string& buffer_uri, size_t buffer_size) {
    const std::string uri = buffer_uri.empty() ? std::string() : ", \"uri\": \"" + buffer_uri + "\"";
    return R"({
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0, 1]}],
  "nodes": [
    {"mesh": 0, "translation": [10, 20, 30]},
    {"translation": [0, 0, -5], "children": [2]},
    {"mesh": 0, "scale": [2, 2, 2]}
  ],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 1}, "indices": 0}]}],
  "buffers": [{"byteLength": )" +
           std::to_string(buffer_size) + uri + R"(}],
  "bufferViews": [
    {"buffer": 0, "byteOffset": 0, "byteLength": 12, "target": 34963},
    {"buffer": 0, "byteOffset": 12, "byteLength": 48, "target": 34962}
  ],
  "accessors": [
    {"bufferView": 0, "componentType": 5123, "count": 6, "type": "SCALAR", "max": [3], "min": [0]},
    {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3", "max": [1, 1, 0], "min": [0, 0, 0]}
  ]
})";
}

std::string gltf_buffer() {
    Bytes b(false);
    for (uint16_t i : {0, 1, 2, 0, 2, 3}) b.put(i);
    for (const Vec3& v : {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(1, 1, 0), Vec3(0, 1, 0)}) b.put(v.x).put(v.y).put(v.z);
    return b.str();
}

void expect_placed_quads(const TriangleMesh& m) {
    ASSERT_EQ(m.triangle_count(), 4u);
    ASSERT_EQ(m.vertices.size(), 8u);  // shared within each placed mesh
    EXPECT_NO_THROW(check_mesh(m, "gltf"));
    const Vec3 corners[4] = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(1, 1, 0), Vec3(0, 1, 0)};
    const uint32_t quad[6] = {0, 1, 2, 0, 2, 3};
    // Node order: the translated quad, then the scaled one.
    for (int t = 0; t < 4; ++t) {
        for (int c = 0; c < 3; ++c) {
            const Vec3 p = corners[quad[3 * (t % 2) + c]];
            const Vec3 expected = t < 2 ? p + Vec3(10, 20, 30) : 2.0f * p + Vec3(0, 0, -5);
            EXPECT_EQ(m.vertex(t, c), expected) << "triangle " << t << " corner " << c;
        }
    }
}

TEST_F(FormatFiles, GltfWithEmbeddedBuffer) {
    const std::string buffer = gltf_buffer();
    const std::string path =
        write("quads.gltf", gltf_json("data:application/octet-stream;base64," + base64(buffer), buffer.size()));
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    const Scene s = load_scene(path);
    EXPECT_EQ(testing::internal::GetCapturedStdout(), "");
    EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
    EXPECT_EQ(s.format, "gltf");
    expect_placed_quads(s.mesh);
}

TEST_F(FormatFiles, Glb) {
    std::string json = gltf_json("", gltf_buffer().size());
    while (json.size() % 4 != 0) json += ' ';
    std::string bin = gltf_buffer();
    while (bin.size() % 4 != 0) bin += '\0';
    Bytes b(false);
    b.put(uint32_t{0x46546C67}).put(uint32_t{2}).put(uint32_t(12 + 8 + json.size() + 8 + bin.size()));
    b.put(uint32_t(json.size())).put(uint32_t{0x4E4F534A});
    std::string glb = b.str() + json;
    Bytes c(false);
    c.put(uint32_t(bin.size())).put(uint32_t{0x004E4942});
    glb += c.str() + bin;
    const Scene s = load_scene(write("quads.glb", glb));
    EXPECT_EQ(s.format, "glb");
    expect_placed_quads(s.mesh);
}

TEST_F(FormatFiles, Off) {
    const std::string path = write("shape.off",
                                   "OFF\n"
                                   "# a quad and a triangle\n"
                                   "5 2 0\n"
                                   "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2.5 -0.25 3\n"
                                   "4 0 1 2 3\n"
                                   "3 1 4 2\n");
    const Scene s = load_scene(path);
    EXPECT_EQ(s.format, "off");
    expect_mesh(s.mesh);

    // Variants: counts on the keyword's line, comments, blank lines, CRLF,
    // colors after vertices and faces (COFF), no header keyword, 4OFF.
    const std::string coff = write("SHAPE.OFF",
                                   "COFF 5 2 0 # counts here\r\n\r\n"
                                   "0 0 0 255 0 0 255\r\n1 0 0 0 255 0 255\r\n# a comment line\r\n"
                                   "1 1 0 0 0 255 255\r\n0 1 0 1 1 1 1\r\n2.5 -0.25 3 9 9 9 9\r\n"
                                   "4 0 1 2 3 0.5 0.5 0.5\r\n3 1 4 2\r\n\r\n# the end\r\n");
    expect_mesh(load_scene(coff).mesh);
    const std::string bare = write("bare.off", "5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2.5 -0.25 3\n4 0 1 2 3\n3 1 4 2\n");
    expect_mesh(load_scene(bare).mesh);
    const std::string homogeneous =
        write("w.off", "4OFF\n5 2 0\n0 0 0 1\n2 0 0 2\n1 1 0 1\n0 4 0 4\n5 -0.5 6 2\n4 0 1 2 3\n3 1 4 2\n");
    expect_mesh(load_scene(homogeneous).mesh);

    // A 12-gon (Assimp's OFF importer would drop it: more than 9 vertices).
    std::string gon = "OFF\n12 1 0\n";
    for (int i = 0; i < 12; ++i) gon += std::to_string(i) + " " + std::to_string(i * i) + " 0\n";
    gon += "12 0 1 2 3 4 5 6 7 8 9 10 11\n";
    const TriangleMesh m = load_scene(write("gon.off", gon)).mesh;
    ASSERT_EQ(m.triangle_count(), 10u);
    EXPECT_EQ(std::vector<uint32_t>(m.indices.end() - 3, m.indices.end()), (std::vector<uint32_t>{0, 10, 11}));
}

TEST_F(FormatFiles, OffErrors) {
    struct Case {
        std::string name, text;
        std::vector<std::string> needles;
    };
    const std::string v3 = "0 0 0\n1 0 0\n0 1 0\n";
    const std::vector<Case> cases = {
        {"empty.off", "", {"empty file"}},
        {"blank.off", "\n  \n", {"empty file"}},
        {"keyword.off", "OFFF\n3 1 0\n" + v3 + "3 0 1 2\n", {"line 1", "'OFFF'"}},
        {"text.off", "hello\n", {"line 1", "not an OFF file"}},
        {"nocounts.off", "OFF\n", {"line 1", "no vertex and face counts"}},
        {"badcounts.off", "OFF\n3 x 0\n", {"line 2", "expected the vertex and face counts"}},
        {"dimension.off", "nOFF 4\n3 1 0\n", {"line 1", "dimension '4'"}},
        {"nofaces.off", "OFF\n3 0 0\n" + v3, {"line 2", "no triangles"}},
        {"huge.off", "OFF\n3000000 1 0\n" + v3 + "3 0 1 2\n", {"line 2", "inconsistent with the file size"}},
        {"range.off", "OFF\n3 2 0\n" + v3 + "3 0 1 2\n3 0 1 3\n",
         {"line 7: face 1: vertex index 3 out of range (3 vertices)"}},
        {"negative.off", "OFF\n3 1 0\n" + v3 + "3 0 -1 2\n", {"line 6: face 0: vertex index -1 out of range"}},
        {"short.off", "OFF\n3 1 0\n" + v3 + "2 0 1\n", {"line 6: face 0 has 2 vertices (needs at least 3)"}},
        {"few.off", "OFF\n3 1 0\n" + v3 + "4 0 1 2\n", {"line 6: face 0 has 3 indices, its count says 4"}},
        {"index.off", "OFF\n3 1 0\n" + v3 + "3 0 x 2\n", {"line 6: face 0: vertex index 'x' is not an integer"}},
        {"coords.off", "OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", {"line 4: vertex 1 has 2 coordinates"}},
        {"word.off", "OFF\n3 1 0\n0 0 0\n1 0 zero\n0 1 0\n3 0 1 2\n", {"line 4: vertex 1: coordinate 'zero'"}},
        {"nan.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
         {"line 4: vertex 1 has a non-finite coordinate (1, nan, 0)"}},
        {"truncated.off", "OFF\n3 2 0\n" + v3 + "3 0 1 2\n", {"file ends after line 6, before face 1"}},
        {"trailing.off", "OFF\n3 1 0\n" + v3 + "3 0 1 2\n3 0 1 2\n", {"line 7: data after the last face"}},
    };
    for (const Case& c : cases) expect_rejected(c.name, c.text, c.needles, load_any);
}

TEST_F(FormatFiles, ColladaNodeMatricesAreApplied) {
    // One triangle instanced twice: as is, and through a node <matrix>
    // (row-major: translate by (1, 2, 3) and swap x and y). Z_UP is not
    // rotated away: coordinates stay in the file's axes.
    const std::string dae = R"(<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries>
    <geometry id="tri" name="tri">
      <mesh>
        <source id="tri-positions">
          <float_array id="tri-positions-array" count="9">0 0 0 1 0 0 0 1 0.5</float_array>
          <technique_common>
            <accessor source="#tri-positions-array" count="3" stride="3">
              <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
            </accessor>
          </technique_common>
        </source>
        <vertices id="tri-vertices"><input semantic="POSITION" source="#tri-positions"/></vertices>
        <triangles count="1"><input semantic="VERTEX" source="#tri-vertices" offset="0"/><p>0 1 2</p></triangles>
      </mesh>
    </geometry>
  </library_geometries>
  <library_visual_scenes>
    <visual_scene id="Scene" name="Scene">
      <node id="a" name="a"><instance_geometry url="#tri"/></node>
      <node id="b" name="b">
        <matrix sid="transform">0 1 0 1 1 0 0 2 0 0 1 3 0 0 0 1</matrix>
        <instance_geometry url="#tri"/>
      </node>
    </visual_scene>
  </library_visual_scenes>
  <scene><instance_visual_scene url="#Scene"/></scene>
</COLLADA>
)";
    const Scene s = load_scene(write("two.dae", dae));
    EXPECT_EQ(s.format, "dae");
    ASSERT_EQ(s.mesh.triangle_count(), 2u);
    const Vec3 tri[3] = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0.5f)};
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(s.mesh.vertex(0, c), tri[c]);
        EXPECT_EQ(s.mesh.vertex(1, c), Vec3(tri[c].y + 1, tri[c].x + 2, tri[c].z + 3));
    }
}

TEST_F(FormatFiles, AssimpErrorsNameTheFile) {
    struct Case {
        std::string name, text;
        std::vector<std::string> needles;
    };
    const std::vector<Case> cases = {
        {"broken.gltf", "{ this is not json", {"Assimp"}},
        {"broken.dae", "<?xml version=\"1.0\"?>\n<COLLADA><library_geometries>", {"Assimp"}},
        {"garbage.glb", "glTF\x02\0\0\0garbage", {"Assimp"}},
        {"nomesh.gltf", R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"name": "empty"}]})",
         {"no triangles"}},
        {"empty.dae", "", {}},
    };
    for (const Case& c : cases) {
        testing::internal::CaptureStdout();
        testing::internal::CaptureStderr();
        expect_rejected(c.name, c.text, c.needles, load_any);
        EXPECT_EQ(testing::internal::GetCapturedStdout(), "") << c.name;
        EXPECT_EQ(testing::internal::GetCapturedStderr(), "") << c.name;
    }
}

// ---------------------------------------------------------------------------
// The shared scenes (MANIFEST.md in CANOPY_SCENES_DIR).

class SharedScenes : public ::testing::Test {
protected:
    void SetUp() override {
        dir_ = CANOPY_SCENES_DIR;
        if (!fs::is_directory(dir_)) GTEST_SKIP() << "no shared scenes at " << dir_;
    }
    std::string path(const std::string& name) const { return (dir_ / name).string(); }
    fs::path dir_;
};

void expect_same_triangles(const TriangleMesh& a, const TriangleMesh& b, float tolerance) {
    ASSERT_EQ(a.triangle_count(), b.triangle_count());
    size_t differ = 0;
    for (size_t t = 0; t < a.triangle_count(); ++t) {
        for (int c = 0; c < 3; ++c) {
            const Vec3 p = a.vertex(t, c), q = b.vertex(t, c);
            for (int k = 0; k < 3; ++k) differ += !(std::abs(p[k] - q[k]) <= tolerance);
        }
    }
    EXPECT_EQ(differ, 0u);
}

TEST_F(SharedScenes, StanfordPly) {
    const Scene bunny = load_scene(path("bun_zipper.ply"));
    EXPECT_EQ(bunny.format, "ply");
    EXPECT_EQ(bunny.mesh.triangle_count(), 69451u);
    EXPECT_EQ(bunny.mesh.vertices.size(), 35947u);
    EXPECT_NO_THROW(check_mesh(bunny.mesh, "bunny"));
    const Box bb = bounds(bunny.mesh);
    EXPECT_EQ(bb.lo, Vec3(-0.0946899f, 0.0329874f, -0.0618736f));
    EXPECT_EQ(bb.hi, Vec3(0.0610091f, 0.187321f, 0.0587997f));

    const Scene dragon = load_scene(path("dragon_vrip_res2.ply"));
    EXPECT_EQ(dragon.mesh.triangle_count(), 202520u);
    EXPECT_EQ(dragon.mesh.vertices.size(), 100250u);
    EXPECT_NO_THROW(check_mesh(dragon.mesh, "dragon"));
    const Box db = bounds(dragon.mesh);
    EXPECT_EQ(db.lo, Vec3(-0.108188f, 0.0527392f, -0.0503454f));
    EXPECT_EQ(db.hi, Vec3(0.0964062f, 0.197139f, 0.0411367f));

    // The small dragon: the same arrays as its OBJ twin.
    const TriangleMesh ply = load_ply(path("dragon_vrip_res3.ply"));
    const TriangleMesh obj = load_obj(path("dragon_vrip_res3.obj"));
    EXPECT_EQ(ply.triangle_count(), 47794u);
    EXPECT_EQ(ply.indices, obj.indices);
    EXPECT_EQ(ply.vertices, obj.vertices);
}

TEST_F(SharedScenes, Collada) {
    const Scene cow = load_scene(path("cow.dae"));
    EXPECT_EQ(cow.format, "dae");
    EXPECT_EQ(cow.mesh.triangle_count(), 5856u);
    EXPECT_EQ(cow.mesh.vertices.size(), 2930u);
    const TriangleMesh cow_obj = load_obj(path("cow.obj"));
    const Box a = bounds(cow.mesh), b = bounds(cow_obj);
    EXPECT_EQ(a.lo, b.lo);
    EXPECT_EQ(a.hi, b.hi);
    expect_same_triangles(cow.mesh, cow_obj, 0.0f);  // exactly, in order

    const Scene coil = load_scene(path("CBcoil.dae"));
    EXPECT_EQ(coil.mesh.triangle_count(), 7884u);
    EXPECT_EQ(coil.mesh.vertices.size(), 3962u);
    const TriangleMesh coil_obj = load_obj(path("CBcoil.obj"));
    // The transforms are applied in double from Assimp's float matrices,
    // the OBJ from the decimal ones: equal within a few ulps.
    const Box c = bounds(coil.mesh), d = bounds(coil_obj);
    for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(c.lo[k], d.lo[k], 1e-6);
        EXPECT_NEAR(c.hi[k], d.hi[k], 1e-6);
    }
    expect_same_triangles(coil.mesh, coil_obj, 1e-6f);
}

}  // namespace
}  // namespace canopy
