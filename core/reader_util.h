// canopy: what the scene readers and generators share: naming a bad value
// in an error message (locale-independent), splitting and parsing text
// tokens, and appending to a mesh. Internal to core/ (not installed).
#pragma once

#include "mesh.h"

#include <cmath>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace canopy::input {

// "(x, y, z)" with each coordinate in its shortest round-trip form.
std::string format_vec(const Vec3& p);

inline bool is_finite(const Vec3& p) { return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z); }

// A point computed in double, rounded once to float.
inline Vec3 make_vec(double x, double y, double z) {
    return Vec3(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
}

inline void push_triangle(TriangleMesh& mesh, uint64_t a, uint64_t b, uint64_t c) {
    mesh.indices.push_back(static_cast<uint32_t>(a));
    mesh.indices.push_back(static_cast<uint32_t>(b));
    mesh.indices.push_back(static_cast<uint32_t>(c));
}

// Splits a line into the tokens between characters c with is_sep(c), into
// `out` (cleared first).
template <class IsSep>
void split_tokens(std::string_view line, std::vector<std::string_view>& out, IsSep is_sep) {
    out.clear();
    size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && is_sep(line[i])) ++i;
        const size_t start = i;
        while (i < line.size() && !is_sep(line[i])) ++i;
        if (i > start) out.push_back(line.substr(start, i - start));
    }
}

// Tokens separated by spaces and tabs (as tinyobjloader splits them).
void split_tokens(std::string_view line, std::vector<std::string_view>& out);

// A token for an error message: in single quotes, at most 40 characters
// (then "..."), bytes outside printable ASCII as '?'.
std::string quote(std::string_view token);

// A coordinate as it becomes a float. False if the token is not a number.
// "nan", "inf" and values beyond the float range parse (to non-finite
// floats) so that the caller can name them.
bool parse_coordinate(std::string_view token, float& out);

// A non-negative decimal integer of digits only that fits in 64 bits.
bool parse_u64(std::string_view text, uint64_t& out);

// A third-party library's message on one line, without trailing dots.
std::string trim_message(std::string s);

}  // namespace canopy::input
