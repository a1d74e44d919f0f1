// canopy: one big node task run by many threads.
//
// Near the root there are fewer nodes than threads, so a big node is binned
// and partitioned by the whole team. The node is cut into phases; the
// scheduler runs the `parallel` phases with its own parallel loop and the
// `serial` ones on one thread, with a barrier between phases (see
// run_parallel_node). The result is bit-identical to run_node():
//  - bins merge with min/max and integer sums only (exact, order-free), so
//    neither how the range is cut into chunks nor which chunks share a bin
//    set (see take_bins()) matters;
//  - the partition swaps the same pairs as partition() (see mark_sides()
//    in kernel/team_partition.h): the chunks find their records' sides as bits, with their
//    share of the child bounds (merged exactly too); one thread cuts the
//    misplaced pairs into pieces by rank, and the pieces are swapped in
//    parallel. Bin, mark and swap: the swap pass touches only the misplaced
//    records. Teams of fewer than kTeamPartitionMin threads partition by
//    halves instead (partition_half() in kernel/team_partition.h): two threads each read
//    half of the records once, pairing misplaced records from either end
//    of the rank order, and one pairs what the two left over.
// A node that chooses its axis from a sample (samples_axis()) first bins
// its chunks' shares of the sample, merged and evaluated by one thread
// (choose_axis()), as binning_mapper() does in run_node().
// It bins every node it is given, so it is given none of the small nodes
// that run_node() costs exactly (kExactMaxPrims; sched::team_parallel()).
// A node of at least BuildOptions::rotate_min primitives then chooses its
// children's splits, one child per thread (look_ahead()), and one thread
// carries them to the children or rotates (kernel/rotate.h), as run_node()
// does; a node whose split was chosen before (NodeTask::carried) skips the
// binning, and one chosen as a range of records skips the partition too.
#pragma once

#include "kernel.h"
#include "trace.h"

#include <algorithm>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

namespace canopy {

class ParallelNode {
public:
    // Records per chunk (bin and mark): a multiple of 64, about kChunk or
    // more, such that a node has at most kMaxChunks chunks and, below that,
    // a multiple of the team's size of them (equal shares: the dragon's
    // root in chunks of 32,768 was seven chunks, four of them on one of two
    // threads).
    static constexpr uint32_t kChunk = 32768;
    static constexpr uint32_t kMaxChunks = 32;
    static constexpr uint32_t kSwapPiece = 16384;  // misplaced pairs per swap piece
    // Teams smaller than this partition a node by halves (two threads,
    // partition_half() and swap_leftovers()) instead of marking sides and
    // swapping by chunks. The chunked partition reads the records twice
    // (mark, then swap), the halves once, swapping each block's misplaced
    // records while they are in cache; on this project's 2-core machines the
    // chunked partition of the 1M sphere's root took longer with two
    // threads (mark 1.1 to 1.5 ms, swap 3.4 ms, traced) than partition()
    // with one (3.4 to 3.6 ms), and until 2026-12-04 (evening) a team of two
    // partitioned on one thread. By halves, on the Intel host (traced 2-thread
    // builds, three each): the 1M sphere's root 1.9 to 2.1 ms against 3.2 to
    // 3.4 on one thread, dragon_vrip_res2's 0.31 to 0.42 against 0.51 to
    // 0.67. The result is the same every way.
    static constexpr uint32_t kTeamPartitionMin = 4;

    // `team`: how many threads will run the parallel phases (a hint: the
    // bin sets they need are made in the serial start phase).
    ParallelNode(const KernelContext& ctx, const NodeTask& t, uint32_t team)
        : ctx_(ctx), t_(t), team_(std::max(1u, team)) {}
    const NodeTask& task() const { return t_; }

    // Whether the node is (still) going to split; read it after the serial
    // phases, from any thread.
    bool splits() const { return splits_; }

    // Serial: decides what kind of node this is; a leaf ends the task.
    void start(SkipCounts& skip) {
        splits_ = start_impl(skip);
        if (!splits_) write_leaf(ctx_, t_);
    }

