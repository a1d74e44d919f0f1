// canopy fuzzing: the PLY reader, through load_scene on a .ply file and
// through parse_ply on the same bytes in memory, which must agree: both
// reject, or both give the same mesh bit for bit.
#include "core/ply.h"
#include "fuzz_common.h"

#include <cstring>
#include <string_view>

namespace {

bool same_bits(const canopy::TriangleMesh& a, const canopy::TriangleMesh& b) {
    return a.vertices.size() == b.vertices.size() && a.indices == b.indices &&
           (a.vertices.empty() ||
            std::memcmp(a.vertices.data(), b.vertices.data(), a.vertices.size() * sizeof(canopy::Vec3)) == 0);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static canopy::fuzz::InputFile file(".ply");
    canopy::TriangleMesh from_file;
    const bool loaded = canopy::fuzz::load_or_reject(file.write(data, size), from_file);

    canopy::TriangleMesh from_memory;
    bool parsed = false;
    try {
        from_memory = canopy::parse_ply(std::string_view(reinterpret_cast<const char*>(data), size), "memory");
        parsed = true;
    } catch (const canopy::Error&) {
    } catch (const std::exception& e) {
        canopy::fuzz::fail("parse_ply threw something other than canopy::Error", e.what());
    }
    if (loaded != parsed)
        canopy::fuzz::fail("load_scene and parse_ply disagree", loaded ? "only the file loads" : "only memory parses");
    if (!loaded) return 0;
    if (!same_bits(from_file, from_memory)) canopy::fuzz::fail("load_scene and parse_ply disagree", "different meshes");
    canopy::fuzz::check_loaded(from_file, "ply");
    return 0;
}
