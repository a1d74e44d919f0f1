#include "embree_compare.h"

#include "core/error.h"
#include "core/geometry.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <mutex>
#include <new>
#include <vector>

namespace canopy::embree {

namespace {

using Clock = std::chrono::steady_clock;

double ms_between(Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
}

const char* error_name(RTCError e) {
    switch (e) {
        case RTC_ERROR_NONE: return "no error";
        case RTC_ERROR_UNKNOWN: return "unknown error";
        case RTC_ERROR_INVALID_ARGUMENT: return "invalid argument";
        case RTC_ERROR_INVALID_OPERATION: return "invalid operation";
        case RTC_ERROR_OUT_OF_MEMORY: return "out of memory";
        case RTC_ERROR_UNSUPPORTED_CPU: return "unsupported CPU";
        case RTC_ERROR_CANCELLED: return "cancelled";
    }
    return "error";
}

// The nodes of Embree's generic build, allocated by rtcThreadLocalAlloc in
// the callbacks below (they live until the RTCBVH is released).
struct TreeNode {
    uint32_t leaf;   // 1 for a leaf
    uint32_t count;  // leaf: primitives; inner: children
};
struct InnerNode : TreeNode {
    TreeNode* child[2];
    RTCBounds bounds[2];
};
struct LeafNode : TreeNode {
    uint32_t* ids() { return reinterpret_cast<uint32_t*>(this + 1); }
};

void* create_node(RTCThreadLocalAllocator alloc, unsigned int child_count, void*) {
    void* p = rtcThreadLocalAlloc(alloc, sizeof(InnerNode), 16);
    auto* n = new (p) InnerNode;
    n->leaf = 0;
    n->count = child_count;
    n->child[0] = n->child[1] = nullptr;
    return n;
}

void set_children(void* node, void** children, unsigned int child_count, void*) {
    auto* n = static_cast<InnerNode*>(node);
    for (unsigned i = 0; i < child_count && i < 2; ++i) n->child[i] = static_cast<TreeNode*>(children[i]);
}

void set_bounds(void* node, const RTCBounds** bounds, unsigned int child_count, void*) {
    auto* n = static_cast<InnerNode*>(node);
    for (unsigned i = 0; i < child_count && i < 2; ++i) n->bounds[i] = *bounds[i];
}

void* create_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive* prims, size_t count, void*) {
    void* p = rtcThreadLocalAlloc(alloc, sizeof(LeafNode) + count * sizeof(uint32_t), 16);
    auto* n = new (p) LeafNode;
    n->leaf = 1;
    n->count = static_cast<uint32_t>(count);
    uint32_t* ids = n->ids();
    for (size_t i = 0; i < count; ++i) ids[i] = prims[i].primID;
    return n;
}

Box to_box(const RTCBounds& b) {
    return Box{Vec3(b.lower_x, b.lower_y, b.lower_z), Vec3(b.upper_x, b.upper_y, b.upper_z)};
}

// Embree's tree in canopy's canonical layout: child pairs appended in
// depth-first pre-order of their parents, left first; leaves' ids appended
// to the permutation in the same order.
Bvh convert(const TreeNode* root, const Box& root_box, size_t primitives) {
    Bvh bvh;
    bvh.permutation.reserve(primitives);
    bvh.nodes.reserve(2 * primitives);
    struct Item {
        const TreeNode* node;
        size_t slot;
    };
    bvh.nodes.emplace_back();  // every field is set below
    bvh.nodes[0].set_box(root_box);
    std::vector<Item> stack{{root, 0}};
    while (!stack.empty()) {
        const Item it = stack.back();
        stack.pop_back();
        if (it.node->leaf) {
            auto* leaf = static_cast<const LeafNode*>(it.node);
            bvh.nodes[it.slot].index = static_cast<uint32_t>(bvh.permutation.size());
            bvh.nodes[it.slot].count = leaf->count;
            const uint32_t* ids = const_cast<LeafNode*>(leaf)->ids();
            bvh.permutation.insert(bvh.permutation.end(), ids, ids + leaf->count);
            continue;
        }
        auto* inner = static_cast<const InnerNode*>(it.node);
        if (inner->count != 2 || !inner->child[0] || !inner->child[1])
            throw Error("Embree rtcBuildBVH returned an inner node with " + std::to_string(inner->count) +
                        " children (expected 2)");
        const size_t first = bvh.nodes.size();
        bvh.nodes[it.slot].index = static_cast<uint32_t>(first);
        bvh.nodes[it.slot].count = 0;
        bvh.nodes.resize(first + 2);
        for (int c = 0; c < 2; ++c) {
            bvh.nodes[first + c].set_box(to_box(inner->bounds[c]));
            bvh.nodes[first + c].count = 0;
        }
        stack.push_back({inner->child[1], first + 1});
        stack.push_back({inner->child[0], first});
    }
    return bvh;
}

}  // namespace

