// canopy sweep: accuracy against speed. For each bin count, the binned
// build's time (median of R builds, at each thread count), its SAH, its SAH
// excess over the exact full-sweep SAH tree (core/sweep_sah.h) in percent,
// and the traversal cost of a fixed, seeded ray set (node visits and
// triangle tests per ray, Mrays/s on one thread); the same for the exact
// tree. Prints a table per scene; optionally writes a CSV and an SVG plot of
// build time (log scale) against error, one curve per scene.
#include "cli.h"
#include "core/bvh.h"
#include "core/rng.h"
#include "core/sah.h"
#include "core/scene.h"
#include "core/sweep_sah.h"
#include "core/traversal.h"
#include "core/validate.h"

#include <glm/geometric.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <numbers>
#include <random>
#include <sstream>

namespace canopy::cli {

namespace {

using Clock = std::chrono::steady_clock;

struct SweepArgs {
    std::vector<std::string> scenes;
    std::string bins = "2,4,8,16,32,64,128,256";
    std::string threads = "1,2";
    std::string scheduler = default_scheduler();
    uint32_t leaf = BuildOptions{}.max_leaf;
    uint32_t rotate_min = BuildOptions{}.rotate_min;
    uint32_t rays = 100000;
    uint32_t repeat = 3;
    std::string csv;
    std::string plot;
};

// The traversal numbers of one tree over the ray set.
struct TraceResult {
    double nodes_per_ray = 0.0;
    double tris_per_ray = 0.0;
    double mrays_per_s = 0.0;
    uint64_t hits = 0;
};

// One row of the table: a bin count (or the exact tree, bins == 0).
struct Row {
    uint32_t bins = 0;                // 0: the exact sweep tree
    std::vector<double> build_ms;     // per thread count (exact: one value, 1 thread)
    double sah = 0.0;
    double error_pct = 0.0;
    TraceResult trace;
};

struct SceneResult {
    std::string name;
    size_t triangles = 0;
    std::vector<Row> rows;  // the bin counts, then the exact tree
};

// The fixed ray set: `count` rays, about half primary rays from a camera
// framing the scene's bounding sphere (looking at its centre from a fixed
// direction, jittered on a grid), the rest secondary rays from the primary
// hit points (origin offset along the normal towards the incoming side,
// directions cosine-distributed around that normal). `tree` finds the hits
// (every valid tree finds the same ones).
std::vector<Ray> make_rays(const Bvh& tree, const TriangleView& mesh, uint32_t count) {
    std::vector<Ray> rays;
    if (tree.empty() || count == 0) return rays;
    rays.reserve(count);
    const Box root = tree.nodes[0].box();
    const glm::dvec3 lo(root.lo), hi(root.hi);
    const glm::dvec3 centre = 0.5 * lo + 0.5 * hi;
    double radius = 0.5 * glm::length(hi - lo);
    if (!(radius > 0.0) || !std::isfinite(radius)) radius = std::max(1.0, glm::length(centre));
    const double half_fov = 20.0 * std::numbers::pi / 180.0;
    const glm::dvec3 from = glm::normalize(glm::dvec3(0.48, 0.36, 0.80));
    const glm::dvec3 eye = centre + from * (radius / std::sin(half_fov));
    const glm::dvec3 fwd = -from;
    const glm::dvec3 right = glm::normalize(glm::cross(fwd, glm::dvec3(0.0, 1.0, 0.0)));
    const glm::dvec3 up = glm::cross(right, fwd);
    const double span = std::tan(half_fov);

    Rng rng(0x5eed5eedULL);
    const uint32_t primary = std::max(1u, count / 2);
    const uint32_t side = static_cast<uint32_t>(std::ceil(std::sqrt(double(primary))));
    struct HitPoint {
        Vec3 org, normal;
    };
    std::vector<HitPoint> hits;
    for (uint32_t i = 0; i < primary; ++i) {
        const double sx = (2.0 * ((i % side) + rng.uniform()) / side - 1.0) * span;
        const double sy = (1.0 - 2.0 * ((i / side) + rng.uniform()) / side) * span;
        Ray r;
        r.org = Vec3(eye);
        r.dir = Vec3(fwd + sx * right + sy * up);
        rays.push_back(r);
        const Hit h = intersect_closest(tree, mesh, r);
        if (!h.found()) continue;
        const uint32_t* idx = mesh.indices.data() + 3 * size_t(h.prim);
        const glm::dvec3 a(mesh.vertices[idx[0]]), b(mesh.vertices[idx[1]]), c(mesh.vertices[idx[2]]);
        const glm::dvec3 p = (1.0 - double(h.u) - double(h.v)) * a + double(h.u) * b + double(h.v) * c;
        glm::dvec3 n = glm::cross(b - a, c - a);
        const double len = glm::length(n);
        n = len > 0.0 && std::isfinite(len) ? n / len : -glm::normalize(glm::dvec3(r.dir));
        if (glm::dot(n, glm::dvec3(r.dir)) > 0.0) n = -n;
        hits.push_back({Vec3(p + n * (1e-4 * radius)), Vec3(n)});
    }
    // Secondary rays, from the hit points in turn (primary rays again when
    // nothing was hit).
    for (size_t k = 0; rays.size() < count; ++k) {
        if (hits.empty()) {
            const Ray again = rays[k % primary];  // a copy: push_back may reallocate
            rays.push_back(again);
            continue;
        }
        const HitPoint& hp = hits[k % hits.size()];
        const double z = 2.0 * rng.uniform() - 1.0, phi = 2.0 * std::numbers::pi * rng.uniform();
        const double rr = std::sqrt(std::max(0.0, 1.0 - z * z));
        glm::dvec3 d = glm::dvec3(hp.normal) + glm::dvec3(rr * std::cos(phi), rr * std::sin(phi), z);
        if (!(glm::length(d) > 1e-6)) d = glm::dvec3(hp.normal);
        Ray r;
        r.org = hp.org;
        r.dir = Vec3(glm::normalize(d));
        rays.push_back(r);
    }
    return rays;
}

TraceResult trace(const Bvh& bvh, const TriangleView& mesh, const std::vector<Ray>& rays,
                  std::vector<Hit>* out) {
    TraceResult res;
    TraversalStats stats;
    if (out) out->resize(rays.size());
    const auto t0 = Clock::now();
    for (size_t i = 0; i < rays.size(); ++i) {
        const Hit h = intersect_closest(bvh, mesh, rays[i], &stats);
        res.hits += h.found();
        if (out) (*out)[i] = h;
    }
    const double s = std::chrono::duration<double>(Clock::now() - t0).count();
    const double n = rays.empty() ? 1.0 : double(rays.size());
    res.nodes_per_ray = double(stats.nodes_visited) / n;
    res.tris_per_ray = double(stats.triangles_tested) / n;
    res.mrays_per_s = s > 0.0 ? double(rays.size()) / s * 1e-6 : 0.0;
    return res;
}

bool same_hit(const Hit& a, const Hit& b) {
    return a.prim == b.prim && std::memcmp(&a.t, &b.t, sizeof(float)) == 0;
}

// Throws nothing for a good run; returns false (after a message on stderr)
// when a tree is invalid or finds other hits than the exact tree.
bool run_scene(const SweepArgs& a, const std::string& spec, const SchedulerEntry& sched,
               const std::vector<uint32_t>& bins_list, const std::vector<uint32_t>& threads_list,
               const Progress& progress, SceneResult& out) {
    progress.show("loading " + spec);
    Scene scene = load_scene(spec);
    const TriangleView view = scene.mesh.view();
    out.name = scene.name;
    out.triangles = view.triangle_count();
    bool ok = true;

    BuildOptions base;
    base.max_leaf = a.leaf;
    base.rotate_min = a.rotate_min;
    base.check();

    // The exact tree, and the ray set (its hits are the reference).
    Row exact;
    progress.show(scene.name + ": the exact sweep tree");
    const auto t0 = Clock::now();
    const Bvh ref = build_sweep_sah(view, base);
    exact.build_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    if (const ValidationReport rep = validate(ref, view, base); !rep.ok()) {
        std::cerr << "canopy sweep: " << scene.name << ": the exact sweep tree failed validation: " << rep.summary()
                  << "\n";
        return false;
    }
    exact.sah = sah_cost(ref);
    const std::vector<Ray> rays = make_rays(ref, view, a.rays);
    std::vector<Hit> ref_hits;
    exact.trace = trace(ref, view, rays, &ref_hits);

    std::vector<Hit> hits;
    for (const uint32_t bins : bins_list) {
        Row row;
        row.bins = bins;
        Bvh first;
        for (size_t ti = 0; ti < threads_list.size(); ++ti) {
            BuildOptions opt = base;
            opt.bins = bins;
            opt.threads = threads_list[ti];
            opt.check();
            progress.show(scene.name + ": bins " + std::to_string(bins) + ", " + std::to_string(threads_list[ti]) +
                          " thread(s)");
            std::vector<double> times;
            for (uint32_t r = 0; r < a.repeat; ++r) {
                Bvh fresh;
                const auto b0 = Clock::now();
                fresh = sched.build_triangles(view, opt, nullptr);
                times.push_back(std::chrono::duration<double, std::milli>(Clock::now() - b0).count());
                if (ti == 0 && r == 0) {
                    first = std::move(fresh);
                } else if (!(fresh == first)) {
                    std::cerr << "canopy sweep: " << scene.name << ": bins " << bins << ": builds differ ("
                              << sched.name << ", threads " << threads_list[ti] << ")\n";
                    ok = false;
                }
            }
            row.build_ms.push_back(median(times));
        }
        if (const ValidationReport rep = validate(first, view, base); !rep.ok()) {
            std::cerr << "canopy sweep: " << scene.name << ": bins " << bins
                      << ": the tree failed validation: " << rep.summary() << "\n";
            ok = false;
        }
        row.sah = sah_cost(first);
        row.error_pct = exact.sah > 0.0 ? 100.0 * (row.sah - exact.sah) / exact.sah : 0.0;
        row.trace = trace(first, view, rays, &hits);
        size_t differ = 0;
        for (size_t i = 0; i < rays.size(); ++i) differ += !same_hit(hits[i], ref_hits[i]);
        if (differ) {
            std::cerr << "canopy sweep: " << scene.name << ": bins " << bins << ": " << differ << " of "
                      << rays.size() << " rays hit differently than in the exact tree\n";
            ok = false;
        }
        out.rows.push_back(std::move(row));
    }
    out.rows.push_back(std::move(exact));
    return ok;
}

void print_table(const SceneResult& s, const std::vector<uint32_t>& threads_list, const SweepArgs& a,
                 const char* sched) {
    std::printf("scene %s: %zu triangles, %s, leaf %u, rotate_min %u, median of %u builds, %u rays\n",
                s.name.c_str(), s.triangles, sched, a.leaf, a.rotate_min, a.repeat, a.rays);
    std::string header = "  bins";
    for (uint32_t t : threads_list) {
        char buf[32];
        std::snprintf(buf, sizeof buf, " %10s", (t ? "ms@" + std::to_string(t) + "T" : std::string("ms@allT")).c_str());
        header += buf;
    }
    header += "        SAH   error %  nodes/ray  tris/ray  Mrays/s";
    std::printf("%s\n", header.c_str());
    for (const Row& r : s.rows) {
        if (r.bins)
            std::printf("%6u", r.bins);
        else
            std::printf("%6s", "exact");
        for (size_t i = 0; i < threads_list.size(); ++i) {
            if (i < r.build_ms.size())
                std::printf(" %10.3f", r.build_ms[i]);
            else
                std::printf(" %10s", "-");
        }
        std::printf(" %10.4f %9.3f %10.2f %9.2f %8.3f\n", r.sah, r.error_pct, r.trace.nodes_per_ray,
                    r.trace.tris_per_ray, r.trace.mrays_per_s);
    }
    std::printf("  (exact: the full-sweep SAH reference, built once, single-threaded)\n\n");
    std::fflush(stdout);
}

std::string csv_quote(const std::string& s) {
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
}

void write_csv(const std::string& path, const std::vector<SceneResult>& results,
               const std::vector<uint32_t>& threads_list, const char* sched) {
    std::ofstream f(path);
    if (!f) throw InputError(path + ": cannot open for writing");
    f << "scene,triangles,builder,bins,threads,build_ms,sah,error_pct,nodes_per_ray,tris_per_ray,mrays_per_s\n";
    f.precision(10);
    for (const SceneResult& s : results)
        for (const Row& r : s.rows)
            for (size_t i = 0; i < r.build_ms.size(); ++i) {
                f << csv_quote(s.name) << ',' << s.triangles << ',' << (r.bins ? sched : "sweep_exact") << ','
                  << (r.bins ? std::to_string(r.bins) : std::string()) << ','
                  << (r.bins ? threads_list[i] : 1u) << ',' << r.build_ms[i] << ',' << r.sah << ','
                  << r.error_pct << ',' << r.trace.nodes_per_ray << ',' << r.trace.tris_per_ray << ','
                  << r.trace.mrays_per_s << '\n';
            }
    if (!f) throw InputError(path + ": write error");
}

std::string xml_escape(const std::string& s) {
    std::string o;
    for (char c : s) {
        switch (c) {
            case '&': o += "&amp;"; break;
            case '<': o += "&lt;"; break;
            case '>': o += "&gt;"; break;
            case '"': o += "&quot;"; break;
            default: o += c;
        }
    }
    return o;
}

// A file's name without its directories (the legend has little room).
std::string legend_name(const std::string& spec) {
    if (is_generator_spec(spec)) return spec;
    const std::string base = std::filesystem::path(spec).filename().string();
    return base.empty() ? spec : base;
}

std::string fmt(double v, int prec = 1) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*f", prec, v);
    return buf;
}

// Build time (x, log scale, at the first thread count) against error % (y),
// one curve per scene, points labelled with their bin count.
void write_svg(const std::string& path, const std::vector<SceneResult>& results, uint32_t threads,
               const char* sched) {
    const double W = 860, H = 540, L = 80, R = 200, T = 50, B = 60;
    double xmin = INFINITY, xmax = -INFINITY, ymin = 0.0, ymax = -INFINITY;
    for (const SceneResult& s : results)
        for (const Row& r : s.rows) {
            if (!r.bins || r.build_ms.empty()) continue;
            const double x = std::max(r.build_ms[0], 1e-6);
            xmin = std::min(xmin, x);
            xmax = std::max(xmax, x);
            ymin = std::min(ymin, r.error_pct);
            ymax = std::max(ymax, r.error_pct);
        }
    if (!(xmin <= xmax)) xmin = 1, xmax = 10;
    if (!(ymax > ymin)) ymax = ymin + 1.0;
    // The x range in decades: the data with a margin, at least half a decade.
    double lxa = std::log10(xmin), lxb = std::log10(xmax);
    const double grow = std::max(0.5 - (lxb - lxa), 0.0) / 2 + 0.05 * (lxb - lxa) + 0.02;
    lxa -= grow;
    lxb += grow;
    // A "nice" y step.
    const double yspan = (ymax - ymin) * 1.08;
    const double raw = yspan / 6.0;
    const double mag = std::pow(10.0, std::floor(std::log10(raw)));
    const double step = raw / mag < 2 ? 2 * mag : raw / mag < 5 ? 5 * mag : 10 * mag;
    const double ya = std::floor(ymin / step) * step, yb = std::ceil((ymin + yspan) / step) * step;
    auto px = [&](double ms) { return L + (std::log10(std::max(ms, 1e-6)) - lxa) / (lxb - lxa) * (W - L - R); };
    auto py = [&](double e) { return T + (yb - e) / (yb - ya) * (H - T - B); };

    std::ostringstream o;
    o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H << "\" viewBox=\"0 0 "
      << W << ' ' << H << "\" font-family=\"sans-serif\" font-size=\"12\">\n";
    o << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
    o << "<text x=\"" << (L + (W - L - R) / 2) << "\" y=\"24\" text-anchor=\"middle\" font-size=\"15\">"
      << "canopy: binned SAH error against build time (" << xml_escape(sched) << ", " << threads
      << (threads == 1 ? " thread" : " threads") << ")</text>\n";
    // Grid and ticks.
    // Vertical grid lines at 1..9 x 10^k, labelled at 1, 2 and 5 x 10^k
    // (every one when the range is narrow).
    const bool narrow = lxb - lxa < 1.2;
    for (double d = std::floor(lxa); d <= std::ceil(lxb); d += 1.0) {
        for (int m = 1; m < 10; ++m) {
            const double lv = d + std::log10(double(m));
            if (lv < lxa || lv > lxb) continue;
            const double x = px(std::pow(10.0, lv));
            o << "<line x1=\"" << fmt(x) << "\" y1=\"" << T << "\" x2=\"" << fmt(x) << "\" y2=\"" << (H - B)
              << "\" stroke=\"" << (m == 1 ? "#bbb" : "#eee") << "\"/>\n";
            if (m == 1 || m == 2 || m == 5 || narrow) {
                char label[32];
                std::snprintf(label, sizeof label, "%g", double(m) * std::pow(10.0, d));
                o << "<text x=\"" << fmt(x) << "\" y=\"" << (H - B + 18) << "\" text-anchor=\"middle\">" << label
                  << "</text>\n";
            }
        }
    }
    for (double v = ya; v <= yb + step * 1e-6; v += step) {
        const double y = py(v);
        o << "<line x1=\"" << L << "\" y1=\"" << fmt(y) << "\" x2=\"" << (W - R) << "\" y2=\"" << fmt(y)
          << "\" stroke=\"" << (std::fabs(v) < step * 1e-6 ? "#888" : "#ddd") << "\"/>\n";
        o << "<text x=\"" << (L - 8) << "\" y=\"" << fmt(y + 4) << "\" text-anchor=\"end\">"
          << fmt(std::fabs(v) < step * 1e-6 ? 0.0 : v, step < 1 ? (step < 0.1 ? 2 : 1) : 0) << "</text>\n";
    }
    o << "<rect x=\"" << L << "\" y=\"" << T << "\" width=\"" << (W - L - R) << "\" height=\"" << (H - T - B)
      << "\" fill=\"none\" stroke=\"black\"/>\n";
    o << "<text x=\"" << (L + (W - L - R) / 2) << "\" y=\"" << (H - 18)
      << "\" text-anchor=\"middle\">build time (ms, log scale, median)</text>\n";
    o << "<text transform=\"translate(22 " << (T + (H - T - B) / 2)
      << ") rotate(-90)\" text-anchor=\"middle\">SAH excess over the exact sweep (%)</text>\n";
    static const char* colours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd",
                                    "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22"};
    for (size_t si = 0; si < results.size(); ++si) {
        const SceneResult& s = results[si];
        const char* col = colours[si % (sizeof colours / sizeof *colours)];
        std::string pts;
        for (const Row& r : s.rows)
            if (r.bins && !r.build_ms.empty())
                pts += fmt(px(r.build_ms[0])) + "," + fmt(py(r.error_pct)) + " ";
        o << "<polyline fill=\"none\" stroke=\"" << col << "\" stroke-width=\"2\" points=\"" << pts << "\"/>\n";
        for (const Row& r : s.rows) {
            if (!r.bins || r.build_ms.empty()) continue;
            const double x = px(r.build_ms[0]), y = py(r.error_pct);
            o << "<circle cx=\"" << fmt(x) << "\" cy=\"" << fmt(y) << "\" r=\"4\" fill=\"" << col << "\"/>\n";
            o << "<text x=\"" << fmt(x + 6) << "\" y=\"" << fmt(y - 6) << "\" fill=\"" << col << "\">" << r.bins
              << "</text>\n";
        }
        const double ly = T + 10 + 20 * double(si);
        o << "<line x1=\"" << (W - R + 15) << "\" y1=\"" << ly << "\" x2=\"" << (W - R + 40) << "\" y2=\"" << ly
          << "\" stroke=\"" << col << "\" stroke-width=\"2\"/>\n";
        o << "<text x=\"" << (W - R + 46) << "\" y=\"" << (ly + 4) << "\">" << xml_escape(legend_name(s.name)) << "</text>\n";
    }
    o << "<text x=\"" << (W - R + 15) << "\" y=\"" << (T + 20 + 20 * double(results.size()))
      << "\" fill=\"#555\">labels: bins</text>\n";
    o << "</svg>\n";
    std::ofstream f(path);
    if (!f) throw InputError(path + ": cannot open for writing");
    f << o.str();
    if (!f) throw InputError(path + ": write error");
}

