// canopy: the node array of a BVH, a vector of nodes whose storage can grow
// without holding its old and new memory at once.
//
// A one-off build keeps its records in the node array's storage, past the
// nodes (core/depth_first.h, NodesBeforeRecords; core/layout.h,
// place_over_records()). When a tree outgrows that storage (random small
// triangles: 1.86 nodes per triangle against the 1.1 slots reserved), a
// std::vector could only copy into a second, bigger array: the old storage
// and the new one held at once, 102 bytes per triangle at the peak of a
// sequential build of 1M random triangles. From kMapMin bytes on, a
// NodeArray lives in a page mapping of its own (core/memory.h), which grows
// in place within a reservation of twice its size, or moves its pages (not
// bytes) to a bigger one; expand() keeps everything in the storage, the
// records past size() included.
//
// The interface is std::vector's where it has one (size, data, reserve,
// resize, emplace_back, ...). Differences: resize() leaves new nodes
// uninitialised (Node's constructor writes nothing), iterators are
// pointers, and expand() is new.
#pragma once

#include "memory.h"
#include "node.h"

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <initializer_list>
#include <utility>

namespace canopy {

class NodeArray {
public:
    // Storage of at least this many bytes is a page mapping where the system
    // has growable ones (Linux): glibc's largest mmap threshold, above which
    // malloc maps every block afresh anyway, so nothing is lost against
    // operator new. Smaller storage comes from operator new, where repeated
    // builds reuse memory malloc has kept (a mapping would be fresh pages,
    // faulted in, every build).
    static constexpr std::size_t kMapMin = std::size_t(32) << 20;

    NodeArray() noexcept = default;
    // An array whose storage is a mapping from `bytes` on instead of
    // kMapMin (tests reach the mapped paths with small arrays this way).
    struct MapFrom {
        std::size_t bytes;
    };
    explicit NodeArray(MapFrom m) noexcept : map_min_(m.bytes) {}
    // An array of n nodes (not initialised) whose storage is a mapping
    // whatever its size, where the system has them, made without reporting
    // its bytes (core/memory.h): the caller reports them, e.g. through a
    // PageLedger as it writes them, all of them before the array lets its
    // storage go. Without mappings, heap storage as usual (mapped() false).
    // `huge` false: advised against huge pages (core/memory.h, map_pages()).
    struct Uncounted {
        bool huge = true;
    };
    NodeArray(Uncounted u, std::size_t n);
    NodeArray(const NodeArray& o) : NodeArray() { assign(o.begin(), o.end()); }
    NodeArray(NodeArray&& o) noexcept { swap(o); }
    NodeArray(std::initializer_list<Node> l) : NodeArray() { assign(l.begin(), l.end()); }
    NodeArray& operator=(std::initializer_list<Node> l) {
        assign(l.begin(), l.end());
        return *this;
    }
    NodeArray& operator=(const NodeArray& o) {
        if (this != &o) assign(o.begin(), o.end());
        return *this;
    }
    NodeArray& operator=(NodeArray&& o) noexcept {
        NodeArray(std::move(o)).swap(*this);
        return *this;
    }
    ~NodeArray() { release(); }

    std::size_t size() const noexcept { return size_; }
    std::size_t capacity() const noexcept { return capacity_; }
    bool empty() const noexcept { return size_ == 0; }
    // Whether the storage is a page mapping (see kMapMin).
    bool mapped() const noexcept { return mapping_.p != nullptr; }

    Node* data() noexcept { return data_; }
    const Node* data() const noexcept { return data_; }
    Node& operator[](std::size_t i) noexcept { return data_[i]; }
    const Node& operator[](std::size_t i) const noexcept { return data_[i]; }
    Node* begin() noexcept { return data_; }
    Node* end() noexcept { return data_ + size_; }
    const Node* begin() const noexcept { return data_; }
    const Node* end() const noexcept { return data_ + size_; }
    Node& front() noexcept { return data_[0]; }
    Node& back() noexcept { return data_[size_ - 1]; }
    const Node& back() const noexcept { return data_[size_ - 1]; }

