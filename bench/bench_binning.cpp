// canopy bench: the binning step alone (step 1 of the node kernel, bin() in
// core/kernel/bin.h), in nanoseconds per record, so that a change to the bin
// updates can be judged without a whole build around it.
//
// Each case prepares the records of a generated scene once, then bins
// ranges of `range` consecutive records (all of them, one after another)
// into cleared bins with the scene root's centroid bounds, keys written as
// a node of that size writes them. Cases:
//   scene      sphere (records in the generator's ring order: neighbours
//              fall in the same bins), random (no order), stadium;
//   order      0: the scene's own order, 1: shuffled (the same records);
//   bins       per axis;
//   axes       3, 2 or 1 (the others marked invalid, as for a node whose
//              centroids are flat on them: a planar scene, a wall);
//   range      records per bin() call: 2^20 (the whole scene: a root), 2^14
//              (a node whose records stay in L2), 2^10, 2^8.
// Counter `ns_per_record`: time per record binned (lower is better).
//
// Before timing, every case checks that the ordered and the shuffled
// records give the same bins (the merge of the two bin sets is exact and
// order-free), and exits non-zero if not.
//
//   ./build/bench/bench_binning [--benchmark_filter=REGEX]
#include "core/kernel.h"
#include "core/primitives.h"
#include "core/scene.h"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace {

using namespace canopy;

constexpr uint32_t kRecords = 1u << 20;
const char* const kScenes[] = {"sphere", "random", "stadium"};

struct Records {
    std::vector<PrimRef> ordered, shuffled;
    Box cbounds;
};

const Records& records(int scene) {
    static std::map<int, std::unique_ptr<Records>> cache;
    auto& slot = cache[scene];
    if (!slot) {
        slot = std::make_unique<Records>();
        const TriangleMesh mesh = generate(kScenes[scene], kRecords);
        const size_t n = std::min<size_t>(mesh.triangle_count(), kRecords);
        slot->ordered.resize(n);
        const PrepareSummary s = prepare_triangles(mesh.view(), 0, n, slot->ordered.data());
        if (s.first_bad != PrepareSummary::kNone) {
            std::fprintf(stderr, "bench_binning: scene %s has a bad triangle\n", kScenes[scene]);
            std::exit(1);
        }
        slot->cbounds = s.cbounds;
        slot->shuffled = slot->ordered;
        std::mt19937 rng(1);
        std::shuffle(slot->shuffled.begin(), slot->shuffled.end(), rng);
    }
    return *slot;
}

BinMapper mapper(const Records& r, uint32_t bins, int axes) {
    BinMapper m = BinMapper::make(r.cbounds, bins);
    for (int a = axes; a < 3; ++a) {  // as for a node flat on the last 3 - axes axes
        m.valid[a] = false;
        m.scale[a] = 0.0f;
    }
    m.scale4 = simd::vec(m.scale);
    return m;
}

// The bins of all records in one bin() call, as comparable numbers.
std::vector<float> whole_bins(const std::vector<PrimRef>& refs, const BinMapper& m) {
    BinSet set(m.bins);
    set.clear(m.bins);
    bin(refs.data(), 0, uint32_t(refs.size()), m, set);
    std::vector<float> out;
    for (int a = 0; a < 3; ++a) {
        if (!m.valid[a]) continue;
        for (uint32_t b = 0; b < m.bins; ++b) {
            const Box box = set.box(a, b);
            out.insert(out.end(), {box.lo.x, box.lo.y, box.lo.z, box.hi.x, box.hi.y, box.hi.z, float(set.count(a, b))});
        }
    }
    return out;
}

void check_order_free(int scene, uint32_t bins, int axes) {
    const Records& r = records(scene);
    const BinMapper m = mapper(r, bins, axes);
    if (whole_bins(r.ordered, m) != whole_bins(r.shuffled, m)) {
        std::fprintf(stderr, "bench_binning: %s, %u bins, %d axes: shuffled records gave other bins\n",
                     kScenes[scene], bins, axes);
        std::exit(1);
    }
}

void BM_Bin(benchmark::State& state) {
    const int scene = int(state.range(0)), order = int(state.range(1)), axes = int(state.range(4));
    const uint32_t bins = uint32_t(state.range(2));
    const Records& r = records(scene);
    const std::vector<PrimRef>& refs = order ? r.shuffled : r.ordered;
    const BinMapper m = mapper(r, bins, axes);
    const uint32_t range = std::min<uint32_t>(uint32_t(state.range(3)), uint32_t(refs.size()));
    const uint32_t n = uint32_t(refs.size()) / range * range;
    BinSet set(bins);
    std::vector<uint32_t> keys(refs.size());
    for (auto _ : state) {
        for (uint32_t b0 = 0; b0 < n; b0 += range) {
            set.clear(m.bins);
            bin(refs.data(), b0, b0 + range, m, set, range > kBinBlock ? keys.data() : nullptr);
            benchmark::DoNotOptimize(set.base);
        }
        benchmark::ClobberMemory();
    }
    state.counters["ns_per_record"] = benchmark::Counter(
        double(n) * double(state.iterations()), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
    state.SetLabel(std::string(kScenes[scene]) + (order ? " shuffled" : " ordered"));
}

void cases(benchmark::internal::Benchmark* b) {
    b->ArgNames({"scene", "order", "bins", "range", "axes"});
    for (int scene = 0; scene < 3; ++scene)
        for (int order = 0; order < 2; ++order)
            for (int bins : {8, 32, 128})
                for (int range : {1 << 20, 1 << 14, 1 << 10, 1 << 8})
                    for (int axes : {3, 2, 1}) b->Args({scene, order, bins, range, axes});
}

}  // namespace

BENCHMARK(BM_Bin)->Apply(cases)->Unit(benchmark::kMillisecond);

int main(int argc, char** argv) {
    for (int scene = 0; scene < 3; ++scene)
        for (int bins : {8, 32, 128})
            for (int axes : {3, 2, 1}) check_order_free(scene, uint32_t(bins), axes);
    benchmark::Initialize(&argc, argv);
    if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    return 0;
}
