// canopy: a fast PLY reader (ASCII, binary little and big endian).
//
// The whole file is read into memory, the header parsed, the header's counts
// checked against the file size, and then the data parsed in one pass:
// binary elements of fixed size (no list properties) by stride, everything
// else property by property with a bounds check before every read; ASCII
// line by line with std::from_chars.
#include "ply.h"

#include "error.h"
#include "file_read.h"
#include "reader_util.h"

#include <bit>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace canopy {
namespace {

// ---------------------------------------------------------------------------
// Header.

enum class Type : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

constexpr size_t size_of(Type t) {
    switch (t) {
        case Type::I8:
        case Type::U8: return 1;
        case Type::I16:
        case Type::U16: return 2;
        case Type::I32:
        case Type::U32:
        case Type::F32: return 4;
        case Type::F64: return 8;
    }
    return 0;
}

constexpr bool is_integer(Type t) { return t != Type::F32 && t != Type::F64; }

struct TypeName {
    std::string_view name;
    Type type;
};

constexpr TypeName kTypeNames[] = {
    {"char", Type::I8},     {"int8", Type::I8},     {"uchar", Type::U8},     {"uint8", Type::U8},
    {"short", Type::I16},   {"int16", Type::I16},   {"ushort", Type::U16},   {"uint16", Type::U16},
    {"int", Type::I32},     {"int32", Type::I32},   {"uint", Type::U32},     {"uint32", Type::U32},
    {"float", Type::F32},   {"float32", Type::F32}, {"double", Type::F64},   {"float64", Type::F64},
};

bool parse_type(std::string_view s, Type& out) {
    for (const TypeName& t : kTypeNames) {
        if (t.name == s) {
            out = t.type;
            return true;
        }
    }
    return false;
}

std::string_view type_name(Type t) {
    for (const TypeName& n : kTypeNames)
        if (n.type == t) return n.name;
    return "?";
}

struct Property {
    std::string name;
    bool list = false;
    Type type = Type::F32;       // the scalar's type, or a list's item type
    Type count_type = Type::U8;  // a list's count type
    size_t line = 0;             // header line
};

struct Element {
    std::string name;
    uint64_t count = 0;
    std::vector<Property> props;
    size_t line = 0;  // header line
};

enum class Encoding { Ascii, BinaryLittle, BinaryBig };

struct Header {
    Encoding encoding = Encoding::Ascii;
    std::vector<Element> elements;
    size_t data_offset = 0;  // first byte after the end_header line
    size_t lines = 0;        // header lines, end_header included
};

using input::quote;

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\v' || c == '\f' || c == '\r'; }

// A header line's tokens (separated by any ASCII white space but newline).
void split(std::string_view line, std::vector<std::string_view>& out) { input::split_tokens(line, out, is_space); }

bool parse_count(std::string_view s, uint64_t& out) {
    if (s.empty() || s[0] < '0' || s[0] > '9') return false;
    const auto res = std::from_chars(s.data(), s.data() + s.size(), out);
    return res.ec == std::errc() && res.ptr == s.data() + s.size();
}

class Parser {
public:
    Parser(std::string_view data, const std::string& name) : data_(data), name_(name) {}

    TriangleMesh parse() {
        if (data_.empty()) fail("empty file (not a PLY file)");
        parse_header();
        find_roles();
        check_sizes();
        mesh_.vertices.resize(static_cast<size_t>(vertex_count_));
        mesh_.indices.reserve(3 * static_cast<size_t>(header_.elements[face_].count));
        switch (header_.encoding) {
            case Encoding::Ascii: parse_ascii(); break;
            case Encoding::BinaryLittle:
                if constexpr (std::endian::native == std::endian::little)
                    parse_binary<false>();
                else
                    parse_binary<true>();
                break;
            case Encoding::BinaryBig:
                if constexpr (std::endian::native == std::endian::big)
                    parse_binary<false>();
                else
                    parse_binary<true>();
                break;
        }
        return std::move(mesh_);
    }

private:
    [[noreturn]] void fail(const std::string& what) const { throw InputError(name_ + ": " + what); }
    [[noreturn]] void fail_header(size_t line, const std::string& what) const {
        fail("header line " + std::to_string(line) + ": " + what);
    }
    [[noreturn]] void fail_line(size_t line, const std::string& what) const {
        fail("line " + std::to_string(line) + ": " + what);
    }

