// canopy fuzzing: tinyobjloader compiled from its header, instrumented like
// the rest, so that the OBJ target sees inside it too. The definitions here
// take the place of Debian's libtinyobjloader (the same version's header).
#define TINYOBJLOADER_IMPLEMENTATION
#include <tiny_obj_loader.h>