    // Serial: merges the bins and evaluates; may turn the node into a leaf.
    void decide(SkipCounts& skip) {
        splits_ = decide_impl(skip);
        if (!splits_) write_leaf(ctx_, t_);
    }

private:
    bool start_impl(SkipCounts& skip) {
        plan_ = plan(t_, *ctx_.options, skip);
        if (plan_ == Plan::Leaf) return false;
        if (plan_ == Plan::Sah && t_.carried) {
            // Chosen before (kernel/rotate.h): nothing to bin; a range is
            // not even partitioned.
            chosen_ = ctx_.carry->take(t_);
            if (chosen_.kind == ChosenSplit::Kind::Range) {
                ++skip.parallel_nodes;
                range_ = true;
                plan_ = Plan::Middle;
                chunks_ = 0;
                chunk_.clear();
                return true;
            }
            m_ = chosen_.m;
            split_ = chosen_.s;
        } else if (plan_ == Plan::Sah) {
            m_ = BinMapper::make(t_.cbounds, bins_for(t_.size(), ctx_.options->bins));
            if (!m_.any_valid()) {
                ++skip.coincident_nodes;
                if (t_.size() <= ctx_.options->max_leaf) return false;
                plan_ = Plan::Middle;
            } else {
                skip.axes_not_binned += 3 - (m_.valid[0] + m_.valid[1] + m_.valid[2]);
                sample_step_ = samples_axis(m_, t_.size()) ? sample_step(t_) : 0;
                cuts_ = SizeCuts::of(t_.bounds);
                sizes_ = cuts_.applies(t_);
            }
        }
        ++skip.parallel_nodes;
        const uint64_t size = t_.size(), team_chunk = uint64_t(team_) * kChunk;
        uint64_t want = std::max<uint64_t>(1, (size + team_chunk - 1) / team_chunk) * team_;
        if (want > kMaxChunks) want = std::max<uint64_t>(team_, kMaxChunks / team_ * team_);
        chunk_size_ = static_cast<uint32_t>(((size + want - 1) / want + 63) / 64 * 64);
        chunks_ = static_cast<uint32_t>((uint64_t(t_.size()) + chunk_size_ - 1) / chunk_size_);
        const uint32_t binned = bin_chunks();
        chunk_sizes_.assign(sizes_ ? binned : 0, SizeBins{});
        bin_pool_.clear();
        free_bins_.clear();
        for (uint32_t i = 0; i < std::min(binned, team_); ++i) free_bins_.push_back(new_bins());
        chunk_.assign(chunks_, PartitionResult{});
        return true;
    }

    bool decide_impl(SkipCounts& skip) {
        if (plan_ != Plan::Sah) return true;
        if (!t_.carried) {
            for (size_t i = 1; i < bin_pool_.size(); ++i) bin_pool_[0]->merge(*bin_pool_[i], m_.bins);
            split_ = evaluate(*bin_pool_[0], m_, t_.bounds, *ctx_.options);
            if (sizes_) {
                for (uint32_t i = 1; i < chunks_; ++i) chunk_sizes_[0].merge(chunk_sizes_[i]);
                consider_size_split(chunk_sizes_[0], cuts_, t_.bounds, *ctx_.options, split_);
                skip.size_splits += split_.by_size();
            }
            if (sah_says_leaf(split_, t_.size(), *ctx_.options)) return false;
        }
        if (!split_.found()) {
            plan_ = Plan::Middle;
            return true;
        }
        if (partitions_by_halves())
            chunk_.assign(2, PartitionResult{});
        else
            sides_.resize((t_.size() + kSideBlock - 1) / kSideBlock);
        return true;
    }

public:
    // Parallel over [0, sample_chunks()), before the bin phase: bins one
    // chunk's share of the sample (binning_mapper() in kernel.h).
    uint32_t sample_chunks() const { return plan_ == Plan::Sah && !t_.carried && sample_step_ ? chunks_ : 0; }
    void sample_chunk(uint32_t i) {
        BinSet* b = take_bins();
        const auto [lo, hi] = chunk_range(i);
        assert((lo - t_.begin) % sample_step_ == 0);  // the chunk's sample is the node's
        bin_sample(ctx_.refs, lo, hi, sample_step_, m_, *b);
        give_back(b);
    }
    // Serial, after the sample: the axis to bin on, as binning_mapper()
    // chooses it; the bin sets are cleared again for the bin phase.
    void choose_axis(SkipCounts& skip) {
        if (!sample_chunks()) return;
        for (size_t i = 1; i < bin_pool_.size(); ++i) bin_pool_[0]->merge(*bin_pool_[i], m_.bins);
        const BinMapper chosen = mapper_from_sample(*bin_pool_[0], m_, t_.bounds, *ctx_.options, skip);
        for (const auto& b : bin_pool_) b->clear(m_.bins);
        m_ = chosen;
    }