    // ---- header -----------------------------------------------------------

    void parse_header() {
        size_t pos = 0;
        size_t line_no = 0;
        bool have_format = false;
        std::vector<std::string_view> tokens;
        for (;;) {
            if (pos >= data_.size()) {
                fail("header is not terminated: no end_header line (file ends after line " +
                     std::to_string(line_no) + ")");
            }
            size_t end = pos;
            while (end < data_.size() && data_[end] != '\n' && data_[end] != '\r') ++end;
            const std::string_view line = data_.substr(pos, end - pos);
            pos = end;
            if (pos < data_.size()) {
                if (data_[pos] == '\r' && pos + 1 < data_.size() && data_[pos + 1] == '\n')
                    pos += 2;
                else
                    pos += 1;
            }
            ++line_no;

            if (line_no == 1) {
                split(line, tokens);
                if (tokens.size() != 1 || tokens[0] != "ply")
                    fail("not a PLY file: line 1 is " + quote(line) + ", expected 'ply'");
                continue;
            }
            for (char c : line) {
                if ((static_cast<unsigned char>(c) < 0x20 && c != '\t' && c != '\v' && c != '\f') ||
                    static_cast<unsigned char>(c) == 0x7f)
                    fail_header(line_no, "binary data in the header (no end_header line before it?)");
            }
            split(line, tokens);
            if (tokens.empty()) continue;  // tolerate blank header lines
            const std::string_view keyword = tokens[0];
            if (keyword == "comment" || keyword == "obj_info") continue;
            if (keyword == "format") {
                if (have_format) fail_header(line_no, "second format line");
                if (tokens.size() != 3) fail_header(line_no, "malformed format line " + quote(line) +
                                                                  " (expected 'format ENCODING 1.0')");
                if (tokens[1] == "ascii")
                    header_.encoding = Encoding::Ascii;
                else if (tokens[1] == "binary_little_endian")
                    header_.encoding = Encoding::BinaryLittle;
                else if (tokens[1] == "binary_big_endian")
                    header_.encoding = Encoding::BinaryBig;
                else
                    fail_header(line_no, "unsupported format " + quote(tokens[1]) +
                                             " (supported: ascii, binary_little_endian, binary_big_endian)");
                if (tokens[2] != "1.0" && tokens[2] != "1")
                    fail_header(line_no, "unsupported PLY version " + quote(tokens[2]) + " (supported: 1.0)");
                have_format = true;
            } else if (keyword == "element") {
                if (tokens.size() != 3)
                    fail_header(line_no, "malformed element line " + quote(line) + " (expected 'element NAME COUNT')");
                Element e;
                e.name = std::string(tokens[1]);
                e.line = line_no;
                if (!parse_count(tokens[2], e.count))
                    fail_header(line_no, "element '" + e.name + "': count " + quote(tokens[2]) +
                                             " is not a non-negative integer");
                for (const Element& other : header_.elements) {
                    if (other.name == e.name)
                        fail_header(line_no, "element '" + e.name + "' declared again (first at header line " +
                                                 std::to_string(other.line) + ")");
                }
                header_.elements.push_back(std::move(e));
            } else if (keyword == "property") {
                if (header_.elements.empty()) fail_header(line_no, "property before any element");
                Element& e = header_.elements.back();
                Property p;
                p.line = line_no;
                if (tokens.size() >= 2 && tokens[1] == "list") {
                    if (tokens.size() != 5)
                        fail_header(line_no, "malformed list property " + quote(line) +
                                                 " (expected 'property list COUNT_TYPE ITEM_TYPE NAME')");
                    p.list = true;
                    if (!parse_type(tokens[2], p.count_type))
                        fail_header(line_no, "unknown type " + quote(tokens[2]));
                    if (!is_integer(p.count_type))
                        fail_header(line_no, "list count type " + quote(tokens[2]) + " is not an integer type");
                    if (!parse_type(tokens[3], p.type)) fail_header(line_no, "unknown type " + quote(tokens[3]));
                    p.name = std::string(tokens[4]);
                } else {
                    if (tokens.size() != 3)
                        fail_header(line_no, "malformed property " + quote(line) + " (expected 'property TYPE NAME')");
                    if (!parse_type(tokens[1], p.type)) fail_header(line_no, "unknown type " + quote(tokens[1]));
                    p.name = std::string(tokens[2]);
                }
                for (const Property& other : e.props) {
                    if (other.name == p.name)
                        fail_header(line_no, "element '" + e.name + "': property '" + p.name +
                                                 "' declared again (first at header line " +
                                                 std::to_string(other.line) + ")");
                }
                e.props.push_back(std::move(p));
            } else if (keyword == "end_header") {
                if (tokens.size() != 1) fail_header(line_no, "malformed end_header line " + quote(line));
                if (!have_format) fail_header(line_no, "no format line before end_header");
                header_.data_offset = pos;
                header_.lines = line_no;
                return;
            } else {
                fail_header(line_no, "unknown keyword " + quote(keyword) +
                                         " (expected format, element, property, comment, obj_info or end_header)");
            }
        }
    }

