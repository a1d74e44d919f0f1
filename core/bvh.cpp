#include "bvh.h"

#include "error.h"

#include <bit>
#include <cstdio>
#include <fstream>

namespace canopy {

static_assert(std::endian::native == std::endian::little,
              "canopy's file format and tree hash assume a little-endian host");

namespace {
constexpr char kMagic[8] = {'C', 'A', 'N', 'O', 'P', 'Y', 'B', 'V'};
constexpr uint32_t kVersion = 1;

uint64_t fnv1a(uint64_t h, const void* data, size_t size) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < size; ++i) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
    return h;
}
}  // namespace

uint64_t tree_hash(const Bvh& bvh) {
    uint64_t h = 0xcbf29ce484222325ull;
    h = fnv1a(h, bvh.nodes.data(), bvh.nodes.size() * sizeof(Node));
    h = fnv1a(h, bvh.permutation.data(), bvh.permutation.size() * sizeof(uint32_t));
    return h;
}

std::string tree_hash_hex(const Bvh& bvh) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(tree_hash(bvh)));
    return buf;
}

void save_bvh(const Bvh& bvh, const std::string& path) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(path + ": cannot open for writing");
    const uint32_t header[4] = {kVersion, static_cast<uint32_t>(bvh.nodes.size()),
                                static_cast<uint32_t>(bvh.permutation.size()), 0};
    out.write(kMagic, sizeof kMagic);
    out.write(reinterpret_cast<const char*>(header), sizeof header);
    out.write(reinterpret_cast<const char*>(bvh.nodes.data()),
              static_cast<std::streamsize>(bvh.nodes.size() * sizeof(Node)));
    out.write(reinterpret_cast<const char*>(bvh.permutation.data()),
              static_cast<std::streamsize>(bvh.permutation.size() * sizeof(uint32_t)));
    out.flush();
    if (!out) throw Error(path + ": write failed");
}

Bvh load_bvh(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error(path + ": cannot open for reading");
    in.seekg(0, std::ios::end);
    const auto file_size = static_cast<uint64_t>(in.tellg());
    in.seekg(0);
    char magic[8];
    uint32_t header[4];
    if (file_size < sizeof magic + sizeof header ||
        !in.read(magic, sizeof magic) || !in.read(reinterpret_cast<char*>(header), sizeof header))
        throw Error(path + ": too short for a canopy BVH header (" + std::to_string(file_size) +
                    " bytes)");
    if (std::memcmp(magic, kMagic, sizeof magic) != 0)
        throw Error(path + ": not a canopy BVH file (bad magic)");
    if (header[0] != kVersion)
        throw Error(path + ": unsupported canopy BVH version " + std::to_string(header[0]));
    if (header[3] != 0) throw Error(path + ": reserved header field is not 0");
    const uint64_t expected = sizeof magic + sizeof header + uint64_t(header[1]) * sizeof(Node) +
                              uint64_t(header[2]) * sizeof(uint32_t);
    if (expected != file_size)
        throw Error(path + ": size " + std::to_string(file_size) + " does not match the header (" +
                    std::to_string(header[1]) + " nodes, " + std::to_string(header[2]) +
                    " primitives: expected " + std::to_string(expected) + " bytes)");
    Bvh bvh;
    bvh.nodes.resize(header[1]);
    bvh.permutation.resize(header[2]);
    in.read(reinterpret_cast<char*>(bvh.nodes.data()),
            static_cast<std::streamsize>(bvh.nodes.size() * sizeof(Node)));
    in.read(reinterpret_cast<char*>(bvh.permutation.data()),
            static_cast<std::streamsize>(bvh.permutation.size() * sizeof(uint32_t)));
    if (!in) throw Error(path + ": read failed");
    return bvh;
}

}  // namespace canopy
