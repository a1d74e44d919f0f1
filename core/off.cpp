// canopy: the OFF (Object File Format) reader, written here: Assimp's OFF
// importer clamps out-of-range indices to the last vertex, drops faces of
// more than 9 vertices, and reads comment and blank-looking lines as
// vertices, all silently.
//
//   [ST][C][N][4][n]OFF        header keyword (optional, as in geomview)
//   [dimension]                with the n prefix (3 only)
//   vertices faces [edges]     may follow the keyword on its line
//   x y z [w] [more ...]       one vertex per line (4: divided by w)
//   n i0 i1 ... [color ...]    one face per line, indices 0-based
//
// '#' starts a comment anywhere; blank lines are skipped. Faces are
// triangulated as fans (i0, ik, ik+1); whatever follows a vertex's
// coordinates or a face's indices on its line (normals, colors, texture
// coordinates) is ignored.
#include "off.h"

#include "error.h"
#include "file_read.h"
#include "reader_util.h"

#include <string_view>
#include <vector>

namespace canopy {

using input::format_vec;
using input::is_finite;
using input::make_vec;
using input::parse_coordinate;
using input::parse_u64;
using input::push_triangle;
using input::quote;
using input::split_tokens;

TriangleMesh load_off(const std::string& path) {
    const std::string text = read_whole_file(path);
    if (text.find_first_not_of(" \t\r\n") == std::string::npos) throw InputError(path + ": empty file");

    struct Line {
        size_t number;
        std::string_view text;
    };
    size_t pos = 0, line_no = 0;
    // The next line with a token on it, comments removed; false at the end.
    const auto next_line = [&](Line& out) {
        const std::string_view all(text);
        while (pos < all.size()) {
            size_t end = all.find_first_of("\r\n", pos);
            if (end == std::string_view::npos) end = all.size();
            std::string_view line = all.substr(pos, end - pos);
            pos = end;
            if (pos < all.size()) pos += (all[pos] == '\r' && pos + 1 < all.size() && all[pos + 1] == '\n') ? 2 : 1;
            ++line_no;
            line = line.substr(0, line.find('#'));
            if (line.find_first_not_of(" \t") != std::string_view::npos) {  // as split_tokens
                out = {line_no, line};
                return true;
            }
        }
        return false;
    };
    const auto fail = [&](size_t line, const std::string& what) {
        throw InputError(path + ": line " + std::to_string(line) + ": " + what);
    };

    std::vector<std::string_view> tokens;
    Line line{};
    if (!next_line(line)) throw InputError(path + ": no data (only comments and blank lines)");
    split_tokens(line.text, tokens);
    size_t first = 0;  // first count token on the line
    bool homogeneous = false;
    if (std::string_view keyword = tokens[0]; keyword.ends_with("OFF")) {
        keyword.remove_suffix(3);
        for (const std::string_view prefix : {"ST", "C", "N", "4", "n"}) {
            if (keyword.starts_with(prefix)) {
                keyword.remove_prefix(prefix.size());
                if (prefix == "4") homogeneous = true;
                if (prefix == "n") {
                    // The dimension follows the keyword.
                    first = 1;
                    if (tokens.size() == 1) {
                        if (!next_line(line)) fail(line.number, "no dimension after " + quote(tokens[0]));
                        split_tokens(line.text, tokens);
                        first = 0;
                    }
                    uint64_t dimension = 0;
                    if (!parse_u64(tokens[first], dimension) || dimension != 3)
                        fail(line.number, "dimension " + quote(tokens[first]) + " is not supported (only 3)");
                    ++first;
                }
            }
        }
        if (!keyword.empty()) fail(line.number, "unknown header keyword " + quote(tokens[0]));
        if (first == 0) first = 1;
        if (first == tokens.size()) {
            if (!next_line(line)) fail(line.number, "no vertex and face counts after the header");
            split_tokens(line.text, tokens);
            first = 0;
        }
    } else if (tokens[0].empty() || tokens[0][0] < '0' || tokens[0][0] > '9') {
        fail(line.number, "not an OFF file: " + quote(tokens[0]) + " is neither a header keyword nor a count");
    }
    uint64_t counts[2] = {0, 0};
    for (int k = 0; k < 2; ++k) {
        if (first + k >= tokens.size() || !parse_u64(tokens[first + k], counts[k]))
            fail(line.number, "expected the vertex and face counts, found " + quote(line.text));
    }
    if (tokens.size() > first + 3) fail(line.number, "more than three counts (vertices faces edges)");
    const uint64_t vertex_count = counts[0], face_count = counts[1];
    if (face_count == 0) fail(line.number, "no triangles: the header declares 0 faces");
    // Every vertex line takes at least 6 bytes ("0 0 0\n"), every face
    // line 7 ("3 0 0 0"), which bounds what the counts may claim.
    const uint64_t size = text.size();
    if (vertex_count > size / 6 || face_count > size / 7 || vertex_count * 6 + face_count * 7 > size + 1)
        fail(line.number, "counts " + std::to_string(vertex_count) + " vertices, " + std::to_string(face_count) +
                              " faces are inconsistent with the file size (" + std::to_string(size) + " bytes)");
    if (vertex_count > std::numeric_limits<uint32_t>::max())
        fail(line.number, std::to_string(vertex_count) + " vertices: more than 32-bit indices can address");

    TriangleMesh mesh;
    mesh.vertices.reserve(static_cast<size_t>(vertex_count));
    mesh.indices.reserve(3 * static_cast<size_t>(face_count));
    // The tokens of the line of element `index` (of `count`) of a `kind`, or
    // an error if the file ends before it. Element names ("vertex 12") are
    // formatted only for an error.
    const auto element_tokens = [&](const char* kind, uint64_t index, uint64_t count) {
        if (!next_line(line))
            throw InputError(path + ": file ends after line " + std::to_string(line_no) + ", before " + kind + " " +
                             std::to_string(index) + " (of " + std::to_string(count) +
                             "): truncated, or the header's counts are wrong");
        split_tokens(line.text, tokens);
    };
    const size_t need = homogeneous ? 4 : 3;
    for (uint64_t v = 0; v < vertex_count; ++v) {
        element_tokens("vertex", v, vertex_count);
        const auto bad = [&](const std::string& what) { fail(line.number, "vertex " + std::to_string(v) + what); };
        if (tokens.size() < need)
            bad(" has " + std::to_string(tokens.size()) + " coordinates (needs " +
                (homogeneous ? "x y z w)" : "x y z)"));
        float xyzw[4] = {0.0f, 0.0f, 0.0f, 1.0f};
        for (size_t k = 0; k < need; ++k) {
            if (!parse_coordinate(tokens[k], xyzw[k])) bad(": coordinate " + quote(tokens[k]) + " is not a number");
        }
        Vec3 p(xyzw[0], xyzw[1], xyzw[2]);
        if (homogeneous) p = make_vec(double(p.x) / xyzw[3], double(p.y) / xyzw[3], double(p.z) / xyzw[3]);
        if (!is_finite(p)) bad(" has a non-finite coordinate " + format_vec(p));
        mesh.vertices.push_back(p);
    }
    for (uint64_t f = 0; f < face_count; ++f) {
        element_tokens("face", f, face_count);
        const auto bad = [&](const std::string& what) { fail(line.number, "face " + std::to_string(f) + what); };
        uint64_t n = 0;
        if (!parse_u64(tokens[0], n)) bad(": vertex count " + quote(tokens[0]) + " is not a number");
        if (n < 3) bad(" has " + std::to_string(n) + " vertices (needs at least 3)");
        if (tokens.size() - 1 < n)
            bad(" has " + std::to_string(tokens.size() - 1) + " indices, its count says " + std::to_string(n));
        uint32_t corner[3] = {0, 0, 0};
        for (uint64_t k = 0; k < n; ++k) {
            const std::string_view token = tokens[1 + k];
            uint64_t index = 0;
            if (!parse_u64(token, index)) {
                if (token.starts_with('-') && token.size() > 1 && parse_u64(token.substr(1), index))
                    bad(": vertex index " + std::string(token) + " out of range (" + std::to_string(vertex_count) +
                        " vertices)");
                bad(": vertex index " + quote(token) + " is not an integer");
            }
            if (index >= vertex_count)
                bad(": vertex index " + std::to_string(index) + " out of range (" + std::to_string(vertex_count) +
                    " vertices)");
            if (k == 0) corner[0] = static_cast<uint32_t>(index);
            corner[2] = static_cast<uint32_t>(index);
            if (k >= 2) push_triangle(mesh, corner[0], corner[1], corner[2]);
            corner[1] = corner[2];
        }
    }
    if (next_line(line))
        fail(line.number, "data after the last face: the header's counts are inconsistent with the file");
    return mesh;
}

}  // namespace canopy
