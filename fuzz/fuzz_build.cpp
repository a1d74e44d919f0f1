// canopy fuzzing: the build itself, from raw arrays.
//
// The input is read as
//   byte 0        bins = 2 + b % 255
//   byte 1        max_leaf = 1 + b % 255
//   byte 2        mode: bits 0-1 vertex encoding (1 int8, 2 int16, else
//                 float32), bit 2 indices taken modulo
//                 the vertex count (so that all are in range), bit 3 keep a
//                 trailing partial triangle, bit 4 traversal_cost 0
//   byte 3        scale exponent of the quantised vertex encodings
//   byte 4        max_depth (0: the default, else 1..255)
//   bytes 5-7     the parallel schedulers' tuning (never changes the tree)
//   bytes 8-9     vertex count (little endian), as far as the bytes go
//   vertices      float32 x y z, or int8 / int16 x y z times 2^scale
//   the rest      uint32 indices (little endian), at most 3 * kMaxTriangles
// and built over as triangles, and over two box inputs: consecutive vertex
// pairs as (lo, hi), and the triangles' bounds. What must happen is worked
// out here first: an InputError for an index count not a multiple of 3, an
// OptionError when max_depth cannot hold the leaves, an InputError naming
// the lowest bad triangle or box (index out of range, non-finite coordinate,
// inverted box), and otherwise a valid tree, the same from the sequential
// scheduler and from every scheduler at 2 threads, and the same from the
// triangles and from their bounds.
#include "core/bvh.h"
#include "core/error.h"
#include "core/mesh.h"
#include "core/options.h"
#include "core/validate.h"
#include "fuzz_common.h"
#include "schedulers/registry.h"

#include <cmath>
#include <cstring>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace {

using namespace canopy;

constexpr size_t kHeader = 10;
constexpr size_t kMaxTriangles = 4096;

// Reads little-endian bytes as the integers and floats they encode.
class Reader {
public:
    Reader(const uint8_t* data, size_t size) : data_(data), size_(size) {}
    size_t left() const { return size_ - pos_; }
    uint8_t u8() { return pos_ < size_ ? data_[pos_++] : 0; }
    uint32_t u32() {
        uint32_t v = 0;
        for (int k = 0; k < 4; ++k) v |= uint32_t(u8()) << (8 * k);
        return v;
    }
    float f32() {
        const uint32_t bits = u32();
        float f;
        std::memcpy(&f, &bits, sizeof f);
        return f;
    }

private:
    const uint8_t* data_;
    size_t size_;
    size_t pos_ = 0;
};

uint32_t ceil_log2(uint64_t x) {
    uint32_t k = 0;
    while ((uint64_t(1) << k) < x) ++k;
    return k;
}

