// canopy: the OFF (Object File Format) reader.
#pragma once

#include "mesh.h"

#include <string>

namespace canopy {

// InputError naming the file, the line and the element that is wrong.
TriangleMesh load_off(const std::string& path);

}  // namespace canopy
