// canopy: one big node task run by many threads.
//
// Near the root there are fewer nodes than threads, so a big node is binned
// and partitioned by the whole team. The node is cut into phases; the
// scheduler runs the `parallel` phases with its own parallel loop and the
// `serial` ones on one thread, with a barrier between phases (see
// run_parallel_node). The result is bit-identical to run_node():
//  - bins merge with min/max and integer sums only (exact, order-free), so
//    how the range is cut into chunks does not matter;
//  - the partition is the stable one, which is unique: blocks count their
//    left-going records, a prefix sum gives every block its output offsets,
//    and each block copies its records to the other buffer.
#pragma once

#include "kernel.h"
#include "trace.h"

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

namespace canopy {

class ParallelNode {
public:
    static constexpr uint32_t kBinChunk = 32768;  // records per binning chunk

    ParallelNode(const KernelContext& ctx, const NodeTask& t) : ctx_(ctx), t_(t) {}
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
        if (plan_ == Plan::Sah) {
            m_ = BinMapper::make(t_.cbounds, bins_for(t_.size(), ctx_.options->bins));
            if (!m_.any_valid()) {
                ++skip.coincident_nodes;
                if (t_.size() <= ctx_.options->max_leaf) return false;
                plan_ = Plan::Middle;
            } else {
                skip.axes_not_binned += 3 - (m_.valid[0] + m_.valid[1] + m_.valid[2]);
                cuts_ = SizeCuts::of(t_.bounds);
                sizes_ = cuts_.applies(t_);
            }
        }
        ++skip.parallel_nodes;
        const uint32_t n = t_.size();
        chunks_ = plan_ == Plan::Sah ? (n + kBinChunk - 1) / kBinChunk : 0;
        if (chunks_ > chunk_bins_.size()) chunk_bins_.resize(chunks_);
        chunk_sizes_.assign(sizes_ ? chunks_ : 0, SizeBins{});
        for (uint32_t i = 0; i < chunks_; ++i)
            if (!chunk_bins_[i]) chunk_bins_[i] = std::make_unique<BinSet>();
        blocks_ = (n + kPartitionBlock - 1) / kPartitionBlock;
        block_.assign(blocks_, PartitionResult{});
        return true;
    }

    bool decide_impl(SkipCounts& skip) {
        if (plan_ != Plan::Sah) return true;
        for (uint32_t i = 1; i < chunks_; ++i) chunk_bins_[0]->merge(*chunk_bins_[i], m_.bins);
        split_ = evaluate(*chunk_bins_[0], m_, t_.bounds, *ctx_.options);
        if (sizes_) {
            for (uint32_t i = 1; i < chunks_; ++i) chunk_sizes_[0].merge(chunk_sizes_[i]);
            consider_size_split(chunk_sizes_[0], cuts_, t_.bounds, *ctx_.options, split_);
            skip.size_splits += split_.by_size();
        }
        if (sah_says_leaf(split_, t_.size(), *ctx_.options)) return false;
        if (!split_.found()) plan_ = Plan::Middle;
        return true;
    }

public:
    // Parallel over [0, bin_chunks()): bins one chunk.
    uint32_t bin_chunks() const { return chunks_; }
    void bin_chunk(uint32_t i) {
        BinSet& b = *chunk_bins_[i];
        b.clear(m_.bins);
        const uint32_t lo = t_.begin + i * kBinChunk, hi = std::min(t_.end, lo + kBinChunk);
        bin(ctx_.src(t_), lo, hi, m_, b);
        if (sizes_) bin_sizes(ctx_.src(t_), lo, hi, cuts_, chunk_sizes_[i]);
    }

    // Parallel over [0, blocks()): counts one block (or, for a middle split,
    // accumulates its share of each half's bounds).
    uint32_t blocks() const { return blocks_; }
    void count_block(uint32_t i) {
        const auto [lo, hi] = block_range(i);
        if (plan_ == Plan::Sah) {
            block_[i] = partition_count(ctx_.src(t_), lo, hi, m_, split_);
            return;
        }
        const uint32_t mid = t_.begin + t_.size() / 2;
        ChildBounds4 acc;
        grow_range(ctx_.src(t_), lo, std::max(lo, std::min(hi, mid)), acc, 0);
        grow_range(ctx_.src(t_), std::min(hi, std::max(lo, mid)), hi, acc, 1);
        block_[i] = PartitionResult{};
        acc.into(block_[i]);
    }

