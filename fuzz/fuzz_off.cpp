// canopy fuzzing: the OFF reader, through load_scene on a .off file.
#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static canopy::fuzz::InputFile file(".off");
    canopy::TriangleMesh mesh;
    if (canopy::fuzz::load_or_reject(file.write(data, size), mesh)) canopy::fuzz::check_loaded(mesh, "off");
    return 0;
}
