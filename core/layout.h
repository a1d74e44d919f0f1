// canopy: placing nodes in the canonical layout.
//
// Parallel schedulers create nodes in whatever order their workers happen to
// run; none of that order may reach the output. Each worker keeps two kinds
// of output in its own arena (PlacementArena):
//
//  - a NodeRecord per node it ran as a task (the few big nodes above the
//    task cutoff), placed by arithmetic:
//
//      c(v) = 1 + 2 * (depth(v) + L(v) - rights(v))
//
//    is the position of the first child of inner node v, where L(v) is the
//    number of leaves whose range starts before v's range (leaves tile the
//    permutation), and rights(v) the number of right turns from the root to
//    v. (In depth-first pre-order, the child pairs allocated before v's are
//    those of v's ancestors and of the inner nodes of the subtrees left of
//    v's path; those subtrees hold L(v) leaves and rights(v) roots, hence
//    L - rights inner nodes.) A left child sits at c(parent), a right child
//    at c(parent) + 1, where the parent's begin, depth and rights follow
//    from the child's record;
//
//  - a SubtreeBlock per subtree it ran inline below the cutoff (almost all
//    nodes): the subtree's nodes in the sequential layout
//    (core/depth_first.h), indices relative to the block. In the canonical
//    layout the descendants of a node fill consecutive slots from its first
//    child's, in the same relative order, so the block's root goes to its
//    arithmetic slot and the rest moves there by one offset: a sequential
//    copy that rewrites child indices.
//
// Renumbering blocks this way was measured against placing every node by
// arithmetic (bench/bench_placement.cpp, README "The schedulers"): the final
// pass took 0.27 to 0.37 times as long, whole 2-thread builds 0.87 to 0.96
// times, and workers store 32 bytes per node instead of 40.
#pragma once

#include "bvh.h"
#include "kernel.h"
#include "memory.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <immintrin.h>
#include <span>
#include <utility>
#include <vector>

namespace canopy {

struct NodeRecord {
    Box box;
    uint32_t begin;
    uint32_t count;  // 0: inner node; otherwise the leaf's primitive count
    uint32_t parent_begin;
    uint8_t depth;
    uint8_t rights;
    uint8_t is_right;
    uint8_t pad = 0;

    static NodeRecord of(const NodeTask& t, bool leaf) {
        return {t.bounds, t.begin, leaf ? t.size() : 0u, t.parent_begin,
                static_cast<uint8_t>(t.depth), t.rights, static_cast<uint8_t>(t.is_right)};
    }
};
static_assert(sizeof(NodeRecord) == 40);

// Rank queries over a bitmap with one bit per permutation slot, set where a
// leaf begins.
class LeafRank {
public:
    explicit LeafRank(uint32_t n) : words_((size_t(n) + 63) / 64 + 1), prefix_(words_.size() + 1) {}

