// canopy: scene input. Mesh files and seeded generators.
#include "scene.h"

#include "error.h"
#include "file_read.h"
#include "ply.h"
#include "rng.h"

#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <tiny_obj_loader.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <istream>
#include <iterator>
#include <limits>
#include <numbers>
#include <random>
#include <streambuf>
#include <string_view>
#include <system_error>
#include <unordered_map>
#include <utility>

namespace canopy {
namespace {

constexpr const char* kDefaultSceneSpec = "gen:sphere:100000";
constexpr std::string_view kGeneratorPrefix = "gen:";
constexpr uint64_t kMaxGeneratorCount = 100'000'000;

// ---------------------------------------------------------------------------
// Formatting helpers (no iostreams: locale-independent, shortest round trip).

std::string format_float(float v) {
    char buf[64];
    const auto res = std::to_chars(buf, buf + sizeof buf, v);
    return std::string(buf, res.ptr);
}

std::string format_vec(const Vec3& p) {
    return "(" + format_float(p.x) + ", " + format_float(p.y) + ", " + format_float(p.z) + ")";
}

bool is_finite(const Vec3& p) {
    return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
}

// ---------------------------------------------------------------------------
// Generators.
//
// Every generator is a pure function of (count, seed). Randomness comes from
// Rng (core/rng.h), the same numbers on every platform. Coordinates are
// computed in double and rounded once to float.

Vec3 make_vec(double x, double y, double z) {
    return Vec3(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
}

void push_triangle(TriangleMesh& mesh, uint64_t a, uint64_t b, uint64_t c) {
    mesh.indices.push_back(static_cast<uint32_t>(a));
    mesh.indices.push_back(static_cast<uint32_t>(b));
    mesh.indices.push_back(static_cast<uint32_t>(c));
}

uint64_t round_at_least(double v, uint64_t lo) {
    const double r = std::round(v);
    return r < static_cast<double>(lo) ? lo : static_cast<uint64_t>(r);
}

// Latitude/longitude sphere of about `count` triangles, appended to `mesh`.
// `stacks` latitude bands (>= 2), `slices` longitude segments (>= 3): one
// vertex per pole, stacks - 1 rings of `slices` shared vertices, triangle fans
// at the poles and two triangles per quad elsewhere, wound counter-clockwise
// seen from outside. 2 * slices * (stacks - 1) triangles, none degenerate.
void append_sphere(TriangleMesh& mesh, uint64_t count, double radius) {
    // With slices ~ 2 * stacks the quads are roughly square:
    // 4 * stacks * (stacks - 1) ~ count.
    const uint64_t stacks =
        round_at_least(0.5 + std::sqrt(0.25 + static_cast<double>(count) / 4.0), 2);
    const uint64_t slices =
        round_at_least(static_cast<double>(count) / (2.0 * static_cast<double>(stacks - 1)), 3);
    const uint64_t rings = stacks - 1;

    const uint64_t base = mesh.vertices.size();
    mesh.vertices.reserve(base + 2 + rings * slices);
    mesh.indices.reserve(mesh.indices.size() + 3 * 2 * slices * rings);

    const double pi = std::numbers::pi;
    const uint64_t north = base;
    mesh.vertices.push_back(make_vec(0.0, 0.0, radius));
    for (uint64_t r = 1; r <= rings; ++r) {
        const double theta = pi * static_cast<double>(r) / static_cast<double>(stacks);
        const double z = radius * std::cos(theta);
        const double ring_radius = radius * std::sin(theta);
        for (uint64_t j = 0; j < slices; ++j) {
            const double phi = 2.0 * pi * static_cast<double>(j) / static_cast<double>(slices);
            mesh.vertices.push_back(
                make_vec(ring_radius * std::cos(phi), ring_radius * std::sin(phi), z));
        }
    }
    const uint64_t south = mesh.vertices.size();
    mesh.vertices.push_back(make_vec(0.0, 0.0, -radius));

    auto ring_vertex = [&](uint64_t r, uint64_t j) { return base + 1 + (r - 1) * slices + j % slices; };

    for (uint64_t j = 0; j < slices; ++j) push_triangle(mesh, north, ring_vertex(1, j), ring_vertex(1, j + 1));
    for (uint64_t r = 1; r < rings; ++r) {
        for (uint64_t j = 0; j < slices; ++j) {
            const uint64_t a0 = ring_vertex(r, j), a1 = ring_vertex(r, j + 1);
            const uint64_t b0 = ring_vertex(r + 1, j), b1 = ring_vertex(r + 1, j + 1);
            push_triangle(mesh, a0, b0, b1);
            push_triangle(mesh, a0, b1, a1);
        }
    }
    for (uint64_t j = 0; j < slices; ++j) push_triangle(mesh, south, ring_vertex(rings, j + 1), ring_vertex(rings, j));
}

TriangleMesh generate_sphere(uint64_t count, uint64_t /*seed*/) {
    TriangleMesh mesh;
    append_sphere(mesh, count, 1.0);
    return mesh;
}

// `count` small triangles, each with its own three vertices, inside [0, 1]^3:
// a centre uniform in the cube shrunk by half the triangle scale s =
// 1 / cbrt(count), and three corners offset uniformly in [-s/2, s/2]^3.
TriangleMesh generate_random(uint64_t count, uint64_t seed) {
    Rng rng(seed);
    const double s = std::min(1.0, 1.0 / std::cbrt(static_cast<double>(count)));
    TriangleMesh mesh;
    mesh.vertices.reserve(3 * count);
    mesh.indices.reserve(3 * count);
    for (uint64_t t = 0; t < count; ++t) {
        double centre[3];
        for (double& c : centre) c = 0.5 * s + (1.0 - s) * rng.uniform();
        for (int corner = 0; corner < 3; ++corner) {
            double p[3];
            for (int axis = 0; axis < 3; ++axis) p[axis] = centre[axis] + s * (rng.uniform() - 0.5);
            mesh.vertices.push_back(make_vec(p[0], p[1], p[2]));
        }
        push_triangle(mesh, 3 * t, 3 * t + 1, 3 * t + 2);
    }
    return mesh;
}

// A `cells` x `cells` grid of quads on each face of the cube [-h, h]^3,
// wound counter-clockwise seen from outside; vertices shared within a face.
void append_box(TriangleMesh& mesh, uint64_t cells, double h) {
    for (int axis = 0; axis < 3; ++axis) {
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        for (const double side : {-1.0, 1.0}) {
            const uint64_t base = mesh.vertices.size();
            for (uint64_t i = 0; i <= cells; ++i) {
                for (uint64_t j = 0; j <= cells; ++j) {
                    double p[3];
                    p[axis] = side * h;
                    p[u] = -h + 2.0 * h * static_cast<double>(i) / static_cast<double>(cells);
                    p[v] = -h + 2.0 * h * static_cast<double>(j) / static_cast<double>(cells);
                    mesh.vertices.push_back(make_vec(p[0], p[1], p[2]));
                }
            }
            auto at = [&](uint64_t i, uint64_t j) { return base + i * (cells + 1) + j; };
            for (uint64_t i = 0; i < cells; ++i) {
                for (uint64_t j = 0; j < cells; ++j) {
                    // (u, v, axis) is right-handed: counter-clockwise in (u, v)
                    // faces +axis, so flip the winding on the -axis face.
                    if (side > 0) {
                        push_triangle(mesh, at(i, j), at(i + 1, j), at(i + 1, j + 1));
                        push_triangle(mesh, at(i, j), at(i + 1, j + 1), at(i, j + 1));
                    } else {
                        push_triangle(mesh, at(i, j), at(i + 1, j + 1), at(i + 1, j));
                        push_triangle(mesh, at(i, j), at(i, j + 1), at(i + 1, j + 1));
                    }
                }
            }
        }
    }
}

// A dense unit sphere (about 97% of the triangles) inside a box of side 1000
// centred on it, made of 12 * cells^2 large triangles (the other ~3%).
TriangleMesh generate_stadium(uint64_t count, uint64_t /*seed*/) {
    const uint64_t cells = round_at_least(std::sqrt(0.03 * static_cast<double>(count) / 12.0), 1);
    const uint64_t box_triangles = 12 * cells * cells;
    const uint64_t sphere_triangles = count > box_triangles ? count - box_triangles : 1;
    TriangleMesh mesh;
    append_sphere(mesh, sphere_triangles, 1.0);
    append_box(mesh, cells, 500.0);
    return mesh;
}

// A room like the Cornell box scenes: five walls of [-1, 1]^3 (floor,
// ceiling, back, left, right; the front open), each one quad of two large
// triangles, a small light quad just below the ceiling, and a dense sphere of
// radius 0.3 floating in the middle (count - 12 triangles, about). Twelve
// primitives far larger than all the others, with centroids among theirs:
// the case the size split is for (see SizeCuts in kernel/size_split.h).
TriangleMesh generate_room(uint64_t count, uint64_t /*seed*/) {
    TriangleMesh mesh;
    append_sphere(mesh, count > 12 ? count - 12 : 1, 0.3);
    for (Vec3& v : mesh.vertices) v += Vec3(0.05f, -0.1f, -0.15f);
    // Quad corners counter-clockwise seen from inside the room.
    const double quads[6][4][3] = {
        {{-1, -1, -1}, {-1, -1, 1}, {1, -1, 1}, {1, -1, -1}},                  // floor
        {{-1, 1, -1}, {1, 1, -1}, {1, 1, 1}, {-1, 1, 1}},                      // ceiling
        {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1}},                  // back
        {{-1, -1, -1}, {-1, 1, -1}, {-1, 1, 1}, {-1, -1, 1}},                  // left
        {{1, -1, -1}, {1, -1, 1}, {1, 1, 1}, {1, 1, -1}},                      // right
        {{-0.4, 0.98, -0.3}, {0.4, 0.98, -0.3}, {0.4, 0.98, 0.3}, {-0.4, 0.98, 0.3}},  // light
    };
    for (const auto& q : quads) {
        const uint64_t base = mesh.vertices.size();
        for (const auto& p : q) mesh.vertices.push_back(make_vec(p[0], p[1], p[2]));
        push_triangle(mesh, base, base + 1, base + 2);
        push_triangle(mesh, base, base + 2, base + 3);
    }
    return mesh;
}

// An nx x ny grid of quads (two triangles each) over [-1, 1]^2 in z = 0.
TriangleMesh generate_plane(uint64_t count, uint64_t /*seed*/) {
    const uint64_t nx = round_at_least(std::sqrt(static_cast<double>(count) / 2.0), 1);
    const uint64_t ny = round_at_least(static_cast<double>(count) / (2.0 * static_cast<double>(nx)), 1);
    TriangleMesh mesh;
    mesh.vertices.reserve((nx + 1) * (ny + 1));
    mesh.indices.reserve(6 * nx * ny);
    for (uint64_t i = 0; i <= nx; ++i) {
        for (uint64_t j = 0; j <= ny; ++j) {
            mesh.vertices.push_back(make_vec(-1.0 + 2.0 * static_cast<double>(i) / static_cast<double>(nx),
                                             -1.0 + 2.0 * static_cast<double>(j) / static_cast<double>(ny), 0.0));
        }
    }
    auto at = [&](uint64_t i, uint64_t j) { return i * (ny + 1) + j; };
    for (uint64_t i = 0; i < nx; ++i) {
        for (uint64_t j = 0; j < ny; ++j) {
            push_triangle(mesh, at(i, j), at(i + 1, j), at(i + 1, j + 1));
            push_triangle(mesh, at(i, j), at(i + 1, j + 1), at(i, j + 1));
        }
    }
    return mesh;
}

// Exactly `count` copies of one triangle, all sharing the same 3 vertices.
TriangleMesh generate_coincident(uint64_t count, uint64_t /*seed*/) {
    TriangleMesh mesh;
    mesh.vertices = {Vec3(0.0f, 0.0f, 0.0f), Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 1.0f, 0.0f)};
    mesh.indices.reserve(3 * count);
    for (uint64_t t = 0; t < count; ++t) push_triangle(mesh, 0, 1, 2);
    return mesh;
}

struct Generator {
    std::string_view name;
    TriangleMesh (*run)(uint64_t count, uint64_t seed);
};

// To add a generator, add a row here (and describe it in scene.h).
constexpr Generator kGenerators[] = {
    {"sphere", &generate_sphere},
    {"random", &generate_random},
    {"stadium", &generate_stadium},
    {"plane", &generate_plane},
    {"coincident", &generate_coincident},
    {"room", &generate_room},
};

const Generator* find_generator(std::string_view name) {
    for (const Generator& g : kGenerators)
        if (g.name == name) return &g;
    return nullptr;
}

std::string generator_list() {
    std::string list;
    for (const Generator& g : kGenerators) {
        if (!list.empty()) list += ", ";
        list += g.name;
    }
    return list;
}

std::string generator_help() {
    return "generators: " + generator_list() + "; spec format gen:NAME:COUNT[:SEED], COUNT 1.." +
           std::to_string(kMaxGeneratorCount);
}

// Empty if (name, count) can be generated, else what is wrong.
std::string generator_problem(std::string_view name, uint64_t count) {
    if (!find_generator(name)) return "unknown generator '" + std::string(name) + "'";
    if (count == 0 || count > kMaxGeneratorCount)
        return "count " + std::to_string(count) + " out of range (1.." + std::to_string(kMaxGeneratorCount) + ")";
    return {};
}

bool parse_u64(std::string_view text, uint64_t& out) {
    if (text.empty() || !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return false;
    const auto res = std::from_chars(text.data(), text.data() + text.size(), out);
    return res.ec == std::errc() && res.ptr == text.data() + text.size();
}

Scene load_generator_spec(const std::string& spec) {
    auto fail = [&](const std::string& what) {
        throw InputError("scene spec '" + spec + "': " + what + " (" + generator_help() + ")");
    };
    std::vector<std::string_view> parts;
    std::string_view rest(spec);
    rest.remove_prefix(kGeneratorPrefix.size());
    for (;;) {
        const size_t colon = rest.find(':');
        parts.push_back(rest.substr(0, colon));
        if (colon == std::string_view::npos) break;
        rest.remove_prefix(colon + 1);
    }
    if (parts[0].empty()) fail("missing generator name");
    if (!find_generator(parts[0])) fail("unknown generator '" + std::string(parts[0]) + "'");
    if (parts.size() < 2 || parts[1].empty()) fail("missing COUNT");
    if (parts.size() > 3) fail("too many fields");
    uint64_t count = 0;
    if (!parse_u64(parts[1], count)) fail("COUNT '" + std::string(parts[1]) + "' is not a positive integer");
    uint64_t seed = 1;
    if (parts.size() == 3 && !parse_u64(parts[2], seed))
        fail("SEED '" + std::string(parts[2]) + "' is not a non-negative 64-bit integer");
    if (const std::string problem = generator_problem(parts[0], count); !problem.empty()) fail(problem);
    return Scene{generate(std::string(parts[0]), count, seed), spec, "generated"};
}

// ---------------------------------------------------------------------------
// OBJ.
//
// tinyobjloader does the parsing and triangulation, but it accepts a lot
// silently: "nan" parses as 0, a missing coordinate defaults to 0, a face
// with fewer than 3 vertices is dropped with a warning, an out-of-range index
// in a triangle is passed through. So the text is scanned first, with line
// numbers, and the loader's output is then checked against the scan.

[[noreturn]] void obj_error(const std::string& path, size_t line, const std::string& what) {
    throw InputError(path + ": line " + std::to_string(line) + ": " + what);
}


bool is_blank(char c) { return c == ' ' || c == '\t'; }

// Splits a line into whitespace-separated tokens (space and tab, as
// tinyobjloader does).
void split_tokens(std::string_view line, std::vector<std::string_view>& out) {
    out.clear();
    size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && is_blank(line[i])) ++i;
        const size_t start = i;
        while (i < line.size() && !is_blank(line[i])) ++i;
        if (i > start) out.push_back(line.substr(start, i - start));
    }
}

