// What several test programs share: small generated meshes, checking an
// InputError's message, the scheduler tuning for small scenes, and a fixture
// with a fresh temporary directory to write input files into.
#pragma once

#include "core/error.h"
#include "core/geometry.h"
#include "core/mesh.h"
#include "core/options.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <system_error>
#include <vector>

namespace canopy::test_util {

// A float in [lo, hi) from 24 random bits (the same value on every platform).
inline float uniform(std::mt19937& rng, float lo, float hi) {
    const float u = float(rng() >> 8) * 0x1p-24f;  // [0, 1) in steps of 2^-24
    return lo + (hi - lo) * u;
}

// n random triangles in [0, 100)^3 of size up to `size` (own vertices).
inline TriangleMesh random_mesh(uint32_t n, uint32_t seed, float size = 2.0f) {
    std::mt19937 rng(seed);
    TriangleMesh m;
    m.vertices.reserve(3 * size_t(n));
    m.indices.reserve(3 * size_t(n));
    for (uint32_t t = 0; t < n; ++t) {
        const Vec3 c(uniform(rng, 0, 100), uniform(rng, 0, 100), uniform(rng, 0, 100));
        for (int k = 0; k < 3; ++k) {
            m.indices.push_back(uint32_t(m.vertices.size()));
            m.vertices.push_back(c + size * Vec3(uniform(rng, -0.5f, 0.5f), uniform(rng, -0.5f, 0.5f),
                                                 uniform(rng, -0.5f, 0.5f)));
        }
    }
    return m;
}

// A k x k grid of unit quads (two triangles each) in the plane z = 0.
inline TriangleMesh grid_mesh(uint32_t k) {
    TriangleMesh m;
    for (uint32_t y = 0; y <= k; ++y)
        for (uint32_t x = 0; x <= k; ++x) m.vertices.push_back(Vec3(float(x), float(y), 0.0f));
    auto v = [&](uint32_t x, uint32_t y) { return y * (k + 1) + x; };
    for (uint32_t y = 0; y < k; ++y)
        for (uint32_t x = 0; x < k; ++x) {
            m.indices.insert(m.indices.end(), {v(x, y), v(x + 1, y), v(x + 1, y + 1)});
            m.indices.insert(m.indices.end(), {v(x, y), v(x + 1, y + 1), v(x, y + 1)});
        }
    return m;
}

// Triangles in the planes x = 2^-k, k = 0..kmax: with bins over [2^-kmax, 1]
// nearly everything falls in bin 0, so every SAH split peels off only the
// few largest: without a depth cap the tree is about as deep as it has
// triangles.
inline TriangleMesh geometric_mesh(int kmax) {
    TriangleMesh m;
    for (int k = 0; k <= kmax; ++k) {
        const float x = std::ldexp(1.0f, -k);
        const uint32_t base = uint32_t(m.vertices.size());
        m.vertices.insert(m.vertices.end(), {Vec3(x, 0, 0), Vec3(x, 1, 0), Vec3(x, 0, 1)});
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
    }
    return m;
}

// n copies of one triangle (three shared vertices).
inline TriangleMesh coincident_mesh(uint32_t n) {
    TriangleMesh m;
    m.vertices = {Vec3(1, 2, 3), Vec3(4, 2, 3), Vec3(1, 6, 3)};
    m.indices.reserve(3 * size_t(n));
    for (uint32_t t = 0; t < n; ++t) m.indices.insert(m.indices.end(), {0u, 1u, 2u});
    return m;
}

// Runs `fn`, expects an InputError whose message contains every needle.
inline void expect_input_error(const std::function<void()>& fn, const std::vector<std::string>& needles) {
    try {
        fn();
        ADD_FAILURE() << "no exception thrown (expected InputError containing '"
                      << (needles.empty() ? std::string() : needles[0]) << "')";
    } catch (const InputError& e) {
        const std::string what = e.what();
        for (const std::string& needle : needles)
            EXPECT_NE(what.find(needle), std::string::npos) << "message '" << what << "' lacks '" << needle << "'";
    } catch (const std::exception& e) {
        ADD_FAILURE() << "wrong exception type: " << e.what();
    }
}

// Tuning turned down so that small scenes reach every code path of the
// parallel schedulers: threads start from 64 primitives, team-parallel nodes
// from 512, tasks from 64; and rotations are costed at nodes of 256
// primitives or more (kRotateMinPrims), in tasks, inline subtrees and team
// nodes alike (this one changes the tree, for every scheduler the same).
inline BuildOptions small_tuning(uint32_t bins, uint32_t threads) {
    BuildOptions o;
    o.bins = bins;
    o.threads = threads;
    o.rotate_min = canopy::kRotateMinPrims;
    o.tuning.prims_per_thread = 64;
    o.tuning.task_cutoff = 64;
    o.tuning.parallel_node_min = 512;
    o.tuning.chunk_nodes = 24;  // blocks outgrow their chunks and move
    o.tuning.place_parallel_min = 0;  // blocks move into place split over the workers
    return o;
}

// Each test gets its own new directory (removed afterwards); write() puts a
// file there and returns its path.
class TempDirTest : public ::testing::Test {
protected:
    void SetUp() override {
        static std::atomic<unsigned> counter{0};
        std::random_device rd;
        for (int attempt = 0; attempt < 100; ++attempt) {
            const auto now = std::chrono::steady_clock::now().time_since_epoch().count();
            dir_ = std::filesystem::temp_directory_path() /
                   ("canopy-test-" + std::to_string(rd()) + "-" + std::to_string(now) + "-" +
                    std::to_string(counter++));
            if (std::filesystem::create_directory(dir_)) return;
        }
        FAIL() << "cannot create a temporary directory";
    }
    void TearDown() override {
        std::error_code ec;
        if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
    }
    std::string write(const std::string& name, const std::string& content) {
        const std::filesystem::path p = dir_ / name;
        std::ofstream out(p, std::ios::binary);
        out << content;
        out.close();
        EXPECT_TRUE(out) << "cannot write " << p;
        return p.string();
    }
    std::filesystem::path dir_;
};

}  // namespace canopy::test_util
