// canopy: what the scene readers and generators share (reader_util.h).
#include "reader_util.h"

#include <algorithm>
#include <charconv>
#include <limits>
#include <system_error>

namespace canopy::input {
namespace {

std::string format_float(float v) {
    char buf[64];
    const auto res = std::to_chars(buf, buf + sizeof buf, v);
    return std::string(buf, res.ptr);
}

bool is_blank(char c) { return c == ' ' || c == '\t'; }

}  // namespace

std::string format_vec(const Vec3& p) {
    // Appended piece by piece: GCC 12 warns (-Wrestrict, a false positive)
    // about "(" + std::string once this is compiled on its own.
    std::string s = "(";
    s.append(format_float(p.x)).append(", ").append(format_float(p.y)).append(", ").append(format_float(p.z));
    return s.append(")");
}

void split_tokens(std::string_view line, std::vector<std::string_view>& out) { split_tokens(line, out, is_blank); }

std::string quote(std::string_view token) {
    constexpr size_t kMax = 40;
    std::string s = "'";
    for (char c : token.substr(0, kMax)) s += (c >= 0x20 && c < 0x7f) ? c : '?';
    if (token.size() > kMax) s += "...";
    return s + "'";
}

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

bool parse_u64(std::string_view text, uint64_t& out) {
    if (text.empty() || !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return false;
    const auto res = std::from_chars(text.data(), text.data() + text.size(), out);
    return res.ec == std::errc() && res.ptr == text.data() + text.size();
}

std::string trim_message(std::string s) {
    // tinyobjloader separates messages with "\n" (and sometimes "\n.").
    for (char& c : s)
        if (c == '\n' || c == '\r') c = ' ';
    while (!s.empty() && (s.back() == ' ' || s.back() == '.')) s.pop_back();
    const size_t start = s.find_first_not_of(' ');
    return start == std::string::npos ? std::string() : s.substr(start);
}

}  // namespace canopy::input