int run_sweep(const SweepArgs& a) {
    const SchedulerEntry& sched = scheduler_or_throw(a.scheduler);
    const std::vector<uint32_t> bins_list = parse_list(a.bins, "--bins");
    const std::vector<uint32_t> threads_list = parse_list(a.threads, "--threads");
    for (uint32_t b : bins_list)
        if (b < kMinBins || b > kMaxBins)
            throw UsageError("--bins: " + std::to_string(b) + " is out of range (" + std::to_string(kMinBins) +
                             " to " + std::to_string(kMaxBins) + ")");
    for (uint32_t t : threads_list)
        if (t > 4096) throw UsageError("--threads: " + std::to_string(t) + " is out of range (0 to 4096)");
    if (a.leaf < 1 || a.leaf > kMaxLeafSize)
        throw UsageError("--leaf: " + std::to_string(a.leaf) + " is out of range (1 to 255)");
    std::vector<std::string> specs = a.scenes;
    if (specs.empty()) specs.push_back(default_scene().name);

    std::vector<SceneResult> results;
    bool ok = true;
    const Progress progress("sweep");
    for (const std::string& spec : specs) {
        SceneResult res;
        try {
            ok = run_scene(a, spec, sched, bins_list, threads_list, progress, res) && ok;
        } catch (...) {
            progress.clear();  // main() prints the error on a clean line
            throw;
        }
        progress.clear();
        if (res.rows.empty()) return kInvalid;
        print_table(res, threads_list, a, sched.name);
        results.push_back(std::move(res));
    }
    if (!a.csv.empty()) write_csv(a.csv, results, threads_list, sched.name);
    if (!a.plot.empty()) write_svg(a.plot, results, threads_list.front(), sched.name);
    return ok ? kOk : kInvalid;
}

}  // namespace