bool finite(const Vec3& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// What a build must do: throw E with `needle` in its message, or succeed.
enum class Outcome { Ok, InputError, OptionError };
struct Expected {
    Outcome outcome = Outcome::Ok;
    std::string needle;
};

Expected expect_depth_or(const BuildOptions& opt, size_t count, Expected otherwise) {
    if (count == 0) return {};
    const uint64_t leaves = (count + opt.max_leaf - 1) / opt.max_leaf;
    if (ceil_log2(leaves) > opt.max_depth) return {Outcome::OptionError, "max_depth"};
    return otherwise;
}

Expected expect_triangles(const TriangleMesh& m, const BuildOptions& opt) {
    if (m.indices.size() % 3 != 0) return {Outcome::InputError, "not a multiple of 3"};
    Expected bad;
    for (size_t t = 0; t < m.triangle_count() && bad.outcome == Outcome::Ok; ++t) {
        for (int k = 0; k < 3; ++k) {
            const uint32_t i = m.indices[3 * t + k];
            if (i >= m.vertices.size() || !finite(m.vertices[i])) {
                bad = {Outcome::InputError, "triangle " + std::to_string(t) + ":"};
                break;
            }
        }
    }
    return expect_depth_or(opt, m.triangle_count(), bad);
}

Expected expect_boxes(std::span<const Box> boxes, const BuildOptions& opt) {
    Expected bad;
    for (size_t i = 0; i < boxes.size(); ++i) {
        if (!finite(boxes[i].lo) || !finite(boxes[i].hi) || boxes[i].is_empty()) {
            bad = {Outcome::InputError, "primitive box " + std::to_string(i) + " "};
            break;
        }
    }
    return expect_depth_or(opt, boxes.size(), bad);
}

// Runs one build and checks it against `want`; the tree when it succeeds.
template <class F>
std::optional<Bvh> run(const Expected& want, const char* what, F&& build) {
    const char* got = "no exception";
    std::string message;
    try {
        Bvh bvh = build();
        if (want.outcome == Outcome::Ok) return bvh;
    } catch (const OptionError& e) {
        if (want.outcome == Outcome::OptionError && message.assign(e.what()).find(want.needle) != std::string::npos)
            return std::nullopt;
        got = "OptionError";
        message = e.what();
    } catch (const InputError& e) {
        if (want.outcome == Outcome::InputError && message.assign(e.what()).find(want.needle) != std::string::npos)
            return std::nullopt;
        got = "InputError";
        message = e.what();
    } catch (const std::exception& e) {
        got = "an exception other than InputError / OptionError";
        message = e.what();
    }
    fuzz::fail(what, std::string("expected ") +
                         (want.outcome == Outcome::Ok            ? "a tree"
                          : want.outcome == Outcome::InputError ? "InputError"
                                                                : "OptionError") +
                         (want.needle.empty() ? "" : " mentioning '" + want.needle + "'") + ", got " + got +
                         (message.empty() ? "" : ": " + message));
}

// Every scheduler at 2 threads must give `ref` (or the same error).
template <class Input>
void check_schedulers(const Input& input, const BuildOptions& opt, const Expected& want,
                      const std::optional<Bvh>& ref) {
    BuildOptions par = opt;
    par.threads = 2;
    for (const SchedulerEntry& s : schedulers()) {
        const std::optional<Bvh> got = run(want, s.name, [&] {
            if constexpr (std::is_same_v<Input, TriangleView>)
                return s.build_triangles(input, par);
            else
                return s.build_boxes(input, par);
        });
        if (ref && !(*got == *ref)) fuzz::fail("a scheduler's tree differs from the sequential one", s.name);
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < kHeader) return 0;
    Reader in(data, size);
    BuildOptions opt;
    opt.bins = 2 + in.u8() % 255;
    opt.max_leaf = 1 + in.u8() % 255;
    const uint8_t mode = in.u8();
    const int scale = int(in.u8()) - 128;
    if (const uint8_t depth = in.u8()) opt.max_depth = depth;
    if (mode & 16) opt.traversal_cost = 0.0f;
    opt.tuning.prims_per_thread = 1 + in.u8();
    opt.tuning.task_cutoff = 1 + in.u8();
    opt.tuning.parallel_node_min = 1 + 4 * uint32_t(in.u8());
    const uint32_t asked = in.u8() | uint32_t(in.u8()) << 8;

    // Vertices.
    const int encoding = mode & 3;
    const size_t vertex_bytes = encoding == 0 || encoding == 3 ? 12 : encoding == 1 ? 3 : 6;
    const size_t nv = std::min<size_t>(asked, in.left() / vertex_bytes);
    TriangleMesh mesh;
    mesh.vertices.resize(nv);
    for (Vec3& v : mesh.vertices) {
        for (int a = 0; a < 3; ++a) {
            if (vertex_bytes == 12) {
                v[a] = in.f32();
            } else if (vertex_bytes == 3) {
                v[a] = std::ldexp(float(int8_t(in.u8())), scale);
            } else {
                const uint32_t lo = in.u8();
                v[a] = std::ldexp(float(int16_t(lo | uint32_t(in.u8()) << 8)), scale);
            }
        }
    }

    // Indices.
    size_t ni = std::min(in.left() / 4, 3 * kMaxTriangles);
    if (!(mode & 8)) ni -= ni % 3;
    mesh.indices.resize(ni);
    for (uint32_t& i : mesh.indices) {
        i = in.u32();
        if ((mode & 4) && nv) i %= uint32_t(nv);
    }

    // Triangles.
    const TriangleView view = mesh.view();
    const Expected want = expect_triangles(mesh, opt);
    if (std::getenv("CANOPY_FUZZ_VERBOSE"))  // what an input decodes to, when reproducing
        std::fprintf(stderr, "bins %u max_leaf %u max_depth %u: %zu vertices, %zu indices: %s\n", opt.bins,
                     opt.max_leaf, opt.max_depth, nv, ni,
                     want.outcome == Outcome::Ok ? "builds" : ("throws, mentioning '" + want.needle + "'").c_str());
    const std::optional<Bvh> ref = run(want, "sequential", [&] { return build<Sequential>(view, opt); });
    if (ref) {
        const ValidationReport report = validate(*ref, view, opt);
        if (!report.ok()) fuzz::fail("the triangle tree failed validation", report.summary());
    }
    check_schedulers(view, opt, want, ref);

    // The triangles' bounds as boxes: the same tree.
    if (ref) {
        std::vector<Box> bounds(mesh.triangle_count());
        for (size_t t = 0; t < bounds.size(); ++t)
            for (int k = 0; k < 3; ++k) bounds[t].extend(mesh.vertex(t, k));
        const std::span<const Box> span(bounds);
        if (!(build<Sequential>(span, opt) == *ref))
            fuzz::fail("the triangles' bounds as boxes", "a different tree than the triangles");
    }

    // Vertex pairs as boxes.
    std::vector<Box> boxes(nv / 2);
    for (size_t i = 0; i < boxes.size(); ++i) boxes[i] = Box{mesh.vertices[2 * i], mesh.vertices[2 * i + 1]};
    const std::span<const Box> span(boxes);
    const Expected want_boxes = expect_boxes(span, opt);
    const std::optional<Bvh> box_ref =
        run(want_boxes, "sequential (boxes)", [&] { return build<Sequential>(span, opt); });
    if (box_ref) {
        const ValidationReport report = validate(*box_ref, span, opt);
        if (!report.ok()) fuzz::fail("the box tree failed validation", report.summary());
    }
    check_schedulers(span, opt, want_boxes, box_ref);
    return 0;
}