    // Parallel over [0, bin_chunks()): bins one chunk.
    uint32_t bin_chunks() const { return plan_ == Plan::Sah && !t_.carried ? chunks_ : 0; }
    void bin_chunk(uint32_t i) {
        BinSet* b = take_bins();
        const auto [lo, hi] = chunk_range(i);
        bin(ctx_.refs, lo, hi, m_, *b, ctx_.permutation);
        give_back(b);
        if (sizes_) bin_sizes(ctx_.refs, lo, hi, cuts_, chunk_sizes_[i]);
    }

    // Whether the split moves records (a SAH split) or is a middle split,
    // which leaves them in place.
    bool moves() const { return plan_ == Plan::Sah; }
    uint32_t chunks() const { return chunks_; }

    // Whether the records are partitioned by halves (partition_half() and
    // pair_leftovers()) rather than by mark_chunk() and swap_piece() (see
    // kTeamPartitionMin).
    bool partitions_by_halves() const { return team_ < kTeamPartitionMin; }
    // Whether the sides come from the keys bin_chunk() wrote and the
    // children's bounds from the bins, as run_node() does for a plane split
    // of more than kBinBlock records.
    bool from_bins() const { return !split_.by_size() && t_.size() > kBinBlock; }
    const uint32_t* keys() const { return from_bins() ? ctx_.permutation : nullptr; }
    // Parallel over [0, 2), SAH splits of a small team: one half of the
    // two-ended partition (kernel/team_partition.h).
    void partition_half(uint32_t i) {
        chunk_[i] = i == 0 ? canopy::partition_half<0>(ctx_.refs, t_.begin, t_.end, m_, split_, halves_[0], keys())
                           : canopy::partition_half<1>(ctx_.refs, t_.begin, t_.end, m_, split_, halves_[1], keys());
    }
    // Serial, after both halves: swaps the pairs they left.
    void pair_leftovers() { swap_leftovers(ctx_.refs, halves_[0], halves_[1]); }

    // Parallel over [0, chunks()), SAH splits: a chunk's side bits and its
    // share of the child bounds.
    void mark_chunk(uint32_t i) {
        const auto [lo, hi] = chunk_range(i);
        chunk_[i] = mark_sides(ctx_.refs, lo, hi, t_.begin, m_, split_, sides_.data(), keys());
    }

    // Serial, after mark_chunk(): cuts the misplaced pairs into pieces.
    void cut_swaps() { plan_swaps(sides_.data(), t_.begin, t_.begin + split_.left_count, kSwapPiece, pieces_); }

    // Parallel over [0, pieces()): swaps one piece's pairs.
    uint32_t pieces() const { return static_cast<uint32_t>(pieces_.size()); }
    void swap_piece(uint32_t i) { swap_misplaced(ctx_.refs, sides_.data(), t_.begin, pieces_[i]); }