    void clear() noexcept { size_ = 0; }
    // Capacity for at least n nodes, keeping the first size() (like
    // std::vector::reserve: the rest of the storage is not kept).
    void reserve(std::size_t n) {
        if (n > capacity_) reallocate(n, size_);
    }
    // Capacity for at least n nodes, keeping every byte of the storage, not
    // only the first size() nodes. A mapping grows in place or moves its
    // pages (its old and new sizes are never held at once); heap storage
    // is copied into a mapping (where the system has them; new heap
    // storage otherwise) a piece at a time, each piece given back once
    // copied, so that the two are never held whole at once either.
    void expand(std::size_t n) {
        if (n > capacity_) reallocate(n, capacity_, true);
    }
    // expand(n), and where `inside`, an address in the storage (a record
    // past the nodes), is afterwards.
    template <class T>
    T* expand(std::size_t n, T* inside) {
        const std::size_t offset = std::size_t(reinterpret_cast<const char*>(inside) - reinterpret_cast<const char*>(data_));
        expand(n);
        return reinterpret_cast<T*>(reinterpret_cast<char*>(data_) + offset);
    }
    // Gives the whole pages of the storage inside [from, to) back to the
    // system: their contents are gone and they must not be written again
    // (they are no longer counted). Returns the bytes given back.
    std::size_t discard(const void* from, const void* to) noexcept;
    // Moves the storage's pages [from, from + bytes) (whole pages, a
    // mapping's) to `to`, the storage of another mapped array, without
    // copying (core/memory.h, move_pages()): they are gone from here like
    // discard()ed ones. False where it cannot (heap storage, the system).
    bool give_pages(const void* from, void* to, std::size_t bytes) noexcept;
    // New nodes are not initialised.
    void resize(std::size_t n) {
        if (n > capacity_) reallocate(std::max(n, 2 * capacity_), size_);
        size_ = n;
    }
    Node& emplace_back() {
        if (size_ == capacity_) reallocate(std::max<std::size_t>(2 * capacity_, 1), size_);
        return data_[size_++];
    }
    // `v` may be one of this array's nodes (copied before the array grows).
    void push_back(const Node& v) {
        const Node copy = v;
        emplace_back() = copy;
    }
    // Appends [first, last), which may lie in this array's first size()
    // nodes (found again after the array grows).
    void append(const Node* first, const Node* last) {
        const std::size_t k = std::size_t(last - first), at = size_;
        const bool own = k && first >= data_ && first < data_ + size_;
        const std::size_t from = own ? std::size_t(first - data_) : 0;
        resize(size_ + k);
        if (own) first = data_ + from;
        if (k) std::memcpy(static_cast<void*>(data_ + at), first, k * sizeof(Node));
    }
    void assign(const Node* first, const Node* last) {
        clear();
        append(first, last);
    }
    void swap(NodeArray& o) noexcept {
        std::swap(data_, o.data_);
        std::swap(size_, o.size_);
        std::swap(capacity_, o.capacity_);
        std::swap(mapping_, o.mapping_);
        std::swap(map_min_, o.map_min_);
        std::swap(heap_discarded_, o.heap_discarded_);
    }

private:
    // New storage of at least n nodes holding the first `keep` of the old.
    // `whole` (expand()): heap storage moves into a mapping, where the
    // system has them, without the two held whole at once.
    void reallocate(std::size_t n, std::size_t keep, bool whole = false);
    void move_to_mapping(std::size_t bytes, std::size_t keep);
    void release() noexcept;

    Node* data_ = nullptr;
    std::size_t size_ = 0;
    std::size_t capacity_ = 0;
    PageMapping mapping_;  // p == data_ when the storage is a mapping
    std::size_t map_min_ = kMapMin;
    std::size_t heap_discarded_ = 0;  // heap storage's bytes given back by discard()
};

}  // namespace canopy