    // Serial: prefix sums over the block counts, merged child bounds.
    void prefix() {
        result_ = PartitionResult{};
        if (plan_ == Plan::Middle) {
            for (const PartitionResult& b : block_) result_.merge(b);
            result_.mid = t_.begin + t_.size() / 2;
            return;
        }
        left_at_.resize(blocks_);
        right_at_.resize(blocks_);
        uint32_t left = 0;
        for (uint32_t i = 0; i < blocks_; ++i) {
            left_at_[i] = left;
            left += block_[i].mid;
            result_.merge(block_[i]);
        }
        uint32_t right = left;
        for (uint32_t i = 0; i < blocks_; ++i) {
            right_at_[i] = right;
            right += (block_range(i).second - block_range(i).first) - block_[i].mid;
        }
        result_.mid = t_.begin + left;
    }

    // Parallel over [0, blocks()), SAH splits only: copies a block's records
    // to their places in the other buffer.
    bool moves() const { return plan_ == Plan::Sah; }
    void scatter_block(uint32_t i) {
        const auto [lo, hi] = block_range(i);
        PrimRef* out = ctx_.dst(t_) + t_.begin;
        partition_scatter(ctx_.src(t_), lo, hi, m_, split_, out + left_at_[i], out + right_at_[i]);
    }

    // Serial: the children.
    void finish(NodeTask children[2]) const { emit(t_, result_, moves(), children); }

private:
    std::pair<uint32_t, uint32_t> block_range(uint32_t i) const {
        const uint32_t lo = t_.begin + i * kPartitionBlock;
        return {lo, std::min(t_.end, lo + kPartitionBlock)};
    }

    KernelContext ctx_;
    NodeTask t_;
    Plan plan_ = Plan::Leaf;
    bool splits_ = false;
    BinMapper m_;
    SizeCuts cuts_;
    bool sizes_ = false;  // the size split is offered (SizeCuts::applies)
    Split split_;
    uint32_t chunks_ = 0, blocks_ = 0;
    std::vector<std::unique_ptr<BinSet>> chunk_bins_;
    std::vector<SizeBins> chunk_sizes_;
    std::vector<PartitionResult> block_;
    std::vector<uint32_t> left_at_, right_at_;
    PartitionResult result_;
};

// Runs a big node with a scheduler's means: for_each(k, fn) calls fn(i) for
// every i in [0, k) in parallel and returns when all are done; serial(fn)
// runs fn once and makes its effects visible to every thread. In an OpenMP
// team every thread calls this (for_each = orphaned `omp for`, serial =
// `omp single`); elsewhere one thread calls it and serial(fn) is fn().
// Returns whether the node split (children written to `children`, which
// in an OpenMP team must be shared). With a trace log (given by one caller
// only), each phase becomes a span on that caller's track: the parallel
// ones (bin, count, scatter) last until the whole team is done.
template <class ForEach, class Serial>
bool run_parallel_node(ParallelNode& pn, NodeTask children[2], SkipCounts& skip, ForEach&& for_each,
                       Serial&& serial, TraceLog* log = nullptr, uint32_t worker = 0) {
    const auto phase = [&](TraceSpan::Kind kind, auto&& body) {
        const TraceScope span(log, pn.task(), worker, kind);
        body();
    };
    phase(TraceSpan::Start, [&] { serial([&] { pn.start(skip); }); });
    if (!pn.splits()) return false;
    phase(TraceSpan::Bin, [&] { for_each(pn.bin_chunks(), [&](uint32_t i) { pn.bin_chunk(i); }); });
    phase(TraceSpan::Evaluate, [&] { serial([&] { pn.decide(skip); }); });
    if (!pn.splits()) return false;
    phase(TraceSpan::Count, [&] { for_each(pn.blocks(), [&](uint32_t i) { pn.count_block(i); }); });
    phase(TraceSpan::Prefix, [&] { serial([&] { pn.prefix(); }); });
    if (pn.moves())
        phase(TraceSpan::Scatter, [&] { for_each(pn.blocks(), [&](uint32_t i) { pn.scatter_block(i); }); });
    phase(TraceSpan::Finish, [&] { serial([&] { pn.finish(children); }); });
    return true;
}

}  // namespace canopy
