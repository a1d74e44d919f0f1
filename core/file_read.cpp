#include "file_read.h"

#include "error.h"

#include <cerrno>
#include <filesystem>
#include <iterator>
#include <system_error>

namespace canopy {

std::ifstream open_for_reading(const std::string& path) {
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) throw InputError(path + ": cannot open: is a directory");
    errno = 0;
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        const int e = errno;
        throw InputError(path + ": cannot open" +
                         (e != 0 ? ": " + std::generic_category().message(e) : std::string()));
    }
    return in;
}

std::string read_whole_file(const std::string& path) {
    std::ifstream in = open_for_reading(path);
    std::string text;
    in.seekg(0, std::ios::end);
    const std::streamoff size = in.tellg();
    in.seekg(0, std::ios::beg);
    if (size > 0 && in) {
        text.resize(static_cast<size_t>(size));
        in.read(text.data(), size);
        text.resize(static_cast<size_t>(in.gcount()));
    } else {
        // Not seekable (a pipe, say): read it as a stream.
        in.clear();
        text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    if (in.bad()) throw InputError(path + ": read error");
    return text;
}

}  // namespace canopy