std::string version() { return RTC_VERSION_STRING; }

struct Device::Impl {
    RTCDevice device = nullptr;
    uint32_t threads = 1;
    std::mutex mutex;
    std::string last_error;

    static void on_error(void* self, RTCError code, const char* str) {
        auto* d = static_cast<Impl*>(self);
        std::lock_guard<std::mutex> lock(d->mutex);
        if (d->last_error.empty()) d->last_error = std::string(error_name(code)) + (str ? std::string(": ") + str : "");
    }
    // Throws when Embree reported an error since the last check.
    void check(const char* what) {
        const RTCError code = rtcGetDeviceError(device);
        std::lock_guard<std::mutex> lock(mutex);
        if (code != RTC_ERROR_NONE || !last_error.empty()) {
            const std::string msg = last_error.empty() ? error_name(code) : last_error;
            last_error.clear();
            throw Error(std::string("Embree ") + what + " failed: " + msg);
        }
    }
};

Device::Device(uint32_t threads) : impl_(std::make_unique<Impl>()) {
    impl_->threads = threads;
    const std::string config = "threads=" + std::to_string(threads);
    impl_->device = rtcNewDevice(config.c_str());
    if (!impl_->device)
        throw Error("Embree rtcNewDevice(\"" + config + "\") failed: " + error_name(rtcGetDeviceError(nullptr)));
    rtcSetDeviceErrorFunction(impl_->device, &Impl::on_error, impl_.get());
}

Device::~Device() {
    if (impl_ && impl_->device) rtcReleaseDevice(impl_->device);
}

uint32_t Device::threads() const { return impl_->threads; }

struct Input::Impl {
    std::vector<float> vertices;  // x y z per vertex, then one float4 of padding
    const uint32_t* indices = nullptr;
    size_t vertex_count = 0;
    size_t triangles = 0;
    std::vector<RTCBuildPrimitive> boxes;  // pristine
    std::vector<RTCBuildPrimitive> work;   // what rtcBuildBVH may overwrite
    Box bounds;
};

Input::Input(const TriangleView& mesh) : impl_(std::make_unique<Impl>()) {
    Impl& in = *impl_;
    in.vertex_count = mesh.vertices.size();
    in.triangles = mesh.triangle_count();
    in.indices = mesh.indices.data();
    in.vertices.assign(3 * in.vertex_count + 4, 0.0f);
    for (size_t v = 0; v < in.vertex_count; ++v)
        for (int a = 0; a < 3; ++a) in.vertices[3 * v + a] = mesh.vertices[v][a];
    in.boxes.resize(in.triangles);
    for (size_t t = 0; t < in.triangles; ++t) {
        Box b;
        for (int c = 0; c < 3; ++c) {
            const uint32_t i = mesh.indices[3 * t + c];
            if (i >= in.vertex_count) throw InputError("triangle " + std::to_string(t) + ": index out of range");
            b.extend(mesh.vertices[i]);
        }
        RTCBuildPrimitive& p = in.boxes[t];
        // As canopy's primitive bounds: -0 stored as +0.
        p.lower_x = canonical_zero(b.lo.x);
        p.lower_y = canonical_zero(b.lo.y);
        p.lower_z = canonical_zero(b.lo.z);
        p.upper_x = canonical_zero(b.hi.x);
        p.upper_y = canonical_zero(b.hi.y);
        p.upper_z = canonical_zero(b.hi.z);
        p.geomID = 0;
        p.primID = static_cast<unsigned>(t);
        in.bounds.extend(Box{Vec3(p.lower_x, p.lower_y, p.lower_z), Vec3(p.upper_x, p.upper_y, p.upper_z)});
    }
    in.work.resize(in.triangles);
}