    void find_roles() {
        const size_t none = header_.elements.size();
        vertex_ = none;
        face_ = none;
        for (size_t i = 0; i < header_.elements.size(); ++i) {
            if (header_.elements[i].name == "vertex") vertex_ = i;
            if (header_.elements[i].name == "face") face_ = i;
        }
        if (vertex_ == none) fail("no 'vertex' element in the header");
        const Element& v = header_.elements[vertex_];
        const char* axes[3] = {"x", "y", "z"};
        for (int k = 0; k < 3; ++k) {
            coord_[k] = v.props.size();
            for (size_t j = 0; j < v.props.size(); ++j)
                if (v.props[j].name == axes[k]) coord_[k] = j;
            if (coord_[k] == v.props.size())
                fail_header(v.line, "element 'vertex' has no property '" + std::string(axes[k]) + "'");
            if (v.props[coord_[k]].list)
                fail_header(v.props[coord_[k]].line, "vertex property '" + std::string(axes[k]) + "' is a list");
        }
        if (v.count > std::numeric_limits<uint32_t>::max())
            fail_header(v.line, std::to_string(v.count) + " vertices: more than 32-bit indices can address");
        vertex_count_ = v.count;

        if (face_ == none) {
            for (const Element& e : header_.elements) {
                if (e.name == "tristrips")
                    fail_header(e.line, "element 'tristrips' is not supported (only 'face' lists): no triangles");
            }
            fail("no triangles: no 'face' element in the header (a point cloud?)");
        }
        const Element& f = header_.elements[face_];
        index_ = f.props.size();
        for (const char* name : {"vertex_indices", "vertex_index"}) {
            for (size_t j = 0; j < f.props.size() && index_ == f.props.size(); ++j)
                if (f.props[j].name == name) index_ = j;
        }
        if (index_ == f.props.size()) {
            size_t lists = 0;
            for (size_t j = 0; j < f.props.size(); ++j) {
                if (f.props[j].list) {
                    ++lists;
                    index_ = j;
                }
            }
            if (lists != 1)
                fail_header(f.line, "element 'face' has no property 'vertex_indices' (nor 'vertex_index')");
        }
        const Property& ip = f.props[index_];
        if (!ip.list) fail_header(ip.line, "face property '" + ip.name + "' is not a list");
        if (!is_integer(ip.type))
            fail_header(ip.line, "face property '" + ip.name + "' has item type " + std::string(type_name(ip.type)) +
                                     " (vertex indices must be integers)");
        if (f.count == 0) fail("no triangles: the header declares 0 faces");
    }

