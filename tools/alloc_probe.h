// canopy tool: a heap high-water mark for `canopy build --json`
// ("peak_bytes"). The tool replaces the global operator new / delete
// (alloc_probe.cpp) to count the bytes the C++ heap holds; the library
// allocates through them, and reports the page mappings it makes itself
// (a big node array, core/memory.h) to an observer the probe sets. Memory that threading runtimes take with
// malloc directly (thread stacks, pool structures) is not counted.
#pragma once

#include <cstddef>

namespace canopy::alloc_probe {

// Starts a measurement: the high-water mark is reset to what is held now.
void start();
// The largest number of bytes held since start(), beyond what was held then.
size_t peak_since_start();

}  // namespace canopy::alloc_probe
