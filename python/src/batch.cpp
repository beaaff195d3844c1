// voxfmt.BatchScene's compiled half: every environment of a batch on CPU threads for NumPy arrays (runtime::BatchScene,
// the runtime's query), on a CUDA device (gpu::Scene, the query core's environment: the same pruning and lookups)
// for CUDA arrays where the package was built with CUDA. Both answer with the same arrays.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <cstdint>
#include <exception>
#include <string>
#include <type_traits>
#include <vector>

#include "common.h"
#include "traversal/eigen.h"

#if defined(VOXFMT_WITH_CUDA)
#include "voxfmt/gpu/batch.h"
#endif

namespace voxfmt::python {

namespace {

using namespace nb::literals;
namespace core = runtime::core;

// A scene's objects and pairs, checked: BAD_OPTION for an empty scene or a pair naming a Body it does not have.
runtime::BatchScene scene_of(const std::vector<const Body*>& bodies,
                             const std::vector<std::pair<int64_t, int64_t>>& pairs) {
  if (bodies.empty()) fail(IssueCode::BadOption, "a batch scene needs at least one Body");
  if (pairs.empty()) fail(IssueCode::BadOption, "a batch scene needs at least one pair (a, b)");
  std::vector<std::shared_ptr<const runtime::CollisionObject>> objects;
  for (const Body* b : bodies) objects.push_back(b->object);
  std::vector<runtime::BatchScene::Pair> checked;
  for (const auto& [a, b] : pairs) {
    if (a < 0 || b < 0 || size_t(a) >= bodies.size() || size_t(b) >= bodies.size())
      fail(IssueCode::BadOption,
           "pair (" + std::to_string(a) + ", " + std::to_string(b) + ") names a Body the scene does not have");
    checked.push_back({uint32_t(a), uint32_t(b)});
  }
  Result<runtime::BatchScene> scene = runtime::BatchScene::create(std::move(objects), std::move(checked));
  if (!scene) throw CodedError(scene.error());
  return std::move(scene.value());
}

template <class T, class... Dims>
using CpuArray = nb::ndarray<T, nb::device::cpu, nb::c_contig, Dims...>;

// The CPU path: runtime::BatchScene on `threads` workers, the GIL released.
nb::dict batch_cpu(const std::vector<const Body*>& bodies, const std::vector<std::pair<int64_t, int64_t>>& pairs,
                   nb::handle poses_a, nb::handle poses_b, nb::handle pair_index, double proximity, double stiffness,
                   int64_t max_contacts, std::optional<int64_t> threads, const std::string& interpolation) {
  if (max_contacts < 0 || max_contacts > (int64_t(1) << 24))
    fail(IssueCode::BadOption, "max_contacts must be in 0..2^24");
  if (threads && *threads < 1) fail(IssueCode::BadOption, "threads must be >= 1 (or None: every core)");
  const runtime::BatchScene scene = scene_of(bodies, pairs);
  std::optional<CpuArray<const int32_t, nb::ndim<1>>> pair;
  if (!pair_index.is_none()) {
    pair.emplace();
    if (!nb::try_cast(pair_index, *pair, false))
      fail(IssueCode::BadOption, "pair_index: expected a C-contiguous int32 array of shape (E,)");
  }
  // float32 or float64 poses, as given (a GPU batch takes float32: the same values here give the same results).
  CpuArray<const float, nb::shape<-1, 4, 4>> a32, b32;
  CpuArray<const double, nb::shape<-1, 4, 4>> a64, b64;
  const bool f32 = nb::try_cast(poses_a, a32, false) && nb::try_cast(poses_b, b32, false);
  const bool f64 = !f32 && nb::try_cast(poses_a, a64, false) && nb::try_cast(poses_b, b64, false);
  if (!f32 && !f64)
    fail(IssueCode::BadOption,
         "poses_a and poses_b: expected C-contiguous (E, 4, 4) arrays of one dtype, float32 or float64");
  const size_t envs = f32 ? a32.shape(0) : a64.shape(0);
  if ((f32 ? b32.shape(0) : b64.shape(0)) != envs)
    fail(IssueCode::BadOption, "poses_a and poses_b hold different numbers of environments");
  if (pair && pair->shape(0) != envs) fail(IssueCode::BadOption, "pair_index must hold one pair per environment");
  runtime::BatchEnvironments in;
  in.count = envs;
  in.poses_a = f32 ? a32.data() : nullptr;
  in.poses_b = f32 ? b32.data() : nullptr;
  in.poses_a_f64 = f64 ? a64.data() : nullptr;
  in.poses_b_f64 = f64 ? b64.data() : nullptr;
  in.pair = pair ? pair->data() : nullptr;
  in.proximity = proximity;
  in.stiffness = stiffness;
  in.interpolation = interpolation_of(interpolation);
  const size_t k = size_t(max_contacts);
  // Their memory was judged by the caller (voxfmt.BatchScene.contacts, with the poses' copies it makes).
  OutArray<int32_t> count({envs}), overflow({envs}), error({envs});
  OutArray<float> max_depth({envs}), force({envs, 3}), torque({envs, 3});
  OutArray<float> points({envs, k, 3}), normals({envs, k, 3}), depths({envs, k});
  OutArray<int32_t> index({envs, k});
  OutArray<uint8_t> of_b({envs, k});
  const runtime::BatchOutputs out{count.data,  max_depth.data, force.data,   torque.data, overflow.data, error.data,
                                  uint32_t(k), points.data,    normals.data, depths.data, index.data,    of_b.data};
  Status done = Status::success();
  SignalCheck interrupted;
  {
    nb::gil_scoped_release release;
    done = scene.contacts(in, out, threads ? unsigned(*threads) : 0u,
                          [&](const runtime::BatchScene::Visit&) { interrupted(); });
  }
  if (!done) throw CodedError(done.error());
  nb::dict d;
  d["count"] = count.array;
  d["max_depth"] = max_depth.array;
  d["force"] = force.array;
  d["torque"] = torque.array;
  d["overflow"] = overflow.array;
  d["error"] = error.array;
  if (k > 0) {
    d["points"] = points.array;
    d["normals"] = normals.array;
    d["depths"] = depths.array;
    d["point_index"] = index.array;
    d["point_of_b"] = of_b.array;
  }
  return d;
}

#if defined(VOXFMT_WITH_CUDA)
template <class T>
T* pointer(uintptr_t address) {
  return reinterpret_cast<T*>(address);
}

// Assets on the device, uploaded once; a call queues one kernel on the caller's stream and returns.
struct DeviceScene {
  std::shared_ptr<gpu::Scene> scene;
  std::vector<std::shared_ptr<const runtime::CollisionObject>> keep;