    // The least number of bytes an element can take: binary, a list takes at
    // least its count; ASCII, every value takes at least one character and a
    // separator.
    uint64_t min_element_bytes(const Element& e) const {
        uint64_t bytes = 0;
        for (const Property& p : e.props) {
            if (header_.encoding == Encoding::Ascii)
                bytes += 2;
            else
                bytes += size_of(p.list ? p.count_type : p.type);
        }
        return bytes;
    }

    void check_sizes() const {
        // +1: the last value of an ASCII file needs no separator after it.
        uint64_t available = data_.size() - header_.data_offset + (header_.encoding == Encoding::Ascii ? 1 : 0);
        for (const Element& e : header_.elements) {
            const uint64_t each = min_element_bytes(e);
            if (each == 0) continue;
            if (e.count > available / each) {
                fail_header(e.line, "element '" + e.name + "' count " + std::to_string(e.count) +
                                        " is inconsistent with the file size: " + std::to_string(e.count) +
                                        " elements need at least " + std::to_string(each) + " bytes each, but only " +
                                        std::to_string(available) + " bytes are left for them (file size " +
                                        std::to_string(data_.size()) + ", header " +
                                        std::to_string(header_.data_offset) + " bytes)");
            }
            available -= e.count * each;
        }
    }

    // ---- the mesh ---------------------------------------------------------

    void put_vertex(uint64_t i, float x, float y, float z, size_t line) {
        const Vec3 p(x, y, z);
        if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
            const std::string where = line ? "line " + std::to_string(line) + ": " : std::string();
            fail(where + "vertex " + std::to_string(i) + " has a non-finite coordinate (" + format_float(x) + ", " +
                 format_float(y) + ", " + format_float(z) + ")");
        }
        mesh_.vertices[static_cast<size_t>(i)] = p;
    }

    static std::string format_float(float v) {
        char buf[64];
        const auto res = std::to_chars(buf, buf + sizeof buf, v);
        return std::string(buf, res.ptr);
    }

    [[noreturn]] void bad_index(uint64_t face, int64_t index, size_t line) const {
        const std::string where = line ? "line " + std::to_string(line) + ": " : std::string();
        fail(where + "face " + std::to_string(face) + ": vertex index " + std::to_string(index) +
             " out of range (" + std::to_string(vertex_count_) + " vertices)");
    }

    [[noreturn]] void short_face(uint64_t face, int64_t n, size_t line) const {
        const std::string where = line ? "line " + std::to_string(line) + ": " : std::string();
        fail(where + "face " + std::to_string(face) + " has " + std::to_string(n) +
             " vertices (needs at least 3)");
    }

    // ---- binary -----------------------------------------------------------

    template <bool Swap, class T>
    static T load(const unsigned char* p) {
        T v;
        if constexpr (Swap && sizeof(T) > 1) {
            unsigned char b[sizeof(T)];
            for (size_t i = 0; i < sizeof(T); ++i) b[i] = p[sizeof(T) - 1 - i];
            std::memcpy(&v, b, sizeof v);
        } else {
            std::memcpy(&v, p, sizeof v);
        }
        return v;
    }