Input::~Input() = default;

size_t Input::triangle_count() const { return impl_->triangles; }

double scene_build_ms(Device& device, Input& input) {
    Device::Impl& d = device.impl();
    Input::Impl& in = input.impl();
    const auto t0 = Clock::now();
    RTCScene scene = rtcNewScene(d.device);
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
    RTCGeometry geom = rtcNewGeometry(d.device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_MEDIUM);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, in.vertices.data(), 0,
                               3 * sizeof(float), in.vertex_count);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, in.indices, 0,
                               3 * sizeof(uint32_t), in.triangles);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    const auto t1 = Clock::now();
    rtcReleaseScene(scene);
    d.check("scene build");
    return ms_between(t0, t1);
}

double builder_ms(Device& device, Input& input, uint32_t max_leaf, uint32_t max_depth, Bvh* tree) {
    Device::Impl& d = device.impl();
    Input::Impl& in = input.impl();
    if (max_leaf < 1 || max_leaf > kMaxBuilderLeaf)
        throw OptionError("Embree's rtcBuildBVH takes leaves of 1 to " + std::to_string(kMaxBuilderLeaf) +
                          " primitives, not " + std::to_string(max_leaf));
    if (in.triangles == 0) {
        if (tree) *tree = Bvh{};
        return 0.0;
    }
    std::copy(in.boxes.begin(), in.boxes.end(), in.work.begin());
    RTCBVH bvh = rtcNewBVH(d.device);
    RTCBuildArguments args = rtcDefaultBuildArguments();
    args.buildQuality = RTC_BUILD_QUALITY_MEDIUM;
    args.buildFlags = RTC_BUILD_FLAG_NONE;
    args.maxBranchingFactor = 2;
    args.maxDepth = max_depth;
    args.sahBlockSize = 1;
    args.minLeafSize = 1;
    args.maxLeafSize = max_leaf;
    args.traversalCost = 1.0f;
    args.intersectionCost = 1.0f;
    args.bvh = bvh;
    args.primitives = in.work.data();
    args.primitiveCount = in.work.size();
    args.primitiveArrayCapacity = in.work.size();
    args.createNode = &create_node;
    args.setNodeChildren = &set_children;
    args.setNodeBounds = &set_bounds;
    args.createLeaf = &create_leaf;
    args.splitPrimitive = nullptr;
    args.buildProgress = nullptr;
    args.userPtr = nullptr;

    const auto t0 = Clock::now();
    void* root = rtcBuildBVH(&args);
    const auto t1 = Clock::now();

    try {
        d.check("rtcBuildBVH");
        if (!root) throw Error("Embree rtcBuildBVH returned no tree");
        if (tree) {
            // The root's box: the union of its children's (as Embree gave
            // them) or, for a leaf root, of all primitives.
            const auto* r = static_cast<const TreeNode*>(root);
            Box root_box = in.bounds;
            if (!r->leaf) {
                const auto* inner = static_cast<const InnerNode*>(r);
                root_box = to_box(inner->bounds[0]);
                root_box.extend(to_box(inner->bounds[1]));
            }
            *tree = convert(r, root_box, in.triangles);
        }
    } catch (...) {
        rtcReleaseBVH(bvh);
        throw;
    }
    rtcReleaseBVH(bvh);
    return ms_between(t0, t1);
}

}  // namespace canopy::embree