  DeviceScene(const std::vector<const Body*>& bodies, const std::vector<std::pair<int64_t, int64_t>>& pairs) {
    (void)scene_of(bodies, pairs);  // the same checks as the CPU path
    std::vector<gpu::Scene::Pair> p;
    for (const auto& [a, b] : pairs) p.push_back({uint32_t(a), uint32_t(b)});
    for (const Body* b : bodies) keep.push_back(b->object);
    Result<std::shared_ptr<gpu::Scene>> uploaded = gpu::Scene::upload(keep, p);
    if (!uploaded) throw CodedError(uploaded.error());
    scene = uploaded.value();
  }

  // Device pointers, as the arrays' __cuda_array_interface__ gives them: batch.py has checked every array's dtype,
  // shape, layout and device there (nanobind reads DLPack, which arrays that only show that interface lack).
  void run(size_t envs, uintptr_t poses_a, uintptr_t poses_b, uintptr_t pair, double proximity, double stiffness,
           uintptr_t count, uintptr_t max_depth, uintptr_t force, uintptr_t torque, uintptr_t overflow, uintptr_t error,
           int64_t max_contacts, uintptr_t points, uintptr_t normals, uintptr_t depths, uintptr_t index, uintptr_t of_b,
           uintptr_t stream) const {
    if (max_contacts < 0 || max_contacts > (int64_t(1) << 24))
      fail(IssueCode::BadOption, "max_contacts must be in 0..2^24");
    if (envs > 0 && (!poses_a || !poses_b || !count || !max_depth || !force || !torque || !overflow || !error))
      fail(IssueCode::BadOption, "a batch needs both poses and every per-environment output");
    if (envs > 0 && max_contacts > 0 && (!points || !normals || !depths || !index || !of_b))
      fail(IssueCode::BadOption, "max_contacts > 0 needs every contact output");
    gpu::Environments in;
    in.count = envs;
    in.poses_a = pointer<const float>(poses_a);
    in.poses_b = pointer<const float>(poses_b);
    in.pair = pointer<const int32_t>(pair);
    in.proximity = proximity;
    in.stiffness = stiffness;
    gpu::Outputs out;
    out.count = pointer<int32_t>(count);
    out.max_depth = pointer<float>(max_depth);
    out.force = pointer<float>(force);
    out.torque = pointer<float>(torque);
    out.overflow = pointer<int32_t>(overflow);
    out.error = pointer<int32_t>(error);
    out.max_contacts = uint32_t(max_contacts);
    if (max_contacts > 0) {
      out.points = pointer<float>(points);
      out.normals = pointer<float>(normals);
      out.depths = pointer<float>(depths);
      out.point_index = pointer<int32_t>(index);
      out.point_of_b = pointer<uint8_t>(of_b);
    }
    const Status launched = scene->contacts(in, out, reinterpret_cast<void*>(stream));
    if (!launched) throw CodedError(launched.error());
  }
};
#endif

// A Body's arrays exactly as the device reads them (core::Body; the value bricks with an apron, as gpu::Scene
// uploads them): for a runner that has only the core and CUDA (scripts/gpu-check.sh on a machine without our
// libraries) to rebuild the same Body there.
nb::dict export_core(const Body& body) {
  const core::Body b = core::body_of(*body.object);
  nb::dict d;
  auto copy = [](const auto* data, size_t count, std::initializer_list<size_t> shape) {
    using T = std::remove_cv_t<std::remove_pointer_t<decltype(data)>>;
    OutArray<T> a(shape);
    std::copy(data, data + count, a.data);
    return a.array;
  };
  const runtime::SparseVoxelmap& map = body.object->voxelmap();
  // The value bricks with their apron, as gpu::Scene uploads them.
  const std::vector<int16_t> apron = core::apron_codes(b.field, map.value_brick_count());
  size_t lattice = 1;
  for (int a = 0; a < 3; ++a) lattice *= size_t(b.field.lattice_dims[a]);
  d["bricks"] = copy(b.field.bricks, map.brick_count(), {map.brick_count()});
  d["codes"] = copy(apron.data(), apron.size(), {apron.size()});
  d["lattice"] = copy(b.field.lattice, lattice, {lattice});
  const float* field_numbers[] = {&b.field.decode_step[0], &b.field.decode_step[1],  &b.field.stored_slack,
                                  &b.field.estimate_slack, &b.field.estimate_offset, &b.field.estimate_shrink,
                                  &b.field.band_edge,      &b.field.lattice_step,    &b.field.cover_max.x,
                                  &b.field.cover_max.y,    &b.field.cover_max.z,     &b.field.object_min.x,
                                  &b.field.object_min.y,   &b.field.object_min.z,    &b.field.object_max.x,
                                  &b.field.object_max.y,   &b.field.object_max.z,    &b.field.value_estimate_slack};
  OutArray<float> numbers({std::size(field_numbers)});
  for (size_t i = 0; i < std::size(field_numbers); ++i) numbers.data[i] = *field_numbers[i];
  d["field_floats"] = numbers.array;
  OutArray<int32_t> dims({9});
  for (int a = 0; a < 3; ++a) {
    dims.data[a] = b.field.dims[a];
    dims.data[3 + a] = b.field.brick_dims[a];
    dims.data[6 + a] = b.field.lattice_dims[a];
  }
  d["field_dims"] = dims.array;
  const size_t n = b.shell.count;
  d["nodes"] = copy(reinterpret_cast<const uint8_t*>(b.shell.nodes), n * sizeof(core::Node), {n * sizeof(core::Node)});
  d["points"] = copy(&b.shell.points[0].x, 3 * n, {n, 3});
  d["normals"] = copy(&b.shell.normals[0].x, 3 * n, {n, 3});
  OutArray<double> doubles({8});
  for (int a = 0; a < 3; ++a) {
    doubles.data[a] = b.origin[a];
    doubles.data[4 + a] = b.center_of_mass[a];
  }
  doubles.data[3] = b.voxel_size;
  doubles.data[7] = b.bounding_radius;
  d["body_doubles"] = doubles.array;
  // The points and centres are from this asset-frame point (PointTree::anchor: zero unless the shell lies far
  // from its origin); a runner that places them must add it, or refuse a non-zero one.
  OutArray<double> anchor({3});
  for (int a = 0; a < 3; ++a) anchor.data[a] = b.shell.anchor[a];
  d["anchor"] = anchor.array;
  d["levels"] = b.shell.levels;
  return d;
}

}  // namespace

void bind_batch(nb::module_& m) {
  m.def("_export_core", &export_core, "body"_a);
  m.def("_batch_cpu", &batch_cpu, "bodies"_a, "pairs"_a, "poses_a"_a, "poses_b"_a, "pair_index"_a.none(), "proximity"_a,
        "stiffness"_a, "max_contacts"_a, "threads"_a.none(), "interpolation"_a = "trilinear");
#if defined(VOXFMT_WITH_CUDA)
  m.def("_cuda_status", [] {
    std::string why;
    const bool ok = gpu::available(&why);
    return std::make_pair(ok, ok ? gpu::device_name() : why);
  });
  // (device, "") or (-1, why): the device of an address, the current device, and making one current.
  m.def("_cuda_device_of", [](uintptr_t address) {
    std::string why;
    const int device = gpu::device_of(reinterpret_cast<const void*>(address), &why);
    return std::make_pair(device, why);
  });
  m.def("_cuda_current_device", [] {
    std::string why;
    const int device = gpu::current_device(&why);
    return std::make_pair(device, why);
  });
  m.def("_cuda_make_current", [](int device) {
    std::string why;
    gpu::make_current(device, &why);
    return why;
  });
  m.def("_cuda_synchronize_stream", [](uintptr_t stream) {
    std::string why;
    {
      nb::gil_scoped_release release;
      gpu::synchronize_stream(stream, &why);
    }
    return why;
  });
  nb::class_<DeviceScene>(m, "_DeviceScene")
      .def(nb::init<const std::vector<const Body*>&, const std::vector<std::pair<int64_t, int64_t>>&>(), "bodies"_a,
           "pairs"_a)
      .def_prop_ro("device_bytes", [](const DeviceScene& s) { return s.scene->device_bytes(); })
      .def_prop_ro("frontier_bytes", [](const DeviceScene& s) { return s.scene->frontier_bytes(); })
      .def("asset_device_bytes", [](const DeviceScene& s, size_t i) { return s.scene->asset_device_bytes(i); })
      .def("run", &DeviceScene::run, "envs"_a, "poses_a"_a, "poses_b"_a, "pair_index"_a, "proximity"_a, "stiffness"_a,
           "count"_a, "max_depth"_a, "force"_a, "torque"_a, "overflow"_a, "error"_a, "max_contacts"_a, "points"_a,
           "normals"_a, "depths"_a, "point_index"_a, "point_of_b"_a, "stream"_a);
#else
  m.def("_cuda_status", [] { return std::make_pair(false, std::string("this build of voxfmt has no CUDA support")); });
#endif
}

}  // namespace voxfmt::python