Runner add_sweep(CLI::App& app) {
    auto a = std::make_shared<SweepArgs>();
    CLI::App* sweep = app.add_subcommand(
        "sweep", "Binned build time, SAH and traversal cost against the exact full-sweep SAH tree, per bin count");
    sweep->add_option("scenes", a->scenes, "Mesh files or gen:NAME:COUNT[:SEED] (default: gen:sphere:100000)");
    sweep->add_option("--bins", a->bins, "Bin counts to compare, comma-separated")->capture_default_str();
    sweep->add_option("--threads", a->threads, "Thread counts to time, comma-separated (0 = all)")
        ->capture_default_str();
    sweep->add_option("--scheduler", a->scheduler, "Scheduler: " + scheduler_names())->capture_default_str();
    sweep->add_option("--leaf", a->leaf, "Largest leaf (1-255)")->capture_default_str();
    sweep->add_option("--rotate-min", a->rotate_min,
                      "Nodes of at least this many primitives may take a tree rotation (0 = none, else >= 256)")
        ->capture_default_str();
    sweep->add_option("--rays", a->rays, "Rays in the fixed ray set (half primary, half secondary)")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100000000u));
    sweep->add_option("--repeat", a->repeat, "Builds to time per point; the median is reported")
        ->capture_default_str()
        ->check(CLI::Range(1u, 100000u));
    sweep->add_option("--csv", a->csv, "Write the results as CSV to FILE");
    sweep->add_option("--plot", a->plot, "Write an SVG plot (build time vs error, one curve per scene) to FILE");
    return [a, sweep]() { return *sweep ? run_sweep(*a) : -1; };
}

}  // namespace canopy::cli
