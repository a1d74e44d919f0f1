// canopy: the BVH type (flat node array + primitive permutation).
//
// Canonical layout (the contract every scheduler reproduces bit for bit):
//  - node 0 is the root;
//  - an inner node (count == 0) stores in `index` the position c of its first
//    child; its second child is c + 1;
//  - child pairs are placed in depth-first pre-order of their parents, left
//    subtree first: the root's children are 1 and 2, the left child's
//    children 3 and 4, and so on;
//  - a leaf (count > 0) covers permutation[index, index + count), a
//    contiguous range left in the order the partition produced.
// An empty input gives an empty BVH (no nodes, no permutation).
#pragma once

#include "node_array.h"

#include <cstdint>
#include <cstring>
#include <memory>
#include <new>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace canopy {

// std::allocator, except that resize() leaves new elements default-
// initialised (for integers: unwritten), as NodeArray does for nodes. A
// build sizes the permutation before it starts and its threads write every
// entry; a zero-fill on the calling thread first would fault in a fresh
// array one page at a time, alone (on this project's virtual machine, in
// about a third of the 1M-triangle builds of a `canopy bench` run: 163 to
// 981 faults, 2 to 11 ms, 2026-12-06).
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
    DefaultInitAllocator() = default;
    template <class U>
    DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
    template <class U>
    struct rebind {
        using other = DefaultInitAllocator<U>;
    };
    template <class U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

// The ids of the input primitives in leaf order: a std::vector whose
// resize() does not zero the new entries.
using PrimitiveOrder = std::vector<uint32_t, DefaultInitAllocator<uint32_t>>;


struct Bvh {
    NodeArray nodes;  // std::vector-like; its storage can grow in place (core/node_array.h)
    PrimitiveOrder permutation;  // ids of the input primitives (see PrimitiveOrder)

    bool empty() const { return nodes.empty(); }
    bool operator==(const Bvh& o) const {
        return nodes.size() == o.nodes.size() && permutation == o.permutation &&
               (nodes.empty() ||
                std::memcmp(nodes.data(), o.nodes.data(), nodes.size() * sizeof(Node)) == 0);
    }
};

// FNV-1a 64-bit over the node array's bytes followed by the permutation's
// bytes, as stored (little-endian).
uint64_t tree_hash(const Bvh& bvh);
// 16 lowercase hex digits, no prefix.
std::string tree_hash_hex(const Bvh& bvh);

// The binary file format: the 8 bytes "CANOPYBV", then little-endian uint32
// version (1), node count, primitive count, 0; then the node array and the
// permutation exactly as in memory. Both throw canopy::Error on failure.
void save_bvh(const Bvh& bvh, const std::string& path);
Bvh load_bvh(const std::string& path);

}  // namespace canopy
