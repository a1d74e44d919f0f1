// canopy fuzzing: the OBJ reader, through load_scene on a .obj file.
#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static canopy::fuzz::InputFile file(".obj");
    canopy::TriangleMesh mesh;
    if (canopy::fuzz::load_or_reject(file.write(data, size), mesh)) canopy::fuzz::check_loaded(mesh, "obj");
    return 0;
}