    // Thread-safe: several workers may mark leaves at once.
    void mark(uint32_t begin) {
        std::atomic_ref<uint64_t>(words_[begin / 64]).fetch_or(uint64_t(1) << (begin % 64),
                                                               std::memory_order_relaxed);
    }
    void finish() {
        prefix_[0] = 0;
        for (size_t i = 0; i < words_.size(); ++i)
            prefix_[i + 1] = prefix_[i] + static_cast<uint32_t>(std::popcount(words_[i]));
    }
    // Number of leaves starting strictly before `pos`.
    uint32_t rank(uint32_t pos) const {
        const uint64_t below = (uint64_t(1) << (pos % 64)) - 1;
        return prefix_[pos / 64] + static_cast<uint32_t>(std::popcount(words_[pos / 64] & below));
    }

private:
    std::vector<uint64_t> words_;
    std::vector<uint32_t> prefix_;
};

inline uint32_t first_child_slot(uint32_t depth, uint32_t leaves_before, uint32_t rights) {
    return 1 + 2 * (depth + leaves_before - rights);
}

// The canonical index of the node a record describes. `rank.rank(pos)`: the
// number of leaves starting before pos.
template <class Rank>
uint32_t canonical_slot(const NodeRecord& r, const Rank& rank) {
    if (r.depth == 0) return 0;
    const uint32_t pbegin = r.is_right ? r.parent_begin : r.begin;
    const uint32_t prights = r.rights - r.is_right;
    return first_child_slot(r.depth - 1u, rank.rank(pbegin), prights) + r.is_right;
}

// A subtree one worker built inline (see the top of this file). Its nodes
// are kept one of two ways, as the arena says (PlacementArena::over_records):
//  - all `size` of them in the arena's chunks: chunks[chunk] from `first` on,
//    then the following chunks from their start (it filled each but its last);
//  - over its own records (a one-off build, whose records lie in the final
//    node array's storage): block nodes 1 to `over_records` written over the
//    records [root.begin, root.begin + over_records), which the subtree no
//    longer needs once it is built, and the nodes after them, when the block
//    has more nodes than records, in the chunks from (chunk, first) as above.
//    Block node 0, the subtree's root, is not stored: `root` describes it
//    (an inner root's first child is block node 1).
struct SubtreeBlock {
    NodeRecord root;      // where the subtree's root sits in the tree
    uint32_t chunk = 0;
    uint32_t first = 0;
    uint32_t size = 0;
    uint32_t leaves = 0;
    uint32_t over_records = 0;
};

// A chunk of a worker's nodes: from 2 MiB on, 2 MiB-aligned memory, so
// that a chunk of whole huge pages faults only in huge pages (see
// allocate_huge() and Workers::reset(), which sizes the chunks).
using NodeChunk = std::vector<Node, HugePageAllocator<Node>>;

// What one worker leaves for the placement.
//
// A worker's subtree blocks go one after another into chunks of nodes, and
// a block that fills a chunk goes on in a new one (ChunkedNodes below), so
// every chunk but the last ends full. (Until 825a86f, 2026-12-05, the last
// one's unused end was given back before the final array was allocated;
// one-off builds no longer allocate one when the tree fits over the
// records, and warm builds keep their chunks. Until late on 2026-12-02 a block needed
// room for its bound, twice its primitives, in one chunk before it started,
// so each chunk's end and the last chunk's unused part were waste that
// depended on which worker built which subtree: the 2-thread peak of
// dragon_vrip_res2 was 79.5 to 86.9 bytes per triangle.)
struct PlacementArena {
    std::vector<NodeRecord> records;        // nodes run one at a time
    std::vector<NodeChunk> chunks;          // the blocks' nodes, block after block
    std::vector<SubtreeBlock> blocks;
    size_t chunk_nodes = size_t(1) << 17;   // chunk size (4 MiB)
    std::vector<NodeChunk> spare;           // emptied chunks of earlier builds
    bool over_records = false;              // blocks are kept over their records (SubtreeBlock)
    NodeArray scratch;                      // one block's nodes while it is built (over_records)

    // The chunk a new block starts in: the last one (ChunkedNodes moves on
    // when it is full).
    NodeChunk& open_chunk() {
        if (chunks.empty()) return new_chunk();
        return chunks.back();
    }
    // A new last chunk, never grown past its capacity, so node addresses in
    // it stay valid.
    NodeChunk& new_chunk() {
        const size_t cap = std::max<size_t>(chunk_nodes, 1);
        NodeChunk c;
        if (!spare.empty() && spare.back().capacity() >= cap) {
            c = std::move(spare.back());
            spare.pop_back();
        } else {
            c.reserve(cap);  // NodeChunk's allocator advises huge pages itself
        }
        return chunks.emplace_back(std::move(c));
    }
    // Appends k nodes to the chunks, from where the last one has room and
    // on into new ones; returns where they start (chunk, first).
    std::pair<uint32_t, uint32_t> append(const Node* src, size_t k) {
        NodeChunk* c = &open_chunk();
        if (c->size() == c->capacity()) c = &new_chunk();
        const std::pair<uint32_t, uint32_t> at{static_cast<uint32_t>(chunks.size() - 1),
                                               static_cast<uint32_t>(c->size())};
        while (k > 0) {
            if (c->size() == c->capacity()) c = &new_chunk();
            const size_t take = std::min(k, c->capacity() - c->size());
            c->insert(c->end(), src, src + take);
            src += take;
            k -= take;
        }
        return at;
    }
    // Empties the arena for another build; the chunks' memory is kept for
    // new_chunk() to reuse.
    void reset() {
        records.clear();
        blocks.clear();
        for (auto& c : chunks) {
            c.clear();
            spare.push_back(std::move(c));
        }
        chunks.clear();
        // Largest last, the one new_chunk() looks at.
        std::sort(spare.begin(), spare.end(),
                  [](const NodeChunk& a, const NodeChunk& b) { return a.capacity() < b.capacity(); });
    }
    size_t node_count() const {
        size_t n = records.size();
        for (const SubtreeBlock& b : blocks) n += b.size;
        return n;
    }
};

// A worker's subtree block in its arena's chunks, as build_depth_first
// (core/depth_first.h) fills it: slots are node addresses, which stay valid
// because chunks never grow; the block starts where the last chunk has room
// and goes on at the start of a new chunk whenever one is full.
class ChunkedNodes {
public:
    struct Slot {
        Node* node;
        uint32_t number;  // in the block
    };
    explicit ChunkedNodes(PlacementArena& a) : arena_(a), chunk_(&a.open_chunk()) {}

