// canopy: the OBJ reader.
//
// tinyobjloader does the parsing and triangulation, but it accepts a lot
// silently: "nan" parses as 0, a missing coordinate defaults to 0, a face
// with fewer than 3 vertices is dropped with a warning, an out-of-range index
// in a triangle is passed through. So the text is scanned first, with line
// numbers, and the loader's output is then checked against the scan.
#include "scene.h"

#include "error.h"
#include "file_read.h"
#include "reader_util.h"

#include <tiny_obj_loader.h>

#include <algorithm>
#include <charconv>
#include <istream>
#include <streambuf>
#include <string_view>
#include <system_error>
#include <vector>

namespace canopy {
namespace {

using input::format_vec;
using input::is_finite;
using input::parse_coordinate;
using input::quote;
using input::split_tokens;
using input::trim_message;

[[noreturn]] void obj_error(const std::string& path, size_t line, const std::string& what) {
    throw InputError(path + ": line " + std::to_string(line) + ": " + what);
}

// A nonzero OBJ index ("7", "-3", "+2").
bool parse_index(std::string_view text, long long& out) {
    if (text.size() > 1 && text[0] == '+' && text[1] != '-') text.remove_prefix(1);
    const char* last = text.data() + text.size();
    const auto res = std::from_chars(text.data(), last, out);
    return res.ec == std::errc() && res.ptr == last;
}

// One corner of a face: v, v/vt, v//vn or v/vt/vn. Only v is used; vt and vn
// must be well formed (tinyobjloader rejects a zero there).
bool parse_corner(std::string_view corner, long long& v) {
    const size_t slash = corner.find('/');
    if (!parse_index(corner.substr(0, slash), v)) return false;
    if (slash == std::string_view::npos) return true;
    std::string_view rest = corner.substr(slash + 1);
    long long other = 0;
    if (!rest.empty() && rest[0] == '/')  // v//vn
        return parse_index(rest.substr(1), other) && other != 0;
    const size_t slash2 = rest.find('/');
    if (!parse_index(rest.substr(0, slash2), other) || other == 0) return false;  // vt
    if (slash2 == std::string_view::npos) return true;
    return parse_index(rest.substr(slash2 + 1), other) && other != 0;  // vn
}

struct ObjScan {
    std::vector<size_t> vertex_lines;  // line of each `v` statement
    uint64_t faces = 0;
    uint64_t triangles = 0;  // as a fan triangulation gives: corners - 2 per face
    size_t lines = 0;
};

ObjScan scan_obj(const std::string& path, const std::string& text) {
    struct ForwardRef {
        size_t line;
        uint64_t face;
        long long index;
    };
    ObjScan scan;
    std::vector<ForwardRef> forward_refs;  // faces with indices beyond the vertices read so far
    std::vector<std::string_view> tokens;
    const std::string_view all(text);
    size_t pos = 0;
    size_t line_no = 0;
    while (pos < all.size()) {
        // Line ends as in tinyobjloader: "\n", "\r\n" or "\r".
        size_t end = all.find_first_of("\r\n", pos);
        if (end == std::string_view::npos) end = all.size();
        const std::string_view line = all.substr(pos, end - pos);
        pos = end;
        if (pos < all.size()) pos += (all[pos] == '\r' && pos + 1 < all.size() && all[pos + 1] == '\n') ? 2 : 1;
        ++line_no;

        if (line.find('\0') != std::string_view::npos)
            obj_error(path, line_no, "binary data (NUL byte): not an OBJ text file, no triangles read");

        split_tokens(line, tokens);
        if (tokens.empty() || tokens[0][0] == '#') continue;
        const std::string_view keyword = tokens[0];

        if (keyword == "v") {
            const size_t vertex = scan.vertex_lines.size() + 1;  // 1-based, as in OBJ
            const auto bad = [&](const std::string& what) {
                obj_error(path, line_no, "vertex " + std::to_string(vertex) + what);
            };
            if (tokens.size() < 4) bad(" has " + std::to_string(tokens.size() - 1) + " coordinates (needs x y z)");
            float xyz[3];
            for (int k = 0; k < 3; ++k) {
                if (!parse_coordinate(tokens[1 + k], xyz[k]))
                    bad(": coordinate " + quote(tokens[1 + k]) + " is not a number");
            }
            const Vec3 p(xyz[0], xyz[1], xyz[2]);
            if (!is_finite(p)) bad(" has a non-finite coordinate " + format_vec(p));
            scan.vertex_lines.push_back(line_no);
        } else if (keyword == "f") {
            ++scan.faces;
            const auto bad = [&](const std::string& what) {
                obj_error(path, line_no, "face " + std::to_string(scan.faces) + what);
            };
            const size_t corners = tokens.size() - 1;
            if (corners < 3) bad(" has " + std::to_string(corners) + " vertices (needs at least 3)");
            const long long defined = static_cast<long long>(scan.vertex_lines.size());
            long long max_forward = 0;
            for (size_t k = 1; k < tokens.size(); ++k) {
                long long index = 0;
                if (!parse_corner(tokens[k], index)) bad(": malformed vertex reference " + quote(tokens[k]));
                if (index == 0) bad(": vertex index 0 (OBJ indices start at 1)");
                if (index < 0 && defined + index < 0)
                    bad(": relative vertex index " + std::to_string(index) + " out of range (" +
                        std::to_string(defined) + " vertices defined before this line)");
                if (index > defined) max_forward = std::max(max_forward, index);
            }
            if (max_forward > 0) forward_refs.push_back({line_no, scan.faces, max_forward});
            scan.triangles += corners - 2;
        } else if (keyword == "vw") {
            // Skin weights, a tinyobjloader extension canopy does not use:
            // "vw vertex joint weight joint weight ...". tinyobjloader casts
            // each joint id, read as a float, to int without a range check
            // (undefined behaviour beyond int, found by fuzzing), so ids
            // must be numbers below 2^30 (far from int's limit whatever the
            // rounding of its own parser); negative ones it rejects itself.
            for (size_t k = 2; k < tokens.size(); k += 2) {
                float id = 0.0f;
                if (!parse_coordinate(tokens[k], id) || !(id < 0x1p30f))
                    obj_error(path, line_no, "skin weight (vw): joint id " + quote(tokens[k]) +
                                                 " is not a number below 2^30");
            }
        }
        // Everything else (vn, vt, g, o, s, usemtl, mtllib, l, p, ...) is
        // left to tinyobjloader; none of it changes the triangles.
    }
    scan.lines = line_no;
    // Positive indices may refer to vertices defined later in the file (as
    // tinyobjloader allows), so they are checked against the final count.
    const long long total = static_cast<long long>(scan.vertex_lines.size());
    for (const ForwardRef& r : forward_refs) {
        if (r.index > total)
            obj_error(path, r.line,
                      "face " + std::to_string(r.face) + ": vertex index " + std::to_string(r.index) +
                          " out of range (file has " + std::to_string(total) + " vertices)");
    }
    return scan;
}

// An istream over a string the caller owns, without copying it.
class MemoryBuffer : public std::streambuf {
public:
    explicit MemoryBuffer(std::string& text) { setg(text.data(), text.data(), text.data() + text.size()); }
};

}  // namespace

TriangleMesh load_obj(const std::string& path) {
    std::string text = read_whole_file(path);
    if (text.find_first_not_of(" \t\r\n") == std::string::npos)
        throw InputError(path + ": no triangles (empty file)");

    const ObjScan scan = scan_obj(path, text);
    if (scan.triangles == 0)
        throw InputError(path + ": no triangles (" + std::to_string(scan.vertex_lines.size()) + " vertices, " +
                         std::to_string(scan.faces) + " faces in " + std::to_string(scan.lines) + " lines)");

    tinyobj::attrib_t attrib;
    std::vector<tinyobj::shape_t> shapes;
    std::vector<tinyobj::material_t> materials;
    std::string warning, error;
    MemoryBuffer buffer(text);
    std::istream stream(&buffer);
    // No material reader: positions only, and no other files are opened.
    const bool ok = tinyobj::LoadObj(&attrib, &shapes, &materials, &warning, &error, &stream,
                                     /*readMatFn=*/nullptr, /*triangulate=*/true,
                                     /*default_vcols_fallback=*/false);
    if (!ok) throw InputError(path + ": tinyobjloader: " + trim_message(error));
    // Warnings that mean geometry was dropped or is wrong (the scan should
    // have caught these first); others (materials, normals, texcoords) are
    // irrelevant to positions.
    for (const char* bad : {"Degenerated face", "invalid vertex index", "Vertex indices out of bounds"}) {
        if (warning.find(bad) != std::string::npos)
            throw InputError(path + ": tinyobjloader: " + trim_message(warning));
    }

    const size_t vertex_count = attrib.vertices.size() / 3;
    if (vertex_count != scan.vertex_lines.size())
        throw InputError(path + ": tinyobjloader read " + std::to_string(vertex_count) + " vertices but the file has " +
                         std::to_string(scan.vertex_lines.size()) + " 'v' lines");

    TriangleMesh mesh;
    mesh.vertices.resize(vertex_count);
    for (size_t i = 0; i < vertex_count; ++i) {
        const Vec3 p(static_cast<float>(attrib.vertices[3 * i]), static_cast<float>(attrib.vertices[3 * i + 1]),
                     static_cast<float>(attrib.vertices[3 * i + 2]));
        if (!is_finite(p))
            obj_error(path, scan.vertex_lines[i],
                      "vertex " + std::to_string(i + 1) + " has a non-finite coordinate " + format_vec(p));
        mesh.vertices[i] = p;
    }

    size_t index_count = 0;
    for (const tinyobj::shape_t& shape : shapes) index_count += shape.mesh.indices.size();
    mesh.indices.reserve(index_count);
    for (const tinyobj::shape_t& shape : shapes) {
        for (const tinyobj::index_t& idx : shape.mesh.indices) {
            if (idx.vertex_index < 0 || static_cast<size_t>(idx.vertex_index) >= vertex_count)
                throw InputError(path + ": triangle " + std::to_string(mesh.indices.size() / 3) + ": vertex index " +
                                 std::to_string(idx.vertex_index) + " out of range (" + std::to_string(vertex_count) +
                                 " vertices)");
            mesh.indices.push_back(static_cast<uint32_t>(idx.vertex_index));
        }
    }
    if (mesh.indices.size() % 3 != 0 || mesh.triangle_count() != scan.triangles)
        throw InputError(path + ": tinyobjloader produced " + std::to_string(mesh.indices.size()) +
                         " triangle corners, but the " + std::to_string(scan.faces) + " faces make " +
                         std::to_string(scan.triangles) + " triangles (a polygon could not be triangulated)");
    return mesh;
}

}  // namespace canopy
