// canopy: a fast PLY reader (ASCII, binary little and big endian).
//
// Reads the `vertex` element's x, y, z properties (any scalar type) and the
// `face` element's index list (`vertex_indices`, or `vertex_index`, or the
// face element's only list property; any integer count and index types).
// Polygons are triangulated as fans (0, k, k+1), in file order. Every other
// property and element is skipped. Faces must have at least 3 vertices.
//
// Errors are InputError whose message starts with the file name and says
// what is wrong and where: the header line, the data line (ASCII), the
// element and its number (0-based, as PLY indices are), or the byte offset.
// Header counts must agree with the file size: a binary file must end
// exactly after its last element, an ASCII file may only have blank lines
// after it.
#pragma once

#include "mesh.h"

#include <string>
#include <string_view>

namespace canopy {

// Reads the whole file, then parses it.
TriangleMesh load_ply(const std::string& path);

// Parses a PLY file held in memory; `name` prefixes every error message.
TriangleMesh parse_ply(std::string_view data, const std::string& name);

}  // namespace canopy
