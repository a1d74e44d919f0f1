// What several test programs share: checking an InputError's message, the
// scheduler tuning for small scenes, and a fixture with a fresh temporary
// directory to write input files into.
#pragma once

#include "core/error.h"
#include "core/options.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <system_error>
#include <vector>

namespace canopy::test_util {

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
// from 512, tasks from 64.
inline BuildOptions small_tuning(uint32_t bins, uint32_t threads) {
    BuildOptions o;
    o.bins = bins;
    o.threads = threads;
    o.tuning.prims_per_thread = 64;
    o.tuning.task_cutoff = 64;
    o.tuning.parallel_node_min = 512;
    o.tuning.chunk_nodes = 24;  // blocks outgrow their chunks and move
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
