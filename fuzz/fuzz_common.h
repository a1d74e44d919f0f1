// canopy fuzzing: what the reader targets share.
//
// The readers take file paths, so every input is written to one temporary
// file per process (with the format's extension), rewritten in place on
// every iteration and removed at exit. A canopy::Error is a clean
// rejection; any other exception, a crash, a sanitizer report or a hang is
// a bug.
#pragma once

#include "core/error.h"
#include "core/mesh.h"
#include "core/scene.h"
#include "core/validate.h"
#include "schedulers/sequential.h"

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

namespace canopy::fuzz {

[[noreturn]] inline void fail(const char* what, const std::string& detail) {
    std::fprintf(stderr, "canopy fuzz: %s: %s\n", what, detail.c_str());
    std::fflush(stderr);
    __builtin_trap();
}

// A temporary file /tmp/canopy-fuzz-XXXXXX<extension>, unique to the process.
class InputFile {
public:
    explicit InputFile(const char* extension) {
        path_ = std::string("/tmp/canopy-fuzz-XXXXXX") + extension;
        fd_ = mkstemps(path_.data(), static_cast<int>(std::string(extension).size()));
        if (fd_ < 0) fail("mkstemps", path_);
    }
    ~InputFile() {
        close(fd_);
        unlink(path_.c_str());
    }
    InputFile(const InputFile&) = delete;
    InputFile& operator=(const InputFile&) = delete;

    // Replaces the file's content by `data`.
    const std::string& write(const uint8_t* data, size_t size) {
        if (ftruncate(fd_, 0) != 0) fail("ftruncate", path_);
        size_t done = 0;
        while (done < size) {
            const ssize_t n = pwrite(fd_, data + done, size - done, static_cast<off_t>(done));
            if (n <= 0) fail("pwrite", path_);
            done += static_cast<size_t>(n);
        }
        return path_;
    }
    const std::string& path() const { return path_; }

private:
    std::string path_;
    int fd_ = -1;
};

// What every successful load must give: a mesh the library accepts as it
// is (finite vertices, indices in range), which builds a valid tree.
inline void check_loaded(const TriangleMesh& mesh, const char* format) {
    try {
        check_mesh(mesh, format);
    } catch (const Error& e) {
        fail("the reader returned a mesh that check_mesh rejects", e.what());
    }
    Bvh bvh;
    try {
        bvh = build<Sequential>(mesh.view());
    } catch (const std::exception& e) {
        fail("building over a loaded mesh threw", e.what());
    }
    const ValidationReport report = validate(bvh, mesh.view());
    if (!report.ok()) fail("the tree failed validation", report.summary());
}

// load_scene on the file; a canopy::Error counts as a clean rejection.
// Returns whether the load succeeded, the mesh in `out`.
inline bool load_or_reject(const std::string& path, TriangleMesh& out) {
    try {
        out = load_scene(path).mesh;
        return true;
    } catch (const Error&) {
        return false;
    } catch (const std::exception& e) {
        fail("load_scene threw something other than canopy::Error", e.what());
    }
}

}  // namespace canopy::fuzz