    Slot root() {
        const Slot s = next();
        first_chunk_ = static_cast<uint32_t>(arena_.chunks.size() - 1);
        first_ = static_cast<uint32_t>(chunk_->size() - 1);
        return s;
    }
    std::array<Slot, 2> pair(uint32_t /*live*/) {
        const Slot a = next();
        return {a, next()};
    }
    static uint32_t number(Slot s) { return s.number; }
    static Node& at(Slot s) { return *s.node; }

    // Where the block starts (after root()), and how many nodes it has.
    uint32_t first_chunk() const { return first_chunk_; }
    uint32_t first() const { return first_; }
    uint32_t size() const { return count_; }

private:
    Slot next() {
        if (chunk_->size() == chunk_->capacity()) chunk_ = &arena_.new_chunk();
        return {&chunk_->emplace_back(), count_++};
    }
    PlacementArena& arena_;
    NodeChunk* chunk_;
    uint32_t first_chunk_ = 0, first_ = 0, count_ = 0;
};

// L(v) from the pieces that tile the permutation (leaf records and blocks):
// sorted by where they begin, with a prefix sum of their leaves. A node's
// range is a union of whole pieces, so the leaves before it are those of
// the pieces that begin before it. Pieces are few (one per task), not one
// per leaf.
class PieceRank {
public:
    void add(uint32_t begin, uint32_t leaves) { pieces_.push_back({begin, leaves}); }
    void finish() {
        std::sort(pieces_.begin(), pieces_.end(), [](const Piece& a, const Piece& b) { return a.begin < b.begin; });
        begins_.resize(pieces_.size());
        prefix_.resize(pieces_.size() + 1);
        prefix_[0] = 0;
        for (size_t i = 0; i < pieces_.size(); ++i) {
            begins_[i] = pieces_[i].begin;
            prefix_[i + 1] = prefix_[i] + pieces_[i].leaves;
        }
    }
    uint32_t rank(uint32_t pos) const {
        return prefix_[size_t(std::lower_bound(begins_.begin(), begins_.end(), pos) - begins_.begin())];
    }

private:
    struct Piece {
        uint32_t begin, leaves;
    };
    std::vector<Piece> pieces_;
    std::vector<uint32_t> begins_, prefix_;
};

// dst[j] = src[j] for j < k, with `shift` added to the child index of every
// inner node (count 0). With AVX2 one 256-bit load and store per node.
inline void copy_shifted(const Node* src, size_t k, uint32_t shift, Node* dst) {
    size_t j = 0;
#if defined(__AVX2__)
    static_assert(offsetof(Node, index) == 24 && offsetof(Node, count) == 28);
    const __m256i add = _mm256_set_epi32(0, int(shift), 0, 0, 0, 0, 0, 0);
    const __m256i zero = _mm256_setzero_si256();
    for (; j < k; ++j) {
        const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(src + j));
        // Lane 7 (count) == 0 gives all ones in lane 7; moved to lane 6 (index).
        const __m256i inner = _mm256_bsrli_epi128(_mm256_cmpeq_epi32(v, zero), 4);
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(dst + j), _mm256_add_epi32(v, _mm256_and_si256(inner, add)));
    }
#endif
    for (; j < k; ++j) {
        Node n = src[j];
        if (!n.is_leaf()) n.index += shift;
        dst[j] = n;
    }
}