    // Parallel over [0, chunks()), middle splits: a chunk's share of each
    // half's bounds (the records stay where they are).
    void middle_chunk(uint32_t i) {
        const auto [lo, hi] = chunk_range(i);
        const uint32_t mid = t_.begin + t_.size() / 2;
        ChildBounds4 acc;
        grow_range(ctx_.refs, lo, std::max(lo, std::min(hi, mid)), acc, 0);
        grow_range(ctx_.refs, std::min(hi, std::max(lo, mid)), hi, acc, 1);
        chunk_[i] = result_of(acc, 0);
    }

    // Serial: merges the chunks' bounds and writes the children.
    void finish(NodeTask children[2]) {
        if (range_) {
            split_as_chosen(ctx_, t_, chosen_, children);
        } else {
            PartitionResult r;
            for (const PartitionResult& c : chunk_) r.merge(c);
            r.mid = t_.begin + (moves() ? split_.left_count : t_.size() / 2);
            if (moves() && from_bins()) {
                if (t_.carried)
                    r.acc = chosen_.part.acc;
                else
                    bounds_from_bins(*bin_pool_[0], m_, t_, split_, r);
            }
            emit(t_, r, children);
        }
    }

    // Whether the node, split by SAH, chooses its children's splits and
    // may rotate (kernel/rotate.h; run_node() takes the same decision).
    bool looks_ahead() const { return (range_ || moves()) && rotates(ctx_, t_) && rotation_room(*ctx_.options, t_); }
    // Parallel over [0, 2), after finish(): chooses child i's split.
    void look_ahead(uint32_t i, const NodeTask children[2]) {
        BinSet* b = take_bins();
        has_ahead_[i] = choose_ahead(ctx_, children[i], *b, ahead_skip_[i], ahead_[i]);
        give_back(b);
    }
    // Serial, after look_ahead(): carries the children's splits to them or
    // rotates.
    void rotate(NodeTask children[2], SkipCounts& skip) {
        skip.add(ahead_skip_[0]);
        skip.add(ahead_skip_[1]);
        rotate_chosen(ctx_, t_, children, ahead_, has_ahead_, skip);
    }

private:
    // The bins a chunk is binned into: one not in use by another chunk. The
    // start phase makes one per team thread; more are made only if more
    // chunks run at once. Each set accumulates several chunks; which chunks
    // share a set depends on timing, but the merge is exact and
    // order-free, so the result does not. (A set per chunk, 56 KiB each,
    // made the 4M stadium's root allocate 123 of them: in a traced build its
    // serial start phase took 23 ms, the first touch of fresh memory, and
    // the merge 1.9 ms. The sets are made by the thread that runs the start
    // phase: made on demand by whichever tbb worker first needed one, the 1M
    // sphere's 2-thread build took 1.06x to 1.16x as long in alternated
    // rounds, an allocator effect (glibc's per-thread arenas) that we did
    // not pin down.)
    BinSet* new_bins() {
        BinSet* b = bin_pool_.emplace_back(std::make_unique<BinSet>()).get();
        b->clear(m_.bins);
        return b;
    }
    BinSet* take_bins() {
        const std::lock_guard<std::mutex> lock(pool_mutex_);
        if (free_bins_.empty()) return new_bins();
        BinSet* b = free_bins_.back();
        free_bins_.pop_back();
        return b;
    }
    void give_back(BinSet* b) {
        const std::lock_guard<std::mutex> lock(pool_mutex_);
        free_bins_.push_back(b);
    }

    std::pair<uint32_t, uint32_t> chunk_range(uint32_t i) const {
        const uint32_t lo = t_.begin + i * chunk_size_;
        return {lo, static_cast<uint32_t>(std::min<uint64_t>(t_.end, uint64_t(lo) + chunk_size_))};
    }

