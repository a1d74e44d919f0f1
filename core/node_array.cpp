// canopy: NodeArray's storage (see node_array.h).
#include "node_array.h"

#include <new>

namespace canopy {

void NodeArray::reallocate(std::size_t n, std::size_t keep) {
    const std::size_t bytes = n * sizeof(Node);
    if (growable_mappings_available() && bytes >= map_min_) {
        if (mapped()) {
            // In place within the reservation, or its pages moved: the old
            // and new sizes are never held at once.
            grow_pages(mapping_, bytes);
        } else {
            PageMapping fresh = map_pages(bytes);
            if (keep) std::memcpy(fresh.p, data_, keep * sizeof(Node));
            release();
            mapping_ = fresh;
        }
        data_ = static_cast<Node*>(mapping_.p);
        capacity_ = mapping_.bytes / sizeof(Node);
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
    if (mapped())
        unmap_pages(mapping_);
    else
        ::operator delete(data_);
    data_ = nullptr;
    capacity_ = 0;
}

}  // namespace canopy