// copy_shifted() for ranges that may overlap: a block whose nodes lie over
// its records moves to slots before or after them (place_over_records()).
// Going up, the nodes are taken from the last one down, so that each is
// read before a store can reach it.
inline void move_shifted(const Node* src, size_t k, uint32_t shift, Node* dst) {
    if (!(dst > src && dst < src + k)) return copy_shifted(src, k, shift, dst);
    for (size_t j = k; j-- > 0;) {
        Node n = src[j];
        if (!n.is_leaf()) n.index += shift;
        dst[j] = n;
    }
}

// Copies `count` nodes of an arena's chunks, from chunks[chunk][first] on
// and at the start of each following chunk (as a block fills them), to dst,
// adding `shift` to inner nodes' child indices.
inline void copy_from_chunks(const PlacementArena& a, uint32_t chunk, uint32_t first, size_t count, uint32_t shift,
                             Node* dst) {
    uint32_t k = chunk;
    const Node* src = a.chunks[k].data() + first;
    size_t left_here = a.chunks[k].size() - first;
    while (count > 0) {
        if (left_here == 0) {
            ++k;
            src = a.chunks[k].data();
            left_here = a.chunks[k].size();
        }
        const size_t take = std::min(left_here, count);
        copy_shifted(src, take, shift, dst);
        src += take;
        dst += take;
        left_here -= take;
        count -= take;
    }
}

// Writes the node a record describes (a task node, or a block's root) into
// its canonical slot.
template <class Rank>
void place_record(const NodeRecord& r, const Rank& rank, Node* nodes) {
    Node& n = nodes[canonical_slot(r, rank)];
    n.set_box(r.box);
    if (r.count) {
        n.index = r.begin;
        n.count = r.count;
    } else {
        n.index = first_child_slot(r.depth, rank.rank(r.begin), r.rights);
        n.count = 0;
    }
}

// The canonical slot of an inner block root's first child: block node i >= 1
// goes to it + i - 1, and an inner node's relative child index j becomes
// it + j - 1.
template <class Rank>
uint32_t block_first_child(const SubtreeBlock& b, const Rank& rank) {
    return first_child_slot(b.root.depth, rank.rank(b.root.begin), b.root.rights);
}

// Copies the nodes after a block's root (block nodes 1 to size - 1) to `dst`,
// its first child's canonical slot `c`, from wherever the arena keeps them
// (`refs`: the records, over which an over_records arena wrote them).
inline void place_block_body(const PlacementArena& a, const SubtreeBlock& b, const PrimRef* refs, uint32_t c,
                             Node* dst) {
    size_t body = b.size - 1;
    if (a.over_records) {
        move_shifted(reinterpret_cast<const Node*>(refs + b.root.begin), b.over_records, c - 1, dst);
        dst += b.over_records;
        body -= b.over_records;
        if (body) copy_from_chunks(a, b.chunk, b.first, body, c - 1, dst);
    } else {
        // The root is the chunks' node (b.chunk, b.first); the body follows.
        copy_from_chunks(a, b.chunk, b.first + 1, body, c - 1, dst);
    }
}

// Writes one arena's records and blocks into their canonical slots of `nodes`.
template <class Rank>
void place_arena(const PlacementArena& arena, const Rank& rank, const PrimRef* refs, Node* nodes) {
    for (const NodeRecord& r : arena.records) place_record(r, rank, nodes);
    for (const SubtreeBlock& b : arena.blocks) {
        place_record(b.root, rank, nodes);
        if (b.size <= 1) continue;
        const uint32_t c = block_first_child(b, rank);
        place_block_body(arena, b, refs, c, nodes + c);
    }
}

// L(v) for every arena's pieces, and the number of nodes.
inline size_t rank_pieces(std::span<const PlacementArena* const> arenas, PieceRank& rank) {
    size_t total = 0;
    for (const PlacementArena* a : arenas) {
        total += a->node_count();
        for (const NodeRecord& r : a->records)
            if (r.count) rank.add(r.begin, 1);
        for (const SubtreeBlock& b : a->blocks) rank.add(b.root.begin, b.leaves);
    }
    rank.finish();
    return total;
}

// Places all arenas into `nodes`, a fresh array. `for_each(k, fn)` runs fn(i)
// for i in [0, k), possibly in parallel; the result does not depend on how.
// `refs`: the records, for over_records arenas.
template <class ForEach>
void place_nodes(std::span<const PlacementArena* const> arenas, const PrimRef* refs, NodeArray& nodes,
                 ForEach&& for_each) {
    PieceRank rank;
    const size_t total = rank_pieces(arenas, rank);
    nodes.clear();
    nodes.reserve(total);
    nodes.resize(total);
    for_each(arenas.size(), [&](size_t i) { place_arena(*arenas[i], rank, refs, nodes.data()); });
}

