// bench/ab/run.sh's program: alternates the sequential builds of two source
// trees (sides a and b, see side.cpp) build by build in one process, so that
// the machine's slow spells fall on both alike, and prints per scene the
// median over rounds of the per-round median of the b/a ratios of
// neighbouring builds, with the range, and the fastest build of each side.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

extern "C" bool ab_load_a(const char*, float**, size_t*, uint32_t**, size_t*);
extern "C" double ab_run_a(const float*, size_t, const uint32_t*, size_t, bool, uint64_t*);
extern "C" double ab_run_b(const float*, size_t, const uint32_t*, size_t, bool, uint64_t*);

namespace {
double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 5) {
        std::fprintf(stderr, "usage: %s ROUNDS BUILDS warm|cold SCENE...\n", argv[0]);
        return 2;
    }
    const int rounds = std::atoi(argv[1]), builds = std::atoi(argv[2]);
    const bool warm = std::strcmp(argv[3], "warm") == 0;
    if (rounds < 1 || builds < 1 || (!warm && std::strcmp(argv[3], "cold") != 0)) {
        std::fprintf(stderr, "ROUNDS and BUILDS must be positive, the mode warm or cold\n");
        return 2;
    }
    int status = 0;
    for (int s = 4; s < argc; ++s) {
        float* v = nullptr;
        uint32_t* idx = nullptr;
        size_t nv = 0, ni = 0;
        if (!ab_load_a(argv[s], &v, &nv, &idx, &ni)) return 1;
        uint64_t ha = 0, hb = 0;
        ab_run_a(v, nv, idx, ni, warm, &ha);  // untimed first builds
        ab_run_b(v, nv, idx, ni, warm, &hb);
        std::vector<double> round_ratios, a_all, b_all;
        for (int r = 0; r < rounds; ++r) {
            std::vector<double> ratios;
            for (int k = 0; k < builds; ++k) {
                double a, b;
                if ((r + k) % 2) {  // which side goes first alternates
                    a = ab_run_a(v, nv, idx, ni, warm, &ha);
                    b = ab_run_b(v, nv, idx, ni, warm, &hb);
                } else {
                    b = ab_run_b(v, nv, idx, ni, warm, &hb);
                    a = ab_run_a(v, nv, idx, ni, warm, &ha);
                }
                ratios.push_back(b / a);
                a_all.push_back(a);
                b_all.push_back(b);
            }
            round_ratios.push_back(median(ratios));
        }
        std::printf("%s (%zu triangles, %s): b/a %.4f [%.4f .. %.4f] over %d rounds of %d builds; "
                    "medians a %.3f ms, b %.3f ms; fastest a %.3f, b %.3f (b/a %.4f); trees %s\n",
                    argv[s], ni / 3, warm ? "warm" : "cold", median(round_ratios),
                    *std::min_element(round_ratios.begin(), round_ratios.end()),
                    *std::max_element(round_ratios.begin(), round_ratios.end()), rounds, builds, median(a_all),
                    median(b_all), *std::min_element(a_all.begin(), a_all.end()),
                    *std::min_element(b_all.begin(), b_all.end()),
                    *std::min_element(b_all.begin(), b_all.end()) / *std::min_element(a_all.begin(), a_all.end()),
                    ha == hb ? "identical" : "DIFFER");
        status |= ha != hb;
        std::free(v);
        std::free(idx);
    }
    return status;
}
