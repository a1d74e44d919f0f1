// canopy: the seeded scene generators.
//
// Every generator is a pure function of (count, seed). Randomness comes from
// Rng (core/rng.h), the same numbers on every platform. Coordinates are
// computed in double and rounded once to float.
#include "generators.h"

#include "error.h"
#include "reader_util.h"
#include "rng.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string_view>
#include <vector>

namespace canopy {
namespace {

using input::make_vec;
using input::parse_u64;
using input::push_triangle;

constexpr std::string_view kGeneratorPrefix = "gen:";
constexpr uint64_t kMaxGeneratorCount = 100'000'000;

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

}  // namespace

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

}  // namespace canopy