// A block of an in-place placement: its arena, and its first child's
// canonical slot.
struct BlockMove {
    const PlacementArena* arena;
    const SubtreeBlock* block;
    uint32_t c;
};

// Moves the blocks' bodies (sorted by range, each to slots at or before its
// records: see place_over_records()) to their slots of `out`, split into
// `groups` runs of consecutive blocks with about equal numbers of nodes,
// run by for_each, in any order or at once. In order within a run, no block
// overwrites another's nodes before they have moved (see below); across
// runs, a block whose slots start before its run's first records may
// overwrite the records of an earlier run's blocks, which may not have
// moved yet: each run first copies such blocks (a prefix of it, since slots
// and records both grow along the run) into a buffer of its own, then
// moves the rest in order, and every buffer goes to its slots once all
// runs are done. A run's own moves stay below its next run's first slot,
// and so below that run's records. The buffers hold about the gap between
// the slots and the records at each run's start: at most the storage's
// slack (a tenth of a node per record).
template <class ForEach>
void move_blocks(std::span<const BlockMove> moves, const PrimRef* refs, Node* out, size_t groups,
                 ForEach&& for_each) {
    groups = std::clamp<size_t>(groups, 1, std::max<size_t>(moves.size(), 1));
    if (groups == 1) {
        for (const BlockMove& m : moves) place_block_body(*m.arena, *m.block, refs, m.c, out + m.c);
        return;
    }
    size_t body = 0;
    for (const BlockMove& m : moves) body += m.block->size - 1;
    std::vector<size_t> first(groups + 1, moves.size());
    first[0] = 0;
    size_t done = 0, g = 1;
    for (size_t k = 0; k < moves.size() && g < groups; ++k) {
        while (g < groups && done >= body * g / groups) first[g++] = k;
        done += moves[k].block->size - 1;
    }
    const auto at = [](const void* p) { return reinterpret_cast<std::uintptr_t>(p); };
    std::vector<std::vector<Node>> buffer(groups);
    std::vector<size_t> buffered_end(groups);
    for_each(groups, [&](size_t r) {
        size_t k = first[r], e = k;
        if (r > 0 && k < first[r + 1]) {
            // Blocks whose slots start below this run's first records.
            const std::uintptr_t limit = at(refs + moves[k].block->root.begin);
            size_t count = 0;
            for (; e < first[r + 1] && at(out + moves[e].c) < limit; ++e) count += moves[e].block->size - 1;
            reserve_on_huge_pages(buffer[r], count);
            buffer[r].resize(count);  // Node() writes nothing
            Node* dst = buffer[r].data();
            for (; k < e; ++k) {
                const BlockMove& m = moves[k];
                place_block_body(*m.arena, *m.block, refs, m.c, dst);
                dst += m.block->size - 1;
            }
        }
        buffered_end[r] = e;
        for (; k < first[r + 1]; ++k) {
            const BlockMove& m = moves[k];
            place_block_body(*m.arena, *m.block, refs, m.c, out + m.c);
        }
    });
    for_each(groups, [&](size_t r) {
        const Node* src = buffer[r].data();
        for (size_t k = first[r]; k < buffered_end[r]; ++k) {
            const size_t size = moves[k].block->size - 1;
            std::memcpy(static_cast<void*>(out + moves[k].c), src, size * sizeof(Node));
            src += size;
        }
    });
}

// The same for blocks whose slots start after their records (a tree with
// more nodes than records: place_over_records()), on one thread: the last
// block first, each moving up past the records of the blocks before it.
// (Split into runs like move_blocks(), each run would first have to copy
// aside its blocks whose slots lie over the next run's records: the gap
// between slots and records grows to the tree's excess of nodes over
// records, 0.86 nodes per record at the top of a random scene's tree. Run
// on two threads that way, the placement of a 2-thread build of 4M random
// triangles took 157 to 185 ms against 49 to 54 on one.)
// `up(move)` picks those blocks out of `moves`.
template <class Up>
void move_blocks_up(std::span<const BlockMove> moves, const PrimRef* refs, Node* out, Up&& up) {
    for (size_t k = moves.size(); k-- > 0;)
        if (up(moves[k])) place_block_body(*moves[k].arena, *moves[k].block, refs, moves[k].c, out + moves[k].c);
}

