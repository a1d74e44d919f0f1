// Bad input: the library throws canopy::InputError (bad data) or
// canopy::OptionError (bad options) naming what and where, on every
// scheduler and in the exact sweep builder; the tool exits 1 for bad input
// with the first stderr line naming the file (and line), and 2 for usage
// errors. The tool is the built binary, passed by Meson in CANOPY_BIN.
#include "core/scene.h"
#include "core/sweep_sah.h"
#include "core/validate.h"
#include "schedulers/registry.h"

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace {

using namespace canopy;
namespace fs = std::filesystem;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

// Thresholds turned down so that the parallel schedulers prepare the
// primitives in parallel chunks even on these small meshes.
BuildOptions parallel_options() {
    BuildOptions o;
    o.threads = 2;
    o.tuning.prims_per_thread = 64;
    o.tuning.task_cutoff = 64;
    o.tuning.parallel_node_min = 512;
    return o;
}

// Every builder: each scheduler, and the exact sweep builder.
struct NamedBuilder {
    std::string name;
    std::function<Bvh(const TriangleView&, const BuildOptions&)> build;
};
std::vector<NamedBuilder> builders() {
    std::vector<NamedBuilder> out;
    for (const SchedulerEntry& s : schedulers())
        out.push_back({s.name, [&s](const TriangleView& m, const BuildOptions& o) { return s.build_triangles(m, o); }});
    out.push_back({"sweep_sah", [](const TriangleView& m, const BuildOptions& o) { return build_sweep_sah(m, o); }});
    return out;
}

// Runs `f`, expecting an exception of type E whose message contains every
// one of `needles`.
template <class E, class F>
void expect_error(F&& f, const std::vector<std::string>& needles, const std::string& what) {
    try {
        f();
        ADD_FAILURE() << what << ": no exception";
    } catch (const E& e) {
        const std::string msg = e.what();
        for (const std::string& n : needles)
            EXPECT_NE(msg.find(n), std::string::npos) << what << ": message '" << msg << "' does not mention '" << n << "'";
    } catch (const std::exception& e) {
        ADD_FAILURE() << what << ": wrong exception type: " << e.what();
    }
}

// A mesh whose triangle t has its own vertices 3t, 3t+1, 3t+2.
TriangleMesh own_vertices(size_t n) { return generate("random", n, 5); }

// ---------------------------------------------------------------------------
// The library.

TEST(BadInputLibrary, NonFiniteCoordinateNamesTheTriangle) {
    for (const float bad : {kNaN, kInf, -kInf}) {
        for (const int axis : {0, 1, 2}) {
            for (const int corner : {0, 1, 2}) {
                TriangleMesh m = own_vertices(3000);
                m.vertices[3 * 1234 + corner][axis] = bad;
                for (const NamedBuilder& b : builders()) {
                    const std::string what = b.name + " value " + std::to_string(bad) + " axis " +
                                             std::to_string(axis) + " corner " + std::to_string(corner);
                    expect_error<InputError>([&] { b.build(m.view(), parallel_options()); },
                                             {"triangle 1234", "non-finite"}, what);
                }
            }
        }
    }
}

TEST(BadInputLibrary, TheLowestBadTriangleIsNamed) {
    TriangleMesh m = own_vertices(5000);
    m.vertices[3 * 4321].x = kNaN;
    m.vertices[3 * 2500 + 1].y = kInf;
    m.indices[3 * 777 + 2] = 1u << 30;
    m.vertices[3 * 3000 + 2].z = -kInf;
    for (const NamedBuilder& b : builders())
        expect_error<InputError>([&] { b.build(m.view(), parallel_options()); }, {"triangle 777", "out of range"},
                                 b.name);
}

TEST(BadInputLibrary, IndexOutOfRange) {
    for (const uint32_t bad : {3u * 2000u, 3u * 2000u + 1u, std::numeric_limits<uint32_t>::max()}) {
        TriangleMesh m = own_vertices(2000);
        m.indices[3 * 1999 + 1] = bad;  // the last triangle
        for (const NamedBuilder& b : builders())
            expect_error<InputError>([&] { b.build(m.view(), parallel_options()); },
                                     {"triangle 1999", std::to_string(bad), "out of range"}, b.name);
    }
}

TEST(BadInputLibrary, IndexCountNotAMultipleOfThree) {
    TriangleMesh m = own_vertices(100);
    m.indices.pop_back();
    for (const NamedBuilder& b : builders())
        expect_error<InputError>([&] { b.build(m.view(), parallel_options()); }, {"multiple of 3"}, b.name);
}

TEST(BadInputLibrary, UnreferencedNonFiniteVerticesAreIgnored) {
    TriangleMesh m = own_vertices(1000);
    m.vertices.push_back(Vec3(kNaN, kInf, -kInf));  // no triangle uses it
    for (const NamedBuilder& b : builders()) {
        Bvh bvh;
        ASSERT_NO_THROW(bvh = b.build(m.view(), parallel_options())) << b.name;
        EXPECT_TRUE(validate(bvh, m.view(), parallel_options()).ok()) << b.name;
    }
}

TEST(BadInputLibrary, EmptyInputGivesAnEmptyTree) {
    const TriangleMesh empty;
    for (const NamedBuilder& b : builders()) {
        Bvh bvh;
        ASSERT_NO_THROW(bvh = b.build(empty.view(), parallel_options())) << b.name;
        EXPECT_TRUE(bvh.empty()) << b.name;
        EXPECT_TRUE(bvh.permutation.empty()) << b.name;
        EXPECT_TRUE(validate(bvh, empty.view()).ok()) << b.name;
    }
}

TEST(BadInputLibrary, BadBoxes) {
    std::vector<Box> boxes(500, Box{Vec3(0.0f), Vec3(1.0f)});
    for (size_t i = 0; i < boxes.size(); ++i) boxes[i] = Box{Vec3(float(i)), Vec3(float(i) + 1.0f)};
    auto with = [&](size_t i, Box b) {
        auto out = boxes;
        out[i] = b;
        return out;
    };
    const auto nan_box = with(321, Box{Vec3(0.0f, kNaN, 0.0f), Vec3(1.0f)});
    const auto inf_box = with(42, Box{Vec3(0.0f), Vec3(1.0f, 1.0f, kInf)});
    const auto inverted = with(7, Box{Vec3(2.0f), Vec3(1.0f)});
    for (const SchedulerEntry& s : schedulers()) {
        expect_error<InputError>([&] { s.build_boxes(nan_box, parallel_options()); }, {"primitive box 321"}, s.name);
        expect_error<InputError>([&] { s.build_boxes(inf_box, parallel_options()); }, {"primitive box 42"}, s.name);
        expect_error<InputError>([&] { s.build_boxes(inverted, parallel_options()); }, {"primitive box 7", "inverted"},
                                 s.name);
    }
    expect_error<InputError>([&] { build_sweep_sah(std::span<const Box>(nan_box)); }, {"primitive box 321"}, "sweep");
    expect_error<InputError>([&] { build_sweep_sah(std::span<const Box>(inverted)); }, {"primitive box 7"}, "sweep");
}

TEST(BadInputLibrary, BadOptions) {
    const TriangleMesh m = own_vertices(1000);
    struct Case {
        std::string name;
        std::function<void(BuildOptions&)> set;
        std::string needle;
    };
    const std::vector<Case> cases = {
        {"bins 1", [](BuildOptions& o) { o.bins = 1; }, "bins"},
        {"bins 257", [](BuildOptions& o) { o.bins = 257; }, "bins"},
        {"leaf 0", [](BuildOptions& o) { o.max_leaf = 0; }, "max_leaf"},
        {"leaf 256", [](BuildOptions& o) { o.max_leaf = 256; }, "max_leaf"},
        {"depth 0", [](BuildOptions& o) { o.max_depth = 0; }, "max_depth"},
        {"depth 256", [](BuildOptions& o) { o.max_depth = 256; }, "max_depth"},
        {"depth too small", [](BuildOptions& o) {
             o.max_leaf = 1;
             o.max_depth = 5;
         }, "max_depth"},
        {"NaN cost", [](BuildOptions& o) { o.traversal_cost = kNaN; }, "traversal_cost"},
        {"zero intersection cost", [](BuildOptions& o) { o.intersection_cost = 0.0f; }, "intersection_cost"},
    };
    for (const Case& c : cases) {
        BuildOptions o = parallel_options();
        c.set(o);
        for (const NamedBuilder& b : builders())
            expect_error<OptionError>([&] { b.build(m.view(), o); }, {c.needle}, b.name + " " + c.name);
    }
}

// ---------------------------------------------------------------------------
// Files: a scratch directory with one file per kind of bad input.

class Files : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = fs::temp_directory_path() / ("canopy_badinput_" + std::to_string(::getpid()));
        fs::create_directories(dir_);
        write("good.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n");
        write("nan.obj", "# a NaN\nv 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
        write("inf.obj", "v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n");
        write("overflow.obj", "v 0 0 0\n\nv 1 0 0\nv 0 1 1e39\nf 1 2 3\n");
        write("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n");
        write("index0.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
        write("relative.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n");
        write("empty.obj", "");
        write("blank.obj", "  \n\t\n\n");
        write("nofaces.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
        write("twocorners.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n");
        write("notanumber.obj", "v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n");
        write("twocoords.obj", "v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n");
        // Skin weights (a tinyobjloader extension): joint ids beyond int were
        // cast to int inside tinyobjloader (undefined behaviour; found by
        // fuzz/run.sh, the second file is the fuzzer's input, shortened).
        write("vw_ok.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvw 1 0 0.25 7 0.75\nf 1 2 3\n");
        write("vw_huge.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvw 1 0 0.5 3e9 0.5\nf 1 2 3\n");
        write("vw_inf.obj", "# a quad\nv 1 0 0\nv 2 1 0\nvw -1.5e3 2.23 2.25 +0. 2.25 +0.5v 0 1e380\nf 1 2 2\n");
        write("vw_word.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvw 1 joint 0.5\nf 1 2 3\n");
        write("text.obj", "This is not a mesh.\nIt is a letter.\n");
        std::string garbage;
        std::mt19937 rng(7);
        for (int i = 0; i < 4096; ++i) garbage += static_cast<char>(rng() & 0xFF);
        write("binary.obj", garbage);
        write("mesh.xyz", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
        fs::create_directories(dir_ / "directory.obj");
    }
    static void TearDownTestSuite() {
        std::error_code ec;
        fs::remove_all(dir_, ec);
    }
    static void write(const std::string& name, const std::string& text) {
        std::ofstream f(dir_ / name, std::ios::binary);
        f << text;
    }
    static std::string path(const std::string& name) { return (dir_ / name).string(); }

    // Loads `name`, expecting an InputError whose message starts with the
    // path and contains every needle.
    static void expect_load_error(const std::string& name, const std::vector<std::string>& needles) {
        const std::string p = path(name);
        try {
            load_scene(p);
            ADD_FAILURE() << name << ": loaded without error";
        } catch (const InputError& e) {
            const std::string msg = e.what();
            EXPECT_EQ(msg.rfind(p, 0), 0u) << name << ": message '" << msg << "' does not start with the path";
            for (const std::string& n : needles)
                EXPECT_NE(msg.find(n), std::string::npos) << name << ": message '" << msg << "' lacks '" << n << "'";
        } catch (const std::exception& e) {
            ADD_FAILURE() << name << ": wrong exception type: " << e.what();
        }
    }

    struct Run {
        int status = -1;  // exit status; -1 when killed by a signal
        std::string out, err;
        std::string first_err_line() const { return err.substr(0, err.find('\n')); }
    };

    static std::string quote(const std::string& s) {
        std::string q = "'";
        for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
        return q + "'";
    }

    // Runs the tool with `args` (already quoted).
    static Run tool(const std::string& args) {
        Run r;
        const char* bin = std::getenv("CANOPY_BIN");
        if (!bin) return r;
        const std::string out = path("stdout.txt"), err = path("stderr.txt");
        const std::string cmd = quote(bin) + " " + args + " >" + quote(out) + " 2>" + quote(err) + " </dev/null";
        const int rc = std::system(cmd.c_str());
        r.status = rc != -1 && WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
        std::ifstream o(out), e(err);
        std::stringstream so, se;
        so << o.rdbuf();
        se << e.rdbuf();
        r.out = so.str();
        r.err = se.str();
        return r;
    }
    static bool have_tool() { return std::getenv("CANOPY_BIN") != nullptr; }

    // `canopy build FILE` must exit 1 with the first stderr line naming the
    // file and containing every needle.
    static void expect_tool_input_error(const std::string& name, const std::vector<std::string>& needles) {
        const Run r = tool("build " + quote(path(name)));
        EXPECT_EQ(r.status, 1) << name << ": stderr: " << r.err;
        const std::string line = r.first_err_line();
        EXPECT_NE(line.find(path(name)), std::string::npos) << name << ": first stderr line '" << line << "'";
        for (const std::string& n : needles)
            EXPECT_NE(line.find(n), std::string::npos) << name << ": first stderr line '" << line << "' lacks '" << n
                                                       << "'";
    }

    static fs::path dir_;
};
fs::path Files::dir_;

TEST_F(Files, LibraryNamesTheFileAndLine) {
    ASSERT_NO_THROW(load_scene(path("good.obj")));
    expect_load_error("nan.obj", {"line 4", "non-finite"});
    expect_load_error("inf.obj", {"line 3", "non-finite"});
    expect_load_error("overflow.obj", {"line 4", "non-finite"});
    expect_load_error("index.obj", {"line 5", "out of range"});
    expect_load_error("index0.obj", {"line 4"});
    expect_load_error("relative.obj", {"line 4", "out of range"});
    expect_load_error("twocorners.obj", {"line 4"});
    expect_load_error("notanumber.obj", {"line 3", "zero"});
    expect_load_error("twocoords.obj", {"line 2"});
    ASSERT_NO_THROW(load_scene(path("vw_ok.obj")));
    expect_load_error("vw_huge.obj", {"line 4", "joint id '3e9'"});
    expect_load_error("vw_inf.obj", {"line 4", "joint id '+0.5v'"});
    expect_load_error("vw_word.obj", {"line 4", "joint id 'joint'"});
}

TEST_F(Files, LibraryRejectsEmptyMissingAndNonMeshFiles) {
    expect_load_error("empty.obj", {"empty"});
    expect_load_error("blank.obj", {"no triangles"});
    expect_load_error("nofaces.obj", {"no triangles"});
    expect_load_error("text.obj", {});
    expect_load_error("binary.obj", {});
    expect_load_error("missing.obj", {"cannot open"});
    expect_load_error("directory.obj", {"directory"});
    expect_load_error("mesh.xyz", {"not supported"});
}

TEST_F(Files, LibraryRejectsBadGeneratorSpecs) {
    for (const char* spec : {"gen:bogus:10", "gen:sphere:0", "gen:sphere:abc", "gen:sphere", "gen:", "gen:sphere:10:x",
                             "gen:sphere:10:1:2", "gen:sphere:1000000000"})
        EXPECT_THROW(load_scene(spec), InputError) << spec;
}

TEST_F(Files, ToolExitsOneNamingFileAndLine) {
    if (!have_tool()) GTEST_SKIP() << "CANOPY_BIN is not set";
    const Run good = tool("build " + quote(path("good.obj")));
    EXPECT_EQ(good.status, 0) << good.err;
    expect_tool_input_error("nan.obj", {"line 4"});
    expect_tool_input_error("inf.obj", {"line 3"});
    expect_tool_input_error("overflow.obj", {"line 4"});
    expect_tool_input_error("index.obj", {"line 5"});
    expect_tool_input_error("index0.obj", {"line 4"});
    expect_tool_input_error("twocorners.obj", {"line 4"});
    expect_tool_input_error("notanumber.obj", {"line 3"});
}

TEST_F(Files, ToolExitsOneOnEmptyMissingAndNonMeshFiles) {
    if (!have_tool()) GTEST_SKIP() << "CANOPY_BIN is not set";
    for (const char* name : {"empty.obj", "blank.obj", "nofaces.obj", "text.obj", "binary.obj", "missing.obj",
                             "directory.obj", "mesh.xyz"})
        expect_tool_input_error(name, {});
    // The same through the other verbs that load scenes.
    for (const char* verb : {"info", "sweep"}) {
        const Run r = tool(std::string(verb) + " " + quote(path("nan.obj")));
        EXPECT_EQ(r.status, 1) << verb << ": " << r.err;
        EXPECT_NE(r.first_err_line().find(path("nan.obj")), std::string::npos) << verb << ": " << r.err;
    }
}

TEST_F(Files, ToolUsageErrorsExitTwo) {
    if (!have_tool()) GTEST_SKIP() << "CANOPY_BIN is not set";
    const std::string good = quote(path("good.obj"));
    for (const std::string& args :
         {std::string("build --bins 1"), "build --bins 1 " + good, "build --bins 257 " + good, "build --leaf 0 " + good,
          "build --leaf 256 " + good, "build --scheduler bogus " + good, "build --no-such-option " + good,
          "build --repeat 0 " + good, std::string("no-such-verb"), std::string(""),
          "sweep --bins 1 " + good, "sweep --bins 2,x " + good, "sweep --threads , " + good,
          "sweep --leaf 0 " + good}) {
        const Run r = tool(args);
        EXPECT_EQ(r.status, 2) << "canopy " << args << ": stderr: " << r.err;
        EXPECT_FALSE(r.err.empty()) << "canopy " << args;
    }
}

TEST_F(Files, ToolRejectsBadGeneratorSpecsWithOne) {
    if (!have_tool()) GTEST_SKIP() << "CANOPY_BIN is not set";
    for (const char* spec : {"gen:bogus:10", "gen:sphere:0", "gen:sphere:abc"}) {
        const Run r = tool(std::string("build ") + spec);
        EXPECT_EQ(r.status, 1) << spec << ": stderr: " << r.err;
        EXPECT_NE(r.first_err_line().find(spec), std::string::npos) << spec << ": " << r.err;
    }
}

}  // namespace