    template <bool Swap>
    static float load_float(const unsigned char* p, Type t) {
        switch (t) {
            case Type::F32: return load<Swap, float>(p);
            case Type::F64: return static_cast<float>(load<Swap, double>(p));
            case Type::I8: return static_cast<float>(load<Swap, int8_t>(p));
            case Type::U8: return static_cast<float>(load<Swap, uint8_t>(p));
            case Type::I16: return static_cast<float>(load<Swap, int16_t>(p));
            case Type::U16: return static_cast<float>(load<Swap, uint16_t>(p));
            case Type::I32: return static_cast<float>(load<Swap, int32_t>(p));
            case Type::U32: return static_cast<float>(load<Swap, uint32_t>(p));
        }
        return 0.0f;
    }

    template <bool Swap>
    static int64_t load_int(const unsigned char* p, Type t) {
        switch (t) {
            case Type::I8: return load<Swap, int8_t>(p);
            case Type::U8: return load<Swap, uint8_t>(p);
            case Type::I16: return load<Swap, int16_t>(p);
            case Type::U16: return load<Swap, uint16_t>(p);
            case Type::I32: return load<Swap, int32_t>(p);
            case Type::U32: return load<Swap, uint32_t>(p);
            case Type::F32:
            case Type::F64: break;  // never: the header check allows integer types only
        }
        return -1;
    }

    [[noreturn]] void truncated(const Element& e, uint64_t i, const unsigned char* at) const {
        fail("truncated binary data: the file ends inside " + e.name + " " + std::to_string(i) + " (element '" +
             e.name + "' has " + std::to_string(e.count) + "; file size " + std::to_string(data_.size()) +
             " bytes, element starts at byte " + std::to_string(at - begin()) + ")");
    }

    const unsigned char* begin() const { return reinterpret_cast<const unsigned char*>(data_.data()); }

    template <bool Swap>
    void emit_face(uint64_t face, const unsigned char* items, Type type, int64_t n) {
        const size_t size = size_of(type);
        const auto index = [&](int64_t k) {
            const int64_t v = load_int<Swap>(items + static_cast<size_t>(k) * size, type);
            if (v < 0 || static_cast<uint64_t>(v) >= vertex_count_) bad_index(face, v, 0);
            return static_cast<uint32_t>(v);
        };
        push_fan(n, index);
    }

    // The face's polygon as a fan (0, k-1, k) of n >= 3 corners; index(k)
    // checks and returns corner k's vertex.
    template <class Count, class Index>
    void push_fan(Count n, const Index& index) {
        const uint32_t first = index(0);
        uint32_t prev = index(1);
        for (Count k = 2; k < n; ++k) {
            const uint32_t cur = index(k);
            mesh_.indices.push_back(first);
            mesh_.indices.push_back(prev);
            mesh_.indices.push_back(cur);
            prev = cur;
        }
    }

