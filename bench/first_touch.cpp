// first_touch: how long a first touch of fresh memory takes on this machine,
// depending on how long the memory was idle before, and whether touching and
// freeing some memory just before (what `canopy bench --prefault` does)
// changes it. A build writes about 100 bytes per triangle into fresh memory,
// so on a machine where this is slow, build times depend on it.
//
//   ./build/bench/first_touch [MIB]     (default 256)
//
// Each line maps MIB of anonymous memory (advised for huge pages, as canopy's
// big arrays are), writes one byte per 4 KiB page, and unmaps it. On this
// project's virtual machine, memory that had been free for about 2 s or more
// took 250 to 480 ms per 256 MiB and memory freed a moment before about 30:
// the guest reports idle free memory to its host (virtio-balloon free page
// reporting), which has to provide it again on the next touch.
#include "core/build_state.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace {

double touch_ms(size_t bytes) {
    const auto t0 = std::chrono::steady_clock::now();
    canopy::RawArray<char> p;  // as a build's arrays: fresh, advised for huge pages
    p.allocate(bytes);
    volatile char* v = p.get();
    for (size_t i = 0; i < bytes; i += 4096) v[i] = 1;
    const auto t1 = std::chrono::steady_clock::now();
    return std::chrono::duration<double, std::milli>(t1 - t0).count();
}

void idle(int ms) { std::this_thread::sleep_for(std::chrono::milliseconds(ms)); }

}  // namespace

int main(int argc, char** argv) {
    const long mib = argc > 1 ? std::atol(argv[1]) : 256;
    if (mib <= 0 || mib > (1 << 20)) {
        std::fprintf(stderr, "usage: first_touch [MIB]   (1 to 1048576, default 256)\n");
        return 2;
    }
    const size_t bytes = size_t(mib) << 20;
    std::printf("first touch of %ld MiB (one byte per 4 KiB page), in ms\n", mib);
    for (const int gap : {0, 100, 100, 3000, 5000}) {
        idle(gap);
        std::printf("  after %5d ms idle:                         %8.1f\n", gap, touch_ms(bytes));
    }
    for (int r = 0; r < 3; ++r) {
        idle(4000);
        const double warm = touch_ms(2 * bytes);
        idle(50);
        std::printf("  after 4000 ms idle, twice as much touched first: %8.1f  (that touch: %.1f)\n",
                    touch_ms(bytes), warm);
    }
    return 0;
}
