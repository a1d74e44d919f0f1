// canopy: NodeArray's storage (see node_array.h).
#include "node_array.h"

#include "memory.h"

#include <new>

namespace canopy {

namespace {
constexpr std::size_t kPage = 4096;
std::size_t whole_pages(std::size_t bytes) { return (bytes + kPage - 1) / kPage * kPage; }
}  // namespace

void NodeArray::reallocate(std::size_t n, std::size_t keep) {
    const std::size_t bytes = n * sizeof(Node);
    if (growable_mappings_available() && bytes >= map_min_) {
        const std::size_t mapping = whole_pages(bytes);
        if (mapped_) {
            // The old and new sizes are not held at once: mremap moves pages.
            data_ = static_cast<Node*>(remap_pages(data_, capacity_ * sizeof(Node), mapping));
        } else {
            Node* fresh = static_cast<Node*>(map_pages(mapping));
            if (keep) std::memcpy(static_cast<void*>(fresh), data_, keep * sizeof(Node));
            release();
            data_ = fresh;
            mapped_ = true;
        }
        capacity_ = mapping / sizeof(Node);
        return;
    }
    Node* fresh = static_cast<Node*>(::operator new(bytes));
    advise_huge_pages(fresh, bytes);
    if (keep) std::memcpy(static_cast<void*>(fresh), data_, keep * sizeof(Node));
    release();  // keeps size_
    data_ = fresh;
    capacity_ = n;
}

void NodeArray::release() noexcept {
    if (data_ == nullptr) return;
    if (mapped_)
        unmap_pages(data_, capacity_ * sizeof(Node));
    else
        ::operator delete(data_);
    data_ = nullptr;
    capacity_ = 0;
    mapped_ = false;
}

}  // namespace canopy