    template <bool Swap>
    void parse_binary() {
        const unsigned char* p = begin() + header_.data_offset;
        const unsigned char* const end = begin() + data_.size();
        for (size_t ei = 0; ei < header_.elements.size(); ++ei) {
            const Element& e = header_.elements[ei];
            if (e.props.empty()) continue;
            const bool is_vertex = ei == vertex_, is_face = ei == face_;
            bool fixed = true;
            size_t stride = 0;
            for (const Property& prop : e.props) {
                fixed = fixed && !prop.list;
                stride += size_of(prop.type);
            }
            if (fixed) {
                // By stride: one size check for the whole element.
                const uint64_t whole = static_cast<uint64_t>(end - p) / stride;
                if (whole < e.count) truncated(e, whole, p + whole * stride);
                if (is_vertex) {
                    size_t offset[3] = {0, 0, 0};
                    Type type[3] = {};
                    for (int k = 0; k < 3; ++k) {
                        for (size_t j = 0; j < coord_[k]; ++j) offset[k] += size_of(e.props[j].type);
                        type[k] = e.props[coord_[k]].type;
                    }
                    for (uint64_t i = 0; i < e.count; ++i) {
                        const unsigned char* q = p + i * stride;
                        put_vertex(i, load_float<Swap>(q + offset[0], type[0]), load_float<Swap>(q + offset[1], type[1]),
                                   load_float<Swap>(q + offset[2], type[2]), 0);
                    }
                }
                p += e.count * stride;
                continue;
            }
            if (is_face && e.props.size() == 1 && e.props[0].count_type == Type::U8 &&
                (e.props[0].type == Type::I32 || e.props[0].type == Type::U32)) {
                parse_binary_faces_fast<Swap>(e, p, end);
                continue;
            }
            // Property by property.
            for (uint64_t i = 0; i < e.count; ++i) {
                const unsigned char* const start = p;
                float xyz[3] = {0.0f, 0.0f, 0.0f};
                for (size_t j = 0; j < e.props.size(); ++j) {
                    const Property& prop = e.props[j];
                    if (!prop.list) {
                        const size_t size = size_of(prop.type);
                        if (static_cast<size_t>(end - p) < size) truncated(e, i, start);
                        if (is_vertex) {
                            for (int k = 0; k < 3; ++k)
                                if (coord_[k] == j) xyz[k] = load_float<Swap>(p, prop.type);
                        }
                        p += size;
                        continue;
                    }
                    const size_t count_size = size_of(prop.count_type);
                    if (static_cast<size_t>(end - p) < count_size) truncated(e, i, start);
                    const int64_t n = load_int<Swap>(p, prop.count_type);
                    p += count_size;
                    if (n < 0)
                        fail(e.name + " " + std::to_string(i) + ": list '" + prop.name + "' has a negative count " +
                             std::to_string(n) + " (at byte " + std::to_string(p - count_size - begin()) + ")");
                    const size_t item_size = size_of(prop.type);
                    if (static_cast<uint64_t>(end - p) / item_size < static_cast<uint64_t>(n)) truncated(e, i, start);
                    if (is_face && j == index_) {
                        if (n < 3) short_face(i, n, 0);
                        emit_face<Swap>(i, p, prop.type, n);
                    }
                    p += static_cast<size_t>(n) * item_size;
                }
                if (is_vertex) put_vertex(i, xyz[0], xyz[1], xyz[2], 0);
            }
        }
        if (p != end)
            fail(std::to_string(end - p) + " bytes of data after the last element (at byte " +
                 std::to_string(p - begin()) + " of " + std::to_string(data_.size()) +
                 "): the header's counts are inconsistent with the file size");
    }

    // The common layout `element face N / property list uchar int|uint
    // vertex_indices` and nothing else.
    template <bool Swap>
    void parse_binary_faces_fast(const Element& e, const unsigned char*& p, const unsigned char* end) {
        const Type type = e.props[0].type;
        const uint64_t limit = vertex_count_;
        for (uint64_t i = 0; i < e.count; ++i) {
            if (p == end) truncated(e, i, p);
            const unsigned n = *p;
            if (static_cast<size_t>(end - p) < 1 + 4 * size_t{n}) truncated(e, i, p);
            if (n < 3) short_face(i, n, 0);
            const unsigned char* items = p + 1;
            p += 1 + 4 * size_t{n};
            const auto index = [&](unsigned k) {
                const uint64_t v = type == Type::U32 ? uint64_t{load<Swap, uint32_t>(items + 4 * k)}
                                                     : static_cast<uint64_t>(load<Swap, int32_t>(items + 4 * k));
                if (v >= limit)
                    bad_index(i, type == Type::U32 ? static_cast<int64_t>(v) : load<Swap, int32_t>(items + 4 * k), 0);
                return static_cast<uint32_t>(v);
            };
            push_fan(n, index);
        }
    }

    // ---- ASCII ------------------------------------------------------------

    // A cursor over the data lines.
    struct Lines {
        const char* next;      // start of the next line
        const char* end;       // end of the data
        size_t line;           // number of the current line
        const char* start;     // the current line's first value
        const char* line_end;  // end of the current line's content
        bool cr_only;          // lines end with a lone '\r' (the header's did)
    };