// Places over_records arenas into `nodes`, whose storage (its capacity; the
// vector is empty) holds the records `refs` and, over them, the blocks'
// nodes: in that same storage when the tree fits in it and every block's
// nodes move towards the front (its canonical slots start at or before its
// records, as when the tree has at most about one node per record up to
// every point: the storage has a tenth more slots than records, in front of
// them). The blocks move in the order of their ranges, each to slots
// before those of every later block's records, so no block is overwritten
// before it has moved; then the task nodes and the blocks' roots are
// written; a tree of at least `parallel_min` nodes moves split over the
// arenas' workers (move_blocks()). A tree that does not fit this way
// (random triangles' trees: 1.86 nodes per record) grows the storage to
// its size instead (NodeArray::expand(), which keeps the records and the
// blocks over them at their offsets; a mapping, from NodeArray::kMapMin
// bytes, grows without a second copy), and the blocks move in two steps:
// first those whose slots start after their records (move_blocks_up():
// each moves up past the records of every block before it, and ends below
// the slots, hence below the records, of every block after it), then the
// others in order as above, all on one thread; the workers only touch the
// storage's new pages first. (Until 2026-12-05 such a tree went
// into a fresh array beside the storage: 127 bytes per triangle at the
// peak of a 2-thread build of 1M random triangles.)
template <class ForEach>
void place_over_records(std::span<const PlacementArena* const> arenas, const PrimRef* refs, NodeArray& nodes,
                        ForEach&& for_each, size_t parallel_min = 0) {
    PieceRank rank;
    const size_t total = rank_pieces(arenas, rank);
    std::vector<BlockMove> moves;
    for (const PlacementArena* a : arenas)
        for (const SubtreeBlock& b : a->blocks)
            if (b.size > 1) moves.push_back({a, &b, 0});
    std::sort(moves.begin(), moves.end(),
              [](const BlockMove& x, const BlockMove& y) { return x.block->root.begin < y.block->root.begin; });
    bool in_place = total <= nodes.capacity();
    const auto at = [](const void* p) { return reinterpret_cast<std::uintptr_t>(p); };
    for (BlockMove& m : moves) {
        m.c = block_first_child(*m.block, rank);
        in_place = in_place && at(nodes.data() + m.c) <= at(refs + m.block->root.begin);
    }
    if (in_place) {
        // Within the capacity: no reallocation, and Node() writes nothing.
        nodes.resize(total);
        move_blocks(moves, refs, nodes.data(), total >= parallel_min ? arenas.size() : 1, for_each);
    } else {
        const size_t old_capacity = nodes.capacity();
        refs = nodes.expand(total, refs);
        nodes.resize(total);
        Node* const base = nodes.data();
        // The storage's new part is fresh memory, faulted in as it is first
        // written: touched here by every worker, a slice each, rather than
        // by the one thread that moves the blocks up.
        const size_t groups = total >= parallel_min ? arenas.size() : 1;
        if (groups > 1 && total > old_capacity) {
            char* const fresh = reinterpret_cast<char*>(base + old_capacity);
            const size_t bytes = (total - old_capacity) * sizeof(Node);
            for_each(groups, [&](size_t r) {
                for (size_t i = bytes * r / groups / 4096 * 4096; i < bytes * (r + 1) / groups; i += 4096) fresh[i] = 0;
            });
        }
        const auto up = [&](const BlockMove& m) { return at(base + m.c) > at(refs + m.block->root.begin); };
        move_blocks_up(moves, refs, base, up);
        // The others, still in the order of their ranges (no second list
        // while the storage and the chunks are both held: the peak).
        // On one thread too: split into runs, the buffers of the blocks
        // copied aside would add to the peak (1.6 bytes per triangle on
        // 1.1M random triangles).
        moves.erase(std::remove_if(moves.begin(), moves.end(), up), moves.end());
        move_blocks(moves, refs, base, 1, for_each);
    }
    Node* const out = nodes.data();
    for_each(arenas.size(), [&](size_t i) {
        for (const NodeRecord& r : arenas[i]->records) place_record(r, rank, out);
        for (const SubtreeBlock& b : arenas[i]->blocks) place_record(b.root, rank, out);
    });
}

}  // namespace canopy