std::string quote(std::string_view token) {
    constexpr size_t kMax = 40;
    std::string s = "'";
    for (char c : token.substr(0, kMax)) s += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
    if (token.size() > kMax) s += "...";
    return s + "'";
}

// A coordinate as it becomes a float. False if the token is not a number.
// "nan", "inf" and values beyond the float range parse (to non-finite floats)
// so that the caller can name them.
bool parse_coordinate(std::string_view token, float& out) {
    if (token.size() > 1 && token[0] == '+' && token[1] != '-') token.remove_prefix(1);
    double value = 0.0;
    const char* first = token.data();
    const char* last = first + token.size();
    const auto res = std::from_chars(first, last, value);
    if (res.ptr != last) return false;
    if (res.ec == std::errc::result_out_of_range) {
        // Too large (overflow) or too small (underflow) for a double.
        const size_t e = token.find_first_of("eE");
        const bool underflow = e != std::string_view::npos && e + 1 < token.size() && token[e + 1] == '-';
        const bool negative = token[0] == '-';
        value = underflow ? 0.0 : (negative ? -1.0 : 1.0) * std::numeric_limits<double>::infinity();
    } else if (res.ec != std::errc()) {
        return false;
    }
    out = static_cast<float>(value);
    return true;
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
            const std::string name = "vertex " + std::to_string(vertex);
            if (tokens.size() < 4)
                obj_error(path, line_no,
                          name + " has " + std::to_string(tokens.size() - 1) + " coordinates (needs x y z)");
            float xyz[3];
            for (int k = 0; k < 3; ++k) {
                if (!parse_coordinate(tokens[1 + k], xyz[k]))
                    obj_error(path, line_no, name + ": coordinate " + quote(tokens[1 + k]) + " is not a number");
            }
            const Vec3 p(xyz[0], xyz[1], xyz[2]);
            if (!is_finite(p))
                obj_error(path, line_no, name + " has a non-finite coordinate " + format_vec(p));
            scan.vertex_lines.push_back(line_no);
        } else if (keyword == "f") {
            ++scan.faces;
            const std::string name = "face " + std::to_string(scan.faces);
            const size_t corners = tokens.size() - 1;
            if (corners < 3)
                obj_error(path, line_no,
                          name + " has " + std::to_string(corners) + " vertices (needs at least 3)");
            const long long defined = static_cast<long long>(scan.vertex_lines.size());
            long long max_forward = 0;
            for (size_t k = 1; k < tokens.size(); ++k) {
                long long index = 0;
                if (!parse_corner(tokens[k], index))
                    obj_error(path, line_no, name + ": malformed vertex reference " + quote(tokens[k]));
                if (index == 0)
                    obj_error(path, line_no, name + ": vertex index 0 (OBJ indices start at 1)");
                if (index < 0 && defined + index < 0)
                    obj_error(path, line_no,
                              name + ": relative vertex index " + std::to_string(index) + " out of range (" +
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

std::string trim_message(std::string s) {
    // tinyobjloader separates messages with "\n" (and sometimes "\n.").
    for (char& c : s)
        if (c == '\n' || c == '\r') c = ' ';
    while (!s.empty() && (s.back() == ' ' || s.back() == '.')) s.pop_back();
    const size_t start = s.find_first_not_of(' ');
    return start == std::string::npos ? std::string() : s.substr(start);
}

// ---------------------------------------------------------------------------
// COLLADA, glTF / GLB: through Assimp.
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

// ---------------------------------------------------------------------------
// OFF (Object File Format), read here: Assimp's OFF importer clamps
// out-of-range indices to the last vertex, drops faces of more than 9
// vertices, and reads comment and blank-looking lines as vertices, all
// silently.
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
    const size_t need = homogeneous ? 4 : 3;
    for (uint64_t v = 0; v < vertex_count; ++v) {
        const std::string name = "vertex " + std::to_string(v);
        if (!next_line(line))
            throw InputError(path + ": file ends after line " + std::to_string(line_no) + ", before " + name + " (of " +
                             std::to_string(vertex_count) + "): truncated, or the header's counts are wrong");
        split_tokens(line.text, tokens);
        if (tokens.size() < need)
            fail(line.number, name + " has " + std::to_string(tokens.size()) + " coordinates (needs " +
                                  (homogeneous ? "x y z w)" : "x y z)"));
        float xyzw[4] = {0.0f, 0.0f, 0.0f, 1.0f};
        for (size_t k = 0; k < need; ++k) {
            if (!parse_coordinate(tokens[k], xyzw[k]))
                fail(line.number, name + ": coordinate " + quote(tokens[k]) + " is not a number");
        }
        Vec3 p(xyzw[0], xyzw[1], xyzw[2]);
        if (homogeneous) p = make_vec(double(p.x) / xyzw[3], double(p.y) / xyzw[3], double(p.z) / xyzw[3]);
        if (!is_finite(p)) fail(line.number, name + " has a non-finite coordinate " + format_vec(p));
        mesh.vertices.push_back(p);
    }
    for (uint64_t f = 0; f < face_count; ++f) {
        const std::string name = "face " + std::to_string(f);
        if (!next_line(line))
            throw InputError(path + ": file ends after line " + std::to_string(line_no) + ", before " + name + " (of " +
                             std::to_string(face_count) + "): truncated, or the header's counts are wrong");
        split_tokens(line.text, tokens);
        uint64_t n = 0;
        if (!parse_u64(tokens[0], n)) fail(line.number, name + ": vertex count " + quote(tokens[0]) + " is not a number");
        if (n < 3) fail(line.number, name + " has " + std::to_string(n) + " vertices (needs at least 3)");
        if (tokens.size() - 1 < n)
            fail(line.number, name + " has " + std::to_string(tokens.size() - 1) + " indices, its count says " +
                                  std::to_string(n));
        uint32_t corner[3] = {0, 0, 0};
        for (uint64_t k = 0; k < n; ++k) {
            const std::string_view token = tokens[1 + k];
            uint64_t index = 0;
            if (!parse_u64(token, index)) {
                if (token.starts_with('-') && token.size() > 1 && parse_u64(token.substr(1), index))
                    fail(line.number, name + ": vertex index " + std::string(token) + " out of range (" +
                                          std::to_string(vertex_count) + " vertices)");
                fail(line.number, name + ": vertex index " + quote(token) + " is not an integer");
            }
            if (index >= vertex_count)
                fail(line.number, name + ": vertex index " + std::to_string(index) + " out of range (" +
                                      std::to_string(vertex_count) + " vertices)");
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

// ---------------------------------------------------------------------------
// File formats by extension.

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

bool is_generator_spec(const std::string& spec) { return spec.starts_with(kGeneratorPrefix); }

std::vector<std::string> generator_names() {
    std::vector<std::string> names;
    for (const Generator& g : kGenerators) names.emplace_back(g.name);
    return names;
}

TriangleMesh generate(const std::string& name, uint64_t count, uint64_t seed) {
    if (const std::string problem = generator_problem(name, count); !problem.empty())
        throw InputError("generate: " + problem + " (generators: " + generator_list() + ")");
    return find_generator(name)->run(count, seed);
}

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