    // Moves to the next line with a value on it. False at the end of the file.
    static bool next_data_line(Lines& c) {
        for (;;) {
            if (c.next >= c.end) return false;
            const char* q = c.next;
            if (c.cr_only) {
                while (q < c.end && *q != '\n' && *q != '\r') ++q;
            } else {
                // '\n' ends a line; a '\r' before it is a blank like any other.
                q = static_cast<const char*>(std::memchr(q, '\n', static_cast<size_t>(c.end - q)));
                if (q == nullptr) q = c.end;
            }
            ++c.line;
            const char* s = c.next;
            while (s < q && is_space(*s)) ++s;
            c.start = s;
            c.line_end = q;
            c.next = q == c.end ? q : q + 1;
            if (c.cr_only && q < c.end && *q == '\r' && c.next < c.end && *c.next == '\n') ++c.next;
            if (s != q) return true;
        }
    }

    // Skips blanks; false at the end of the line.
    static bool at_value(const char*& p, const char* line_end) {
        while (p < line_end && is_space(*p)) ++p;
        return p < line_end;
    }

    static std::string_view token_at(const char* p, const char* line_end) {
        const char* q = p;
        while (q < line_end && !is_space(*q)) ++q;
        return std::string_view(p, static_cast<size_t>(q - p));
    }

    static void skip_value(const char*& p, const char* line_end) {
        while (p < line_end && !is_space(*p)) ++p;
    }

    static bool value_ends(const char* q, const char* line_end) { return q == line_end || is_space(*q); }

    // The value at p as it becomes a float; advances p past it. False if it
    // is not a number. "nan", "inf" and values beyond the float range parse
    // (to non-finite floats) so that the vertex can be named.
    static bool parse_float(const char*& p, const char* line_end, Type type, float& out) {
        const char* first = p;
        if (line_end - first > 1 && first[0] == '+' && first[1] != '-') ++first;
        if (is_integer(type)) {
            long long v = 0;
            const auto res = std::from_chars(first, line_end, v);
            if (res.ec != std::errc() || !value_ends(res.ptr, line_end)) return false;
            out = static_cast<float>(v);
            p = res.ptr;
            return true;
        }
        std::from_chars_result res{};
        if (type == Type::F32) {
            res = std::from_chars(first, line_end, out);
        } else {
            double d = 0.0;
            res = std::from_chars(first, line_end, d);
            out = static_cast<float>(d);
        }
        if (res.ptr == first || !value_ends(res.ptr, line_end)) return false;
        if (res.ec == std::errc::result_out_of_range) {
            const std::string_view token(first, static_cast<size_t>(res.ptr - first));
            const size_t e = token.find_first_of("eE");
            const bool underflow = e != std::string_view::npos && e + 1 < token.size() && token[e + 1] == '-';
            const bool negative = token[0] == '-';
            out = underflow ? (negative ? -0.0f : 0.0f)
                            : (negative ? -1.0f : 1.0f) * std::numeric_limits<float>::infinity();
        } else if (res.ec != std::errc()) {
            return false;
        }
        p = res.ptr;
        return true;
    }

    static bool parse_int(const char*& p, const char* line_end, int64_t& out) {
        const char* first = p;
        if (line_end - first > 1 && first[0] == '+' && first[1] != '-') ++first;
        const auto res = std::from_chars(first, line_end, out);
        if (res.ec != std::errc() || !value_ends(res.ptr, line_end)) return false;
        p = res.ptr;
        return true;
    }

