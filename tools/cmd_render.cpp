// canopy render: build a BVH over a scene and ray trace a picture of it, or
// (--heatmap) the classic picture of BVH quality: the nodes each primary ray
// visits, through a turbo colour ramp, with a legend drawn in a built-in
// bitmap font. The PNG is written with stb_image_write.
#include "cli.h"
#include "core/bvh.h"
#include "core/scene.h"
#include "core/traversal.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <glm/geometric.hpp>

#include <unistd.h>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wpedantic"
#pragma GCC diagnostic ignored "-Wcast-qual"
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>
#pragma GCC diagnostic pop

namespace canopy::cli {

namespace {

struct RenderArgs {
    std::string scene;
    std::string output;
    uint32_t width = 640;
    uint32_t height = 480;
    bool heatmap = false;
    std::string scheduler = default_scheduler();
    uint32_t threads = 0;
};

struct Rgb {
    uint8_t r, g, b;
};

class Image {
public:
    Image(uint32_t w, uint32_t h) : w_(w), h_(h), px_(size_t(w) * h * 3, 0) {}
    uint32_t width() const { return w_; }
    uint32_t height() const { return h_; }
    void set(int x, int y, Rgb c) {
        if (x < 0 || y < 0 || uint32_t(x) >= w_ || uint32_t(y) >= h_) return;
        uint8_t* p = &px_[(size_t(y) * w_ + uint32_t(x)) * 3];
        p[0] = c.r;
        p[1] = c.g;
        p[2] = c.b;
    }
    void fill(int x0, int y0, int x1, int y1, Rgb c) {  // [x0, x1) x [y0, y1)
        for (int y = y0; y < y1; ++y)
            for (int x = x0; x < x1; ++x) set(x, y, c);
    }
    const uint8_t* data() const { return px_.data(); }

private:
    uint32_t w_, h_;
    std::vector<uint8_t> px_;
};

// --- A 5x7 bitmap font: digits and the few other characters the legend uses.
// Each row is 5 bits, most significant bit leftmost.

struct Glyph {
    char c;
    std::array<uint8_t, 7> rows;
};

constexpr Glyph kFont[] = {
    {'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}},
    {'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}},
    {'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
    {'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}},
    {'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
    {'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}},
    {'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
    {'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}},
    {'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
    {'a', {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F}},
    {'d', {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F}},
    {'e', {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E}},
    {'n', {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11}},
    {'o', {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E}},
    {'r', {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10}},
    {'s', {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E}},
    {'y', {0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E}},
    {'/', {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}},
    {' ', {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00}},
};
constexpr int kGlyphW = 5, kGlyphH = 7, kAdvance = 6;
// The legend band, in font pixels: padding 2, bar 5, gap 2, text 7, padding 2.
constexpr int kLegendRows = 2 + 5 + 2 + kGlyphH + 2;

const Glyph* glyph(char c) {
    for (const Glyph& g : kFont)
        if (g.c == c) return &g;
    return nullptr;
}

int text_width(const std::string& s, int scale) {
    return s.empty() ? 0 : (int(s.size()) * kAdvance - 1) * scale;
}

void draw_text(Image& img, int x, int y, const std::string& s, int scale, Rgb c) {
    for (char ch : s) {
        if (const Glyph* g = glyph(ch)) {
            for (int row = 0; row < kGlyphH; ++row)
                for (int col = 0; col < kGlyphW; ++col)
                    if (g->rows[row] & (0x10 >> col))
                        img.fill(x + col * scale, y + row * scale, x + (col + 1) * scale, y + (row + 1) * scale, c);
        }
        x += kAdvance * scale;
    }
}

// --- Turbo (Google, 2019; sampled from its polynomial approximation at 17
// points), interpolated linearly: dark blue through green and yellow to red.
Rgb ramp(double t) {
    static constexpr std::array<std::array<double, 3>, 17> k = {{
        {35, 23, 27},    {73, 62, 175},  {68, 106, 238}, {50, 149, 247}, {38, 189, 225}, {41, 221, 187},
        {64, 243, 146},  {102, 253, 109}, {150, 250, 80}, {198, 235, 59}, {238, 208, 45}, {255, 171, 36},
        {255, 128, 29},  {238, 84, 21},  {201, 45, 12},  {161, 18, 2},   {144, 13, 0},
    }};
    t = std::clamp(std::isfinite(t) ? t : 0.0, 0.0, 1.0) * double(k.size() - 1);
    const size_t i = std::min(size_t(t), k.size() - 2);
    const double f = t - double(i);
    auto mix = [&](int ch) { return uint8_t(std::lround(k[i][ch] + (k[i + 1][ch] - k[i][ch]) * f)); };
    return {mix(0), mix(1), mix(2)};
}

uint8_t encode_srgb(double linear) {
    linear = std::clamp(linear, 0.0, 1.0);
    const double s = linear <= 0.0031308 ? 12.92 * linear : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
    return uint8_t(std::lround(s * 255.0));
}

// --- The camera: looks at the centre of the scene's box from a fixed
// direction (in front, +z, slightly above; up +y), 40 degrees vertical field
// of view, at the smallest distance (plus a margin) at which all eight
// corners of the box are inside the frame.
struct Camera {
    Vec3 eye, forward, right, up;
    float tan_x = 0, tan_y = 0;  // half extents of the image plane at distance 1

    Camera(const Box& box, uint32_t w, uint32_t h) {
        constexpr double kPi = 3.14159265358979323846;
        const double vfov = 40.0 * kPi / 180.0;
        tan_y = float(std::tan(vfov / 2));
        tan_x = tan_y * float(w) / float(std::max(h, 1u));
        forward = -glm::normalize(Vec3(0.0f, 0.3f, 1.0f));
        right = glm::normalize(glm::cross(forward, Vec3(0.0f, 1.0f, 0.0f)));
        up = glm::cross(right, forward);

        Vec3 centre(0.0f);
        double radius = 1.0;
        if (!box.is_empty()) {
            centre = (box.lo + box.hi) * 0.5f;
            const double ex = box.extent(0), ey = box.extent(1), ez = box.extent(2);
            radius = 0.5 * std::sqrt(ex * ex + ey * ey + ez * ez);
            if (!(radius > 0.0) || !std::isfinite(radius)) radius = 1.0;
        }
        constexpr double kMargin = 1.15;  // the box fills at most 1/1.15 of the frame
        double dist = 1e-3 * radius;
        if (!box.is_empty()) {
            for (int corner = 0; corner < 8; ++corner) {
                const Vec3 p((corner & 1 ? box.hi.x : box.lo.x), (corner & 2 ? box.hi.y : box.lo.y),
                             (corner & 4 ? box.hi.z : box.lo.z));
                const Vec3 q = p - centre;
                const double pr = std::abs(double(glm::dot(q, right)));
                const double pu = std::abs(double(glm::dot(q, up)));
                const double pf = double(glm::dot(q, forward));
                // A corner at depth dist + pf must satisfy |pr| <= tan_x / margin * depth.
                dist = std::max(dist, pr * kMargin / tan_x - pf);
                dist = std::max(dist, pu * kMargin / tan_y - pf);
                dist = std::max(dist, -pf + 1e-3 * radius);  // the eye stays outside the box
            }
        }
        eye = centre - forward * float(dist);
    }

    Ray ray(uint32_t x, uint32_t y, uint32_t w, uint32_t h) const {
        const float sx = (2.0f * (float(x) + 0.5f) / float(w) - 1.0f) * tan_x;
        const float sy = (1.0f - 2.0f * (float(y) + 0.5f) / float(h)) * tan_y;
        Ray r;
        r.org = eye;
        r.dir = glm::normalize(forward + sx * right + sy * up);
        return r;
    }
};

// Calls row(y) for every y in [0, rows) on `threads` threads (rows handed out
// one at a time), printing a percentage on stderr when it is a terminal.
template <class RowFn>
void parallel_rows(uint32_t rows, uint32_t threads, bool progress, const RowFn& row) {
    std::atomic<uint32_t> next{0}, done{0};
    auto work = [&](bool reporter) {
        int shown = -1;
        for (uint32_t y; (y = next.fetch_add(1, std::memory_order_relaxed)) < rows;) {
            row(y);
            const uint32_t d = done.fetch_add(1, std::memory_order_relaxed) + 1;
            if (reporter && progress) {
                const int pct = int(uint64_t(d) * 100 / rows);
                if (pct != shown) {
                    std::fprintf(stderr, "\rcanopy render: tracing %3d%%", pct);
                    shown = pct;
                }
            }
        }
    };
    std::vector<std::thread> pool;
    for (uint32_t t = 1; t < threads; ++t) pool.emplace_back(work, false);
    work(true);
    for (std::thread& t : pool) t.join();
    if (progress) std::fprintf(stderr, "\rcanopy render: tracing 100%%\n");
}

// The legend of the heatmap in the band [y0, img.height()): a caption, a
// colour bar from lo to hi and tick labels at lo, the middle and hi.
void draw_legend(Image& img, int y0, uint32_t lo, uint32_t hi, int scale) {
    const int w = int(img.width()), h = int(img.height());
    const Rgb band{24, 24, 28}, ink{235, 235, 235};
    img.fill(0, y0, w, h, band);
    const int pad = 2 * scale;
    const int bar_h = 5 * scale;
    const int text_h = kGlyphH * scale;
    const int bar_y = y0 + pad;
    const int label_y = bar_y + bar_h + 2 * scale;

    const uint32_t mid = lo + (hi - lo) / 2;
    const std::string lo_s = std::to_string(lo), mid_s = std::to_string(mid), hi_s = std::to_string(hi);
    const std::string caption = "nodes/ray";
    const int half_label = (text_width(hi_s, scale) + 1) / 2;

    int x_left = pad + (text_width(lo_s, scale) + 1) / 2;
    const int x_right = w - pad - half_label;
    // The caption sits to the left of the bar when that leaves the bar at
    // least half of the width.
    const int cap_w = text_width(caption, scale);
    if (x_right - (x_left + cap_w + 6 * scale) >= w / 2) {
        draw_text(img, pad, bar_y + (label_y + text_h - bar_y - text_h) / 2, caption, scale, ink);
        x_left += cap_w + 6 * scale;
    }
    if (x_right <= x_left) return;  // too narrow for a legend

    const int span = x_right - x_left;
    for (int x = x_left; x <= x_right; ++x) {
        const Rgb c = ramp(double(x - x_left) / double(span));
        img.fill(x, bar_y, x + 1, bar_y + bar_h, c);
    }
    auto tick = [&](uint32_t value, const std::string& label) {
        const double f = hi > lo ? double(value - lo) / double(hi - lo) : 0.0;
        const int x = x_left + int(std::lround(f * span));
        img.fill(x - scale / 2, bar_y + bar_h, x - scale / 2 + scale, bar_y + bar_h + scale, ink);
        const int tw = text_width(label, scale);
        const int tx = std::clamp(x - tw / 2, 0, std::max(0, w - tw));
        draw_text(img, tx, label_y, label, scale, ink);
    };
    tick(lo, lo_s);
    if (hi > lo) {
        // The middle label only when it does not run into the outer ones.
        const double fm = double(mid - lo) / double(hi - lo);
        const int xm = x_left + int(std::lround(fm * span));
        const int mw = text_width(mid_s, scale);
        const int gap = 2 * scale;
        const bool fits = xm - mw / 2 >= x_left + (text_width(lo_s, scale) + 1) / 2 + gap &&
                          xm + (mw + 1) / 2 <= x_right - half_label - gap;
        if (fits && mid != lo && mid != hi) tick(mid, mid_s);
        tick(hi, hi_s);
    }
}

int run_render(const RenderArgs& a) {
    const SchedulerEntry* sched = &scheduler_or_throw(a.scheduler);
    const bool progress = isatty(2) != 0;
    if (progress) std::fprintf(stderr, "canopy render: loading %s\n", a.scene.empty() ? "the default scene" : a.scene.c_str());
    Scene scene = a.scene.empty() ? default_scene() : load_scene(a.scene);
    const TriangleView view = scene.mesh.view();
    BuildOptions opt;
    opt.threads = a.threads;
    opt.check();
    if (progress) std::fprintf(stderr, "canopy render: building the BVH (%s)\n", sched->name);
    const Bvh bvh = sched->build_triangles(view, opt);

    const uint32_t w = a.width, h = a.height;
    Image img(w, h);

    // The heatmap keeps a band at the bottom for its legend; the scene is
    // framed in the rows above it.
    const int scale = std::max(1, int(std::min(h / 180, w / 240)));
    const uint32_t legend_h = a.heatmap ? uint32_t(kLegendRows * scale) : 0;
    if (legend_h + 8 > h) throw UsageError("render: --height " + std::to_string(h) + " leaves no room for the heatmap legend (at least " +
                                           std::to_string(legend_h + 8) + " rows)");
    const uint32_t rh = h - legend_h;

    Box box;
    for (uint32_t i : scene.mesh.indices) box.extend(scene.mesh.vertices[i]);
    const Camera cam(box, w, rh);

    std::vector<uint32_t> visits(size_t(w) * rh, 0);
    std::vector<uint8_t> hits(size_t(w) * rh, 0);
    const uint32_t threads = a.threads ? a.threads : std::max(1u, std::thread::hardware_concurrency());
    const Vec3 albedo(0.80f, 0.76f, 0.68f);
    const Rgb background{48, 48, 52};
    parallel_rows(rh, std::min(threads, rh), progress, [&](uint32_t y) {
        for (uint32_t x = 0; x < w; ++x) {
            const Ray ray = cam.ray(x, y, w, rh);
            TraversalStats stats;
            const Hit hit = intersect_closest(bvh, view, ray, &stats);
            visits[size_t(y) * w + x] = uint32_t(std::min<uint64_t>(stats.nodes_visited, UINT32_MAX));
            hits[size_t(y) * w + x] = hit.found();
            if (a.heatmap) continue;
            if (!hit.found()) {
                img.set(int(x), int(y), background);
                continue;
            }
            const Vec3 p0 = scene.mesh.vertex(hit.prim, 0), p1 = scene.mesh.vertex(hit.prim, 1),
                       p2 = scene.mesh.vertex(hit.prim, 2);
            const Vec3 n = glm::cross(p1 - p0, p2 - p0);
            const float len = glm::length(n);
            const float lambert = len > 0.0f && std::isfinite(len) ? std::abs(glm::dot(n / len, ray.dir)) : 0.0f;
            const Vec3 c = albedo * (0.08f + 0.92f * lambert);
            img.set(int(x), int(y), {encode_srgb(c.x), encode_srgb(c.y), encode_srgb(c.z)});
        }
    });

    uint64_t sum = 0;
    uint32_t vmin = UINT32_MAX, vmax = 0;
    uint64_t hit_sum = 0, hit_count = 0;
    for (size_t i = 0; i < visits.size(); ++i) {
        const uint32_t v = visits[i];
        sum += v;
        hit_sum += hits[i] ? v : 0;
        hit_count += hits[i];
        vmin = std::min(vmin, v);
        vmax = std::max(vmax, v);
    }
    const double mean = visits.empty() ? 0.0 : double(sum) / double(visits.size());

    if (a.heatmap) {
        for (uint32_t y = 0; y < rh; ++y)
            for (uint32_t x = 0; x < w; ++x) {
                const uint32_t v = visits[size_t(y) * w + x];
                img.set(int(x), int(y), ramp(vmax > vmin ? double(v - vmin) / double(vmax - vmin) : 0.0));
            }
        draw_legend(img, int(rh), vmin, vmax, scale);
    }

    errno = 0;
    if (!stbi_write_png(a.output.c_str(), int(w), int(h), 3, img.data(), int(w) * 3)) {
        const std::string why = errno ? std::string(": ") + std::strerror(errno) : std::string();
        throw Error(a.output + ": cannot write the PNG" + why);
    }
    std::printf("scene      %s (%zu triangles)\n", scene.name.c_str(), view.triangle_count());
    std::printf("scheduler  %s\n", sched->name);
    std::printf("image      %s (%ux%u%s)\n", a.output.c_str(), w, h, a.heatmap ? ", heatmap" : "");
    std::printf("nodes/ray  mean %.2f, max %u (min %u) over %zu primary rays\n", mean, vmax,
                visits.empty() ? 0u : vmin, visits.size());
    std::printf("           mean %.2f over the %llu rays that hit the scene\n",
                hit_count ? double(hit_sum) / double(hit_count) : 0.0, (unsigned long long)hit_count);
    std::fflush(stdout);
    return kOk;
}

}  // namespace

Runner add_render(CLI::App& app) {
    auto a = std::make_shared<RenderArgs>();
    CLI::App* render = app.add_subcommand("render", "Ray trace a PNG of a scene, or a heatmap of the nodes each ray visits");
    render->add_option("scene", a->scene, "Mesh file or gen:NAME:COUNT[:SEED] (default: gen:sphere:100000)");
    render->add_option("-o,--output", a->output, "The PNG file to write")->required();
    render->add_option("--width", a->width, "Image width in pixels")->capture_default_str()->check(CLI::Range(1u, 16384u));
    render->add_option("--height", a->height, "Image height in pixels")->capture_default_str()->check(CLI::Range(1u, 16384u));
    render->add_flag("--heatmap", a->heatmap,
                     "Colour each pixel by the BVH nodes its ray visits (turbo colour ramp), with a legend in a bottom band");
    render->add_option("--scheduler", a->scheduler, "Scheduler: " + scheduler_names())->capture_default_str();
    render->add_option("--threads", a->threads, "Thread upper bound for the build and the tracing (0 = all hardware threads)")
        ->capture_default_str();
    return [a, render]() { return *render ? run_render(*a) : -1; };
}

}  // namespace canopy::cli
