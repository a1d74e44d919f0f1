// canopy: opening and reading input files, with the errors every reader
// reports the same way ("PATH: cannot open: REASON").
#pragma once

#include <fstream>
#include <string>

namespace canopy {

// Opens `path` in binary mode; throws InputError naming the path and the
// reason (a directory, a missing file, no permission).
std::ifstream open_for_reading(const std::string& path);

// The whole file (seekable or not); InputError on open or read failure.
std::string read_whole_file(const std::string& path);

}  // namespace canopy