    void parse_ascii() {
        const size_t off = header_.data_offset;
        const bool cr_only = off > 0 && data_[off - 1] == '\r';  // "end_header\r" not followed by '\n'
        Lines c{data_.data() + off, data_.data() + data_.size(), header_.lines, nullptr, nullptr, cr_only};
        std::vector<uint32_t> polygon;
        for (size_t ei = 0; ei < header_.elements.size(); ++ei) {
            const Element& e = header_.elements[ei];
            if (e.props.empty()) continue;
            const bool is_vertex = ei == vertex_, is_face = ei == face_;
            for (uint64_t i = 0; i < e.count; ++i) {
                if (!next_data_line(c))
                    fail("file ends after line " + std::to_string(c.line) + ", before " + e.name + " " +
                         std::to_string(i) + " (element '" + e.name + "' has " + std::to_string(e.count) +
                         "): truncated, or the header's counts are wrong");
                const auto item = [&] { return e.name + " " + std::to_string(i); };
                const char* p = c.start;
                const char* const le = c.line_end;
                float xyz[3] = {0.0f, 0.0f, 0.0f};
                for (size_t j = 0; j < e.props.size(); ++j) {
                    const Property& prop = e.props[j];
                    if (!at_value(p, le))
                        fail_line(c.line, item() + ": too few values (property '" + prop.name + "' missing)");
                    if (!prop.list) {
                        int k = 0;
                        while (k < 3 && !(is_vertex && coord_[k] == j)) ++k;
                        if (k == 3) {
                            skip_value(p, le);
                        } else if (!parse_float(p, le, prop.type, xyz[k])) {
                            fail_line(c.line, item() + ": property '" + prop.name + "': " + quote(token_at(p, le)) +
                                                  " is not a number");
                        }
                        continue;
                    }
                    int64_t n = 0;
                    const char* const count_at = p;
                    if (!parse_int(p, le, n) || n < 0)
                        fail_line(c.line, item() + ": list '" + prop.name + "': count " + quote(token_at(count_at, le)) +
                                              " is not a non-negative integer");
                    const bool indices = is_face && j == index_;
                    if (indices) {
                        if (n < 3) short_face(i, n, c.line);
                        polygon.clear();
                    }
                    for (int64_t k = 0; k < n; ++k) {
                        if (!at_value(p, le))
                            fail_line(c.line, item() + ": list '" + prop.name + "' has " + std::to_string(k) +
                                                  " values, its count says " + std::to_string(n));
                        if (!indices) {
                            skip_value(p, le);
                            continue;
                        }
                        int64_t v = 0;
                        if (!parse_int(p, le, v))
                            fail_line(c.line, item() + ": vertex index " + quote(token_at(p, le)) +
                                                  " is not an integer");
                        if (v < 0 || static_cast<uint64_t>(v) >= vertex_count_) bad_index(i, v, c.line);
                        polygon.push_back(static_cast<uint32_t>(v));
                    }
                    if (indices) {
                        for (size_t k = 2; k < polygon.size(); ++k) {
                            mesh_.indices.push_back(polygon[0]);
                            mesh_.indices.push_back(polygon[k - 1]);
                            mesh_.indices.push_back(polygon[k]);
                        }
                    }
                }
                if (at_value(p, le))
                    fail_line(c.line, item() + ": more values than the properties of element '" + e.name +
                                          "' (header line " + std::to_string(e.line) + ")");
                if (is_vertex) put_vertex(i, xyz[0], xyz[1], xyz[2], c.line);
            }
        }
        if (next_data_line(c))
            fail_line(c.line, "data after the last element: the header's counts are inconsistent with the file");
    }

    std::string_view data_;
    const std::string& name_;
    Header header_;
    size_t vertex_ = 0, face_ = 0;  // element numbers
    size_t coord_[3] = {0, 0, 0};   // vertex property numbers of x, y, z
    size_t index_ = 0;              // face property number of the index list
    uint64_t vertex_count_ = 0;
    TriangleMesh mesh_;
};


}  // namespace

TriangleMesh parse_ply(std::string_view data, const std::string& name) { return Parser(data, name).parse(); }

TriangleMesh load_ply(const std::string& path) {
    const std::string data = read_whole_file(path);
    return parse_ply(data, path);
}

}  // namespace canopy