    KernelContext ctx_;
    NodeTask t_;
    uint32_t team_ = 1;
    Plan plan_ = Plan::Leaf;
    bool splits_ = false;
    BinMapper m_;
    SizeCuts cuts_;
    bool sizes_ = false;  // the size split is offered (SizeCuts::applies)
    uint32_t sample_step_ = 0;  // the axis is chosen from a sample of this step (samples_axis()); 0: not
    Split split_;
    ChosenSplit chosen_;  // t_.carried: the split chosen for it before
    bool range_ = false;  // chosen_ is a range: nothing to partition
    ChosenSplit ahead_[2];  // the children's splits (look_ahead())
    bool has_ahead_[2] = {false, false};
    SkipCounts ahead_skip_[2];
    uint32_t chunks_ = 0;
    uint32_t chunk_size_ = kChunk;
    std::vector<std::unique_ptr<BinSet>> bin_pool_;  // see take_bins()
    std::vector<BinSet*> free_bins_;
    std::mutex pool_mutex_;
    std::vector<SizeBins> chunk_sizes_;
    std::vector<PartitionResult> chunk_;  // each chunk's share of the child bounds
    std::vector<uint64_t> sides_;  // bit i: record t_.begin + i goes left
    std::vector<SwapPiece> pieces_;
    HalfLeftovers halves_[2];
};

// Runs a big node with a scheduler's means: for_each(k, fn) calls fn(i) for
// every i in [0, k) in parallel and returns when all are done; serial(fn)
// runs fn once and makes its effects visible to every thread. In an OpenMP
// team every thread calls this (for_each = orphaned `omp for`, serial =
// `omp single`); elsewhere one thread calls it and serial(fn) is fn().
// Returns whether the node split (children written to `children`, which
// in an OpenMP team must be shared). With a trace log (given by one caller
// only), each phase becomes a span on that caller's track: the parallel
// ones (bin, mark and swap, or count for a middle split) last until the
// whole team is done; a small team's partition by halves is the span
// `partition`.
template <class ForEach, class Serial>
bool run_parallel_node(ParallelNode& pn, NodeTask children[2], SkipCounts& skip, ForEach&& for_each,
                       Serial&& serial, TraceLog* log = nullptr, uint32_t worker = 0) {
    const auto phase = [&](TraceSpan::Kind kind, auto&& body) {
        const TraceScope span(log, pn.task(), worker, kind);
        body();
    };
    phase(TraceSpan::Start, [&] { serial([&] { pn.start(skip); }); });
    if (!pn.splits()) return false;
    phase(TraceSpan::Bin, [&] {
        if (pn.sample_chunks()) {
            for_each(pn.sample_chunks(), [&](uint32_t i) { pn.sample_chunk(i); });
            serial([&] { pn.choose_axis(skip); });
        }
        for_each(pn.bin_chunks(), [&](uint32_t i) { pn.bin_chunk(i); });
    });
    phase(TraceSpan::Evaluate, [&] { serial([&] { pn.decide(skip); }); });
    if (!pn.splits()) return false;
    if (pn.moves() && pn.partitions_by_halves()) {
        phase(TraceSpan::Partition, [&] {
            for_each(2, [&](uint32_t i) { pn.partition_half(i); });
            serial([&] { pn.pair_leftovers(); });
        });
    } else if (pn.moves()) {
        phase(TraceSpan::Mark, [&] { for_each(pn.chunks(), [&](uint32_t i) { pn.mark_chunk(i); }); });
        phase(TraceSpan::Swap, [&] {
            serial([&] { pn.cut_swaps(); });
            for_each(pn.pieces(), [&](uint32_t i) { pn.swap_piece(i); });
        });
    } else
        phase(TraceSpan::Count, [&] { for_each(pn.chunks(), [&](uint32_t i) { pn.middle_chunk(i); }); });
    phase(TraceSpan::Finish, [&] {
        serial([&] { pn.finish(children); });
        if (pn.looks_ahead()) {  // the children's splits, one child per thread
            for_each(2, [&](uint32_t i) { pn.look_ahead(i, children); });
            serial([&] { pn.rotate(children, skip); });
        }
    });
    return true;
}

}  // namespace canopy
