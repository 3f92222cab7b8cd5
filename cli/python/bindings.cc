// The Python module `reflcap` (pybind11): reflcap's files and algorithms as NumPy arrays.
//
//   read_capture(path)                  capture.json as a dict (cameras, lights, images, mesh)
//   load_image(capture, index)          a capture's photograph, H x W x 3 float32
//   read_samples(store) / read_chunk    a sample store (reflcap-samples/1) as arrays
//   read_fit(fit)                       a FIT folder: params, sigma, status maps, fit_report.json
//   param_names(lobes)                  the parameter-vector layout every function here uses
//   eval_brdf(params, wi, wo)           brdf::EvalRgb (engine/brdf/lafortune.h), per sample
//   fit_samples(wi, wo, value, ...)     fit::Fitter (engine/fit/fitter.h) on NumPy samples
//   render_view(capture, fit, index)    the CPU reference renderer (render/reference)
//
// A texel's parameter vector is the parameter maps' channel list in BrdfChannelNames order
// (engine/texel/brdf_maps.h): rho_d.{R,G,B}, then per lobe k and field Cx, Cy, Cz, n the three
// channels R, G, B — 3 + 12 K floats. Directions are in the texel's tangent frame (z = shading
// normal), both pointing away from the surface.
//
// Errors: a failed Status becomes a Python exception carrying its message (which names the file
// and field): NotFound -> FileNotFoundError; InvalidArgument, DataLoss, FailedPrecondition ->
// ValueError; Unavailable, Internal -> RuntimeError. Long work (reading a store, fitting,
// rendering) runs without the GIL.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numeric>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "engine/brdf/lafortune.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"
#include "engine/fit/model.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/texel/brdf_maps.h"
#include "engine/texel/sample_store.h"
#include "engine/texel/samples.h"
#include "render/reference/render_capture.h"

namespace py = pybind11;

namespace reflcap::python {
namespace {

using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using UintArray = py::array_t<uint32_t, py::array::c_style | py::array::forcecast>;

[[noreturn]] void ThrowStatus(const Status& status) {
  PyObject* type = PyExc_RuntimeError;
  switch (status.code()) {
    case StatusCode::kNotFound:
      type = PyExc_FileNotFoundError;
      break;
    case StatusCode::kInvalidArgument:
    case StatusCode::kDataLoss:
    case StatusCode::kFailedPrecondition:
      type = PyExc_ValueError;
      break;
    default:
      break;
  }
  PyErr_SetString(type, status.message().c_str());
  throw py::error_already_set();
}

void Check(const Status& status) {
  if (!status.ok()) ThrowStatus(status);
}

template <typename T>
T Take(StatusOr<T> result) {
  if (!result.ok()) ThrowStatus(result.status());
  return std::move(result).value();
}

// A str or os.PathLike argument as a path.
std::filesystem::path ToPath(const py::object& path) {
  return std::filesystem::path(
      py::str(py::module_::import("os").attr("fspath")(path)).cast<std::string>());
}

template <typename T>
py::array_t<T> NewArray(const std::vector<py::ssize_t>& shape) {
  return py::array_t<T>(shape);
}

py::array_t<double> Vec3(const Vec3d& v) {
  py::array_t<double> out({py::ssize_t(3)});
  for (int i = 0; i < 3; ++i) out.mutable_at(i) = v[i];
  return out;
}

py::array_t<double> Mat3(const Mat3d& m) {
  py::array_t<double> out({py::ssize_t(3), py::ssize_t(3)});
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out.mutable_at(r, c) = m(r, c);
  return out;
}

// An Image as an H x W x C float32 array (a copy).
py::array_t<float> ImageArray(const Image& image) {
  py::array_t<float> out({py::ssize_t(image.height), py::ssize_t(image.width),
                          py::ssize_t(image.channels)});
  std::memcpy(out.mutable_data(), image.data.data(), image.data.size() * sizeof(float));
  return out;
}

// ---- Captures ------------------------------------------------------------------------------

// The capture.json path of a read_capture() dict, a capture folder or a capture.json path.
std::filesystem::path CapturePath(const py::object& capture) {
  std::filesystem::path path =
      py::isinstance<py::dict>(capture) ? ToPath(capture.cast<py::dict>()["path"]) : ToPath(capture);
  if (std::filesystem::is_directory(path)) path /= "capture.json";
  return path;
}

py::dict CaptureDict(const Capture& capture) {
  py::dict d;
  d["path"] = capture.json_path.string();
  d["folder"] = capture.Folder().string();
  d["minor_version"] = capture.minor_version;
  if (capture.mesh.empty()) {
    d["mesh"] = py::none();
  } else {
    d["mesh"] = capture.Resolve(capture.mesh).string();
  }
  if (capture.normal_map) {
    py::dict nm;
    nm["camera"] = capture.normal_map->camera;
    nm["normals"] = capture.Resolve(capture.normal_map->normals).string();
    nm["mask"] = capture.Resolve(capture.normal_map->mask).string();
    d["normal_map"] = nm;
  } else {
    d["normal_map"] = py::none();
  }
  py::list cameras;
  for (const Camera& cam : capture.cameras) {
    py::dict c;
    c["id"] = cam.id;
    c["model"] = cam.model == CameraModel::kPinhole ? "pinhole" : "orthographic";
    c["width"] = cam.width;
    c["height"] = cam.height;
    c["K"] = Mat3(cam.K);
    c["dist"] = std::vector<double>(cam.dist.begin(), cam.dist.end());
    c["R"] = Mat3(cam.cam_from_world.rotation);  // cam_from_world: p_cam = R p_world + t
    c["t"] = Vec3(cam.cam_from_world.translation);
    c["pixel_size_m"] = cam.pixel_size_m;
    c["pixel_filter"] = PixelFilterName(cam.pixel_filter);
    cameras.append(c);
  }
  d["cameras"] = cameras;
  py::list lights;
  for (const Light& light : capture.lights) {
    py::dict l;
    l["id"] = light.id;
    l["type"] = light.type == LightType::kPoint ? "point" : "directional";
    l["position"] = Vec3(light.position);
    l["direction"] = Vec3(light.direction);
    l["intensity"] = Vec3(light.intensity);
    lights.append(l);
  }
  d["lights"] = lights;
  if (capture.turntable) {
    py::dict t;
    t["axis"] = Vec3(capture.turntable->axis);
    t["point"] = Vec3(capture.turntable->point);
    d["turntable"] = t;
  } else {
    d["turntable"] = py::none();
  }
  py::list images;
  for (const CaptureImage& image : capture.images) {
    py::dict i;
    i["file"] = image.file;
    i["camera"] = image.camera;
    i["light"] = image.light;
    i["turntable_deg"] = image.turntable_deg;
    i["exposure_s"] = image.exposure_s;
    i["split"] = SplitName(image.split);
    i["saturation"] = image.saturation;
    i["variance"] = image.variance.empty() ? py::object(py::none()) : py::str(image.variance);
    images.append(i);
  }
  d["images"] = images;
  d["ground_truth"] = capture.ground_truth_json.empty()
                          ? py::object(py::none())
                          : py::module_::import("json").attr("loads")(capture.ground_truth_json);
  return d;
}

py::dict ReadCaptureDict(const py::object& path) {
  return CaptureDict(Take(ReadCapture(CapturePath(path))));
}

void CheckImageIndex(const Capture& capture, long index) {
  if (index < 0 || size_t(index) >= capture.images.size()) {
    ThrowStatus(InvalidArgumentError(capture.json_path.string(), ": image index ", index,
                                     " out of range (", capture.images.size(), " images)"));
  }
}

py::array_t<float> LoadImage(const py::object& capture_arg, long index) {
  const Capture capture = Take(ReadCapture(CapturePath(capture_arg)));
  CheckImageIndex(capture, index);
  StatusOr<Image> read = InternalError("unread");
  {
    py::gil_scoped_release release;
    read = ReadImageRgb(capture.Resolve(capture.images[index].file));
  }
  if (!read.ok()) {
    ThrowStatus(read.status().WithContext(StrCat(capture.json_path.string(), ": images[", index,
                                                 "].file")));
  }
  const Image image = std::move(read).value();
  return ImageArray(image);
}

// ---- Sample stores -------------------------------------------------------------------------

py::dict StoreInfoDict(const SampleStoreInfo& info) {
  py::dict d;
  d["texels"] = info.texels;
  d["chunk_texels"] = info.chunk_texels;
  d["chunks"] = info.chunks;
  d["sample_count"] = info.samples;
  d["capture"] = info.capture;
  d["split"] = info.split;
  d["min_cos"] = info.min_cos;
  d["images"] = info.images;
  d["geometry"] = info.geometry;
  py::dict atlas;
  atlas["width"] = info.atlas_width;
  atlas["height"] = info.atlas_height;
  py::array_t<uint32_t> pixels({py::ssize_t(info.pixel_of_texel.size())});
  std::copy(info.pixel_of_texel.begin(), info.pixel_of_texel.end(), pixels.mutable_data());
  atlas["pixel_of_texel"] = pixels;
  d["atlas"] = atlas;
  return d;
}

// Samples of `chunks` (consecutive, in order) as arrays into `d`: texel (global index), wi, wo,
// value, weight, image per sample; offsets (CSR over the chunks' texels, from first_texel).
void PutSamples(const std::vector<TexelSampleChunk>& chunks, py::dict& d) {
  size_t n = 0, texels = 0;
  for (const TexelSampleChunk& c : chunks) {
    n += c.samples.size();
    texels += c.texel_count;
  }
  const py::ssize_t ns = py::ssize_t(n);
  auto texel = NewArray<uint32_t>({ns});
  auto wi = NewArray<float>({ns, 3});
  auto wo = NewArray<float>({ns, 3});
  auto value = NewArray<float>({ns, 3});
  auto weight = NewArray<float>({ns, 3});
  auto image = NewArray<uint32_t>({ns});
  auto offsets = NewArray<uint64_t>({py::ssize_t(texels + 1)});
  uint32_t* t_out = texel.mutable_data();
  float* wi_out = wi.mutable_data();
  float* wo_out = wo.mutable_data();
  float* v_out = value.mutable_data();
  float* w_out = weight.mutable_data();
  uint32_t* i_out = image.mutable_data();
  uint64_t* o_out = offsets.mutable_data();
  size_t s = 0, row = 0;
  o_out[0] = 0;
  for (const TexelSampleChunk& c : chunks) {
    for (uint32_t i = 0; i < c.texel_count; ++i) {
      for (uint64_t k = c.offsets[i]; k < c.offsets[i + 1]; ++k, ++s) {
        const BrdfSample& b = c.samples[k];
        t_out[s] = c.first_texel + i;
        std::copy(b.wi, b.wi + 3, wi_out + 3 * s);
        std::copy(b.wo, b.wo + 3, wo_out + 3 * s);
        std::copy(b.value, b.value + 3, v_out + 3 * s);
        std::copy(b.weight, b.weight + 3, w_out + 3 * s);
        i_out[s] = b.image;
      }
      o_out[++row] = s;
    }
  }
  d["texel"] = texel;
  d["wi"] = wi;
  d["wo"] = wo;
  d["value"] = value;
  d["weight"] = weight;
  d["image"] = image;
  d["offsets"] = offsets;
}

std::unique_ptr<SampleStoreReader> OpenStore(const py::object& store_dir) {
  return Take(SampleStoreReader::Open(ToPath(store_dir)));
}

std::vector<TexelSampleChunk> ReadChunks(const SampleStoreReader& store, uint32_t first,
                                         uint32_t count) {
  std::vector<TexelSampleChunk> chunks;
  Status status;
  {
    py::gil_scoped_release release;
    for (uint32_t i = first; i < first + count && status.ok(); ++i) {
      StatusOr<TexelSampleChunk> chunk = store.ReadChunk(i);
      if (chunk.ok()) {
        chunks.push_back(std::move(chunk).value());
      } else {
        status = chunk.status();
      }
    }
  }
  Check(status);
  return chunks;
}

py::dict ReadSamples(const py::object& store_dir) {
  std::unique_ptr<SampleStoreReader> store = OpenStore(store_dir);
  py::dict d = StoreInfoDict(store->info());
  PutSamples(ReadChunks(*store, 0, store->info().chunks), d);
  return d;
}

py::dict ReadChunk(const py::object& store_dir, long index) {
  std::unique_ptr<SampleStoreReader> store = OpenStore(store_dir);
  if (index < 0 || index >= long(store->info().chunks)) {
    ThrowStatus(InvalidArgumentError(ToPath(store_dir).string(), ": chunk index ", index,
                                     " out of range (", store->info().chunks, " chunks)"));
  }
  std::vector<TexelSampleChunk> chunks = ReadChunks(*store, uint32_t(index), 1);
  py::dict d;
  d["index"] = index;
  d["first_texel"] = chunks[0].first_texel;
  d["texel_count"] = chunks[0].texel_count;
  PutSamples(chunks, d);
  return d;
}

py::dict ReadStoreInfo(const py::object& store_dir) {
  return StoreInfoDict(OpenStore(store_dir)->info());
}

// ---- Fits ----------------------------------------------------------------------------------

// The lobe count of a parameter vector of `size` floats; ValueError unless 3 + 12 K, K <= 3.
int LobesOfVector(py::ssize_t size) {
  if (size < 3 || (size - 3) % 12 != 0 || (size - 3) / 12 > brdf::kMaxLobes) {
    ThrowStatus(InvalidArgumentError("params: a parameter vector has 3 + 12 K floats (K = 0..",
                                     brdf::kMaxLobes, " lobes; see param_names), got ", size));
  }
  return int((size - 3) / 12);
}

// Channels `names` of `image` as an H x W x names.size() array; `file` names a missing one.
py::array_t<float> SelectChannels(const Image& image, const std::vector<std::string>& file_names,
                                  const std::vector<std::string>& names, const std::string& file) {
  std::vector<int> source;
  for (const std::string& name : names) {
    auto it = std::find(file_names.begin(), file_names.end(), name);
    if (it == file_names.end()) {
      ThrowStatus(InvalidArgumentError(file, ": channel ", name, ": missing"));
    }
    source.push_back(int(it - file_names.begin()));
  }
  const py::ssize_t h = image.height, w = image.width, c = py::ssize_t(names.size());
  py::array_t<float> out({h, w, c});
  float* dst = out.mutable_data();
  for (size_t p = 0; p < image.PixelCount(); ++p) {
    for (py::ssize_t k = 0; k < c; ++k) dst[p * c + k] = image.data[p * image.channels + source[k]];
  }
  return out;
}

int LobesOfChannels(const std::vector<std::string>& names) {
  int lobes = 0;
  while (lobes < brdf::kMaxLobes &&
         std::find(names.begin(), names.end(), StrCat("lobe", lobes, ".n.R")) != names.end()) {
    ++lobes;
  }
  return lobes;
}

py::dict ReadFit(const py::object& fit_arg) {
  std::filesystem::path fit = ToPath(fit_arg);
  std::filesystem::path folder = fit;
  std::filesystem::path params_path = fit / "params.exr";
  if (!std::filesystem::is_directory(fit)) {
    params_path = fit;
    folder = fit.parent_path();
  }
  std::vector<std::string> names;
  Image params = Take(ReadExrChannels(params_path, &names));
  const int lobes = LobesOfChannels(names);
  const std::vector<std::string> layout = BrdfChannelNames(lobes);
  py::dict d;
  d["path"] = folder.string();
  d["lobes"] = lobes;
  d["width"] = params.width;
  d["height"] = params.height;
  d["channels"] = layout;
  d["params"] = SelectChannels(params, names, layout, params_path.string());
  const std::filesystem::path sigma_path = folder / "sigma.exr";
  if (std::filesystem::exists(sigma_path)) {
    std::vector<std::string> sigma_names;
    Image sigma = Take(ReadExrChannels(sigma_path, &sigma_names));
    d["sigma"] = SelectChannels(sigma, sigma_names, layout, sigma_path.string());
  } else {
    d["sigma"] = py::none();
  }
  const std::filesystem::path status_path = folder / "status.exr";
  py::dict status;
  if (std::filesystem::exists(status_path)) {
    std::vector<std::string> status_names;
    Image maps = Take(ReadExrChannels(status_path, &status_names));
    for (size_t c = 0; c < status_names.size(); ++c) {
      // Every status channel but the cost holds an integer code, exact in float below 2^24.
      const bool is_float = status_names[c] == "cost";
      py::array channel = is_float ? py::array(py::array_t<float>({py::ssize_t(maps.height),
                                                                   py::ssize_t(maps.width)}))
                                   : py::array(py::array_t<int32_t>({py::ssize_t(maps.height),
                                                                     py::ssize_t(maps.width)}));
      for (size_t p = 0; p < maps.PixelCount(); ++p) {
        const float v = maps.data[p * maps.channels + c];
        if (is_float) {
          static_cast<float*>(channel.mutable_data())[p] = v;
        } else {
          static_cast<int32_t*>(channel.mutable_data())[p] = int32_t(v);
        }
      }
      status[py::str(status_names[c])] = channel;
    }
  }
  d["status"] = status;
  std::vector<std::string> status_names;
  for (int s = 0; s < fit::kFitStatusCount; ++s) {
    status_names.push_back(fit::FitStatusName(fit::FitStatus(s)));
  }
  d["status_names"] = status_names;
  const std::filesystem::path report_path = folder / "fit_report.json";
  if (std::filesystem::exists(report_path)) {
    std::ifstream in(report_path);
    std::stringstream text;
    text << in.rdbuf();
    d["report"] = py::module_::import("json").attr("loads")(text.str());
  } else {
    d["report"] = py::none();
  }
  return d;
}

// One texel's parameter vector (BrdfChannelNames layout) as BrdfParams.
brdf::BrdfParams ParamsFromVector(const float* v, int lobes) {
  brdf::BrdfParams p;
  p.num_lobes = lobes;
  for (int c = 0; c < 3; ++c) p.rho_d[c] = v[c];
  for (int k = 0; k < lobes; ++k) {
    for (int c = 0; c < 3; ++c) {
      brdf::LobeParams& lobe = p.lobes[k][c];
      const float* f = v + 3 + 12 * k;
      lobe.cx = f[0 + c];
      lobe.cy = f[3 + c];
      lobe.cz = f[6 + c];
      lobe.n = f[9 + c];
    }
  }
  return p;
}

void ParamsToVector(const brdf::BrdfParams& p, int lobes, float* v) {
  for (int c = 0; c < 3; ++c) v[c] = p.rho_d[c];
  for (int k = 0; k < lobes; ++k) {
    for (int c = 0; c < 3; ++c) {
      const brdf::LobeParams& lobe = p.lobes[k][c];
      float* f = v + 3 + 12 * k;
      f[0 + c] = lobe.cx;
      f[3 + c] = lobe.cy;
      f[6 + c] = lobe.cz;
      f[9 + c] = lobe.n;
    }
  }
}

// (N, 3) view of a direction/value argument: (3,) is one row.
FloatArray Rows3(const py::object& arg, const char* name) {
  FloatArray a = FloatArray::ensure(arg);
  if (!a) throw py::error_already_set();
  if (a.ndim() == 1 && a.shape(0) == 3) {
    a = FloatArray::ensure(a.reshape({py::ssize_t(1), py::ssize_t(3)}));
  }
  if (a.ndim() != 2 || a.shape(1) != 3) {
    ThrowStatus(InvalidArgumentError(name, ": expected shape (N, 3) or (3,), got ndim ",
                                     a.ndim()));
  }
  return a;
}

py::array_t<float> EvalBrdf(const py::object& params_arg, const py::object& wi_arg,
                            const py::object& wo_arg) {
  FloatArray params = FloatArray::ensure(params_arg);
  if (!params) throw py::error_already_set();
  FloatArray wi = Rows3(wi_arg, "wi");
  FloatArray wo = Rows3(wo_arg, "wo");
  const py::ssize_t n = wi.shape(0);
  if (wo.shape(0) != n) {
    ThrowStatus(InvalidArgumentError("wo: ", wo.shape(0), " rows, wi has ", n));
  }
  if (params.ndim() != 1 && params.ndim() != 2) {
    ThrowStatus(InvalidArgumentError("params: expected shape (P,) or (N, P)"));
  }
  const bool per_sample = params.ndim() == 2;
  const py::ssize_t size = params.shape(params.ndim() - 1);
  const int lobes = LobesOfVector(size);
  if (per_sample && params.shape(0) != n) {
    ThrowStatus(InvalidArgumentError("params: ", params.shape(0), " rows, wi has ", n));
  }
  const py::ssize_t rows = per_sample ? n : 1;
  std::vector<brdf::BrdfParams> p(rows);
  for (py::ssize_t r = 0; r < rows; ++r) {
    p[r] = ParamsFromVector(params.data() + r * size, lobes);
    for (int k = 0; k < lobes; ++k) {
      for (int c = 0; c < 3; ++c) {
        const float e = p[r].lobes[k][c].n;
        // The exponent range lafortune.h evaluates in (a lobe with all C's 0 is absent: the
        // all-zero pixels of a map without texel are evaluated as 0).
        const brdf::LobeParams& l = p[r].lobes[k][c];
        const bool absent = l.cx == 0 && l.cy == 0 && l.cz == 0;
        if (!(e >= brdf::kMinLobeExponent && e <= brdf::kMaxExponent) && !absent) {
          ThrowStatus(InvalidArgumentError("params: row ", r, ": lobe", k, ".n.", "RGB"[c], " = ",
                                           e, " outside [", brdf::kMinLobeExponent, ", ",
                                           brdf::kMaxExponent, "]"));
        }
        if (absent) p[r].lobes[k][c].n = 1;
      }
    }
  }
  py::array_t<float> out({n, py::ssize_t(3)});
  float* dst = out.mutable_data();
  const float* a = wi.data();
  const float* b = wo.data();
  for (py::ssize_t i = 0; i < n; ++i) {
    const Vec3f f = brdf::EvalRgb(p[per_sample ? i : 0], Vec3f(a[3 * i], a[3 * i + 1], a[3 * i + 2]),
                                  Vec3f(b[3 * i], b[3 * i + 1], b[3 * i + 2]));
    for (int c = 0; c < 3; ++c) dst[3 * i + c] = f[c];
  }
  return out;
}

py::dict FitSamples(const py::object& wi_arg, const py::object& wo_arg,
                    const py::object& value_arg, const py::object& weight_arg,
                    const py::object& texel_arg, const std::string& backend_name, int lobes,
                    const std::string& lobe_model, const std::string& init,
                    const std::string& loss, double loss_scale, int max_iterations,
                    double highlight_cone_deg, int min_samples, bool channel_retry, int threads,
                    const std::string& device) {
  FloatArray wi = Rows3(wi_arg, "wi");
  FloatArray wo = Rows3(wo_arg, "wo");
  FloatArray value = Rows3(value_arg, "value");
  const py::ssize_t n = wi.shape(0);
  const bool has_weight = !weight_arg.is_none();
  FloatArray weight = has_weight ? Rows3(weight_arg, "weight") : value;
  if (wo.shape(0) != n || value.shape(0) != n || weight.shape(0) != n) {
    ThrowStatus(InvalidArgumentError("wi, wo, value, weight: must have the same number of rows (",
                                     n, ")"));
  }
  std::vector<uint32_t> texel(n, 0);
  if (!texel_arg.is_none()) {
    UintArray t = UintArray::ensure(texel_arg);
    if (!t) throw py::error_already_set();
    if (t.ndim() != 1 || t.shape(0) != n) {
      ThrowStatus(InvalidArgumentError("texel: expected shape (", n, ",)"));
    }
    std::copy(t.data(), t.data() + n, texel.begin());
  }

  fit::FitOptions options;
  options.lobes = lobes;
  options.lobe_model = Take(fit::ParseLobeModel(lobe_model));
  options.init = Take(fit::ParseInitScheme(init));
  options.loss = Take(fit::ParseLossKind(loss));
  options.loss_scale = loss_scale;
  options.max_iterations = max_iterations;
  options.highlight_cone_deg = highlight_cone_deg;
  options.min_samples = min_samples;
  options.channel_retry = channel_retry;
  options.threads = threads;
  Check(options.Validate());
  const fit::Backend backend = Take(fit::ParseBackend(backend_name));

  // Texel-major chunk: texels 0 .. max(texel), samples stably grouped by texel.
  TexelSampleChunk chunk;
  const uint32_t texels = n == 0 ? 1 : *std::max_element(texel.begin(), texel.end()) + 1;
  chunk.first_texel = 0;
  chunk.texel_count = texels;
  chunk.offsets.assign(size_t(texels) + 1, 0);
  for (uint32_t t : texel) ++chunk.offsets[size_t(t) + 1];
  for (uint32_t t = 0; t < texels; ++t) chunk.offsets[t + 1] += chunk.offsets[t];
  chunk.samples.resize(n);
  std::vector<uint64_t> next(chunk.offsets.begin(), chunk.offsets.end() - 1);
  for (py::ssize_t i = 0; i < n; ++i) {
    BrdfSample& s = chunk.samples[next[texel[i]]++];
    for (int c = 0; c < 3; ++c) {
      s.wi[c] = wi.data()[3 * i + c];
      s.wo[c] = wo.data()[3 * i + c];
      s.value[c] = value.data()[3 * i + c];
      s.weight[c] = has_weight ? weight.data()[3 * i + c] : 1.0f;
    }
    s.image = 0;
  }

  std::vector<fit::TexelFit> results;
  std::string device_name;
  Status status;
  {
    py::gil_scoped_release release;
    StatusOr<std::unique_ptr<fit::Fitter>> fitter = fit::CreateFitter(backend, threads, device);
    if (fitter.ok()) {
      device_name = (*fitter)->device();
      status = (*fitter)->Fit(chunk, options, &results);
    } else {
      status = fitter.status();
    }
  }
  Check(status);

  const py::ssize_t size = 3 + 12 * lobes;
  const py::ssize_t nt = texels;
  auto params = NewArray<float>({nt, size});
  auto sigma = NewArray<float>({nt, size});
  auto status_out = NewArray<int32_t>({nt});
  auto cost = NewArray<float>({nt});
  auto iterations = NewArray<int32_t>({nt});
  auto samples = NewArray<int32_t>({nt});
  auto lambert_only = NewArray<bool>({nt});
  for (py::ssize_t t = 0; t < nt; ++t) {
    const fit::TexelFit& r = results[t];
    ParamsToVector(r.params, lobes, params.mutable_data() + t * size);
    ParamsToVector(r.sigma, lobes, sigma.mutable_data() + t * size);
    status_out.mutable_data()[t] = int32_t(r.status);
    cost.mutable_data()[t] = r.cost;
    iterations.mutable_data()[t] = r.iterations;
    samples.mutable_data()[t] = r.samples;
    lambert_only.mutable_data()[t] = r.lambert_only;
  }
  py::dict d;
  d["params"] = params;
  d["sigma"] = sigma;
  d["status"] = status_out;
  d["cost"] = cost;
  d["iterations"] = iterations;
  d["samples"] = samples;
  d["lambert_only"] = lambert_only;
  d["channels"] = BrdfChannelNames(lobes);
  std::vector<std::string> status_names;
  for (int s = 0; s < fit::kFitStatusCount; ++s) {
    status_names.push_back(fit::FitStatusName(fit::FitStatus(s)));
  }
  d["status_names"] = status_names;
  d["backend"] = fit::BackendName(backend);
  d["device"] = device_name;
  return d;
}

// ---- Rendering -----------------------------------------------------------------------------

py::object RenderView(const py::object& capture_arg, const py::object& fit_arg, long index,
                      int supersample, bool cast_shadows, bool with_mask) {
  const Capture capture = Take(ReadCapture(CapturePath(capture_arg)));
  CheckImageIndex(capture, index);
  std::filesystem::path params = ToPath(fit_arg);
  if (std::filesystem::is_directory(params)) params /= "params.exr";
  render::RenderOptions options;
  options.supersampling = supersample;
  options.cast_shadows = cast_shadows;
  Check(options.Validate());
  render::RenderResult result;
  Status status;
  {
    py::gil_scoped_release release;
    // As `reflcap render`: height-field shadows for normal-map captures with cast shadows.
    StatusOr<std::unique_ptr<render::FittedCapture>> fitted =
        render::LoadFittedCapture(capture, params, cast_shadows);
    if (fitted.ok()) {
      StatusOr<render::RenderResult> rendered =
          render::RenderCaptureImage(**fitted, size_t(index), options);
      if (rendered.ok()) {
        result = std::move(rendered).value();
      } else {
        status = rendered.status();
      }
    } else {
      status = fitted.status();
    }
  }
  Check(status);
  py::array_t<float> pixels = ImageArray(result.pixels);
  if (!with_mask) return std::move(pixels);
  py::array_t<float> mask = ImageArray(result.mask);
  return py::make_tuple(pixels, mask.reshape({py::ssize_t(result.mask.height),
                                               py::ssize_t(result.mask.width)}));
}

py::array_t<float> ReadExr(const py::object& path_arg) {
  Image image = Take(ReadExrRgb(ToPath(path_arg)));
  return ImageArray(image);
}

std::vector<std::string> ParamNames(int lobes) {
  if (lobes < 0 || lobes > brdf::kMaxLobes) {
    ThrowStatus(InvalidArgumentError("lobes: 0..", brdf::kMaxLobes, ", got ", lobes));
  }
  return BrdfChannelNames(lobes);
}

void SetLogLevel(const std::string& level) {
  const std::pair<const char*, LogLevel> levels[] = {{"debug", LogLevel::kDebug},
                                                     {"info", LogLevel::kInfo},
                                                     {"warning", LogLevel::kWarning},
                                                     {"error", LogLevel::kError}};
  for (const auto& [name, value] : levels) {
    if (level == name) return SetLogThreshold(value);
  }
  ThrowStatus(InvalidArgumentError("level: debug, info, warning or error, got ", level));
}

}  // namespace
}  // namespace reflcap::python

PYBIND11_MODULE(reflcap, m) {
  using namespace reflcap::python;
  m.doc() =
      "reflcap: per-texel BRDF capture (Lambert + Lafortune lobes). Captures, sample stores and "
      "fits as NumPy arrays, the BRDF, fitting, and the CPU reference renderer. A texel's "
      "parameter vector is laid out as param_names(lobes); directions are in the texel's "
      "tangent frame (z = shading normal), both pointing away from the surface.";
  // The library's progress messages would interleave with a notebook's output: warnings only.
  reflcap::SetLogThreshold(reflcap::LogLevel::kWarning);

  m.def("set_log_level", &SetLogLevel, py::arg("level"),
        "Sets which library messages reach stderr: 'debug', 'info', 'warning' (default), "
        "'error'.");
  m.def("read_capture", &ReadCaptureDict, py::arg("path"),
        "Reads and validates capture.json (a path to it or its folder) into a dict: path, folder, "
        "mesh (absolute path or None), normal_map, cameras (id, model, width, height, K 3x3, dist, "
        "R, t = cam_from_world, pixel_size_m, pixel_filter), lights (id, type, position, "
        "direction, intensity), turntable (axis, point or None), images (file, camera, light, "
        "turntable_deg, exposure_s, "
        "split, saturation, variance), ground_truth (dict or None).");
  m.def("load_image", &LoadImage, py::arg("capture"), py::arg("index"),
        "Photograph `index` of a capture (a read_capture dict or a path) as an H x W x 3 float32 "
        "array (EXR or PNG, linear as stored).");
  m.def("read_exr", &ReadExr, py::arg("path"),
        "An RGB OpenEXR file (e.g. a `reflcap render` output) as an H x W x 3 float32 array.");
  m.def("read_store_info", &ReadStoreInfo, py::arg("store"),
        "store.json and atlas.bin of a sample store, without its samples (as read_samples).");
  m.def("read_samples", &ReadSamples, py::arg("store"),
        "A whole sample store (small stores; read_chunk for big ones): texels, chunk_texels, "
        "chunks, sample_count, capture, split, min_cos, images, geometry, atlas {width, height, "
        "pixel_of_texel (uint32, y * width + x)}, and per sample texel (uint32), wi, wo, value, "
        "weight (N x 3 float32), image (uint32), with offsets (uint64, texels + 1: CSR).");
  m.def("read_chunk", &ReadChunk, py::arg("store"), py::arg("index"),
        "Chunk `index` of a sample store: index, first_texel, texel_count and the arrays of "
        "read_samples (texel holds global texel indices; offsets index from first_texel).");
  m.def("param_names", &ParamNames, py::arg("lobes"),
        "Names of a parameter vector's entries for `lobes` lobes: rho_d.{R,G,B}, then per lobe k "
        "lobe<k>.{Cx,Cy,Cz,n}.{R,G,B} (3 + 12 lobes floats; the parameter maps' channels).");
  m.def("read_fit", &ReadFit, py::arg("fit"),
        "A FIT folder (or its params.exr): params (H x W x P float32, channels = param_names("
        "lobes)), sigma (same, -1 = unknown; None without sigma.exr), status (dict of H x W "
        "maps from status.exr: status, model, material_cluster, lobe_donor, albedo_filled, "
        "iterations as int32, cost as float32), status_names, lobes, width, height, report "
        "(fit_report.json or None).");
  m.def("eval_brdf", &EvalBrdf, py::arg("params"), py::arg("wi"), py::arg("wo"),
        "f(wi, wo) per RGB channel (N x 3 float32, 1/sr): params one texel's vector (P,) or one "
        "per sample (N, P); wi, wo (N, 3) or (3,), unit, tangent frame. Same float code as the "
        "fitters and renderers (engine/brdf/lafortune.h).");
  m.def("fit_samples", &FitSamples, py::arg("wi"), py::arg("wo"), py::arg("value"),
        py::arg("weight") = py::none(), py::arg("texel") = py::none(),
        py::arg("backend") = "cpu", py::arg("lobes") = 1, py::arg("lobe_model") = "aniso",
        py::arg("init") = "seed", py::arg("loss") = "none", py::arg("loss_scale") = 3.0,
        py::arg("max_iterations") = 100, py::arg("highlight_cone_deg") = 5.0,
        py::arg("min_samples") = 8, py::arg("channel_retry") = true, py::arg("threads") = 0,
        py::arg("device") = "",
        "Fits Lambert + `lobes` Lafortune lobes to samples (wi, wo, value, weight: N x 3; weight "
        "= inverse variance, default 1; texel: uint per sample, default all one texel) with "
        "backend 'cpu', 'ceres' or 'vulkan' (RuntimeError when no Vulkan device). Returns "
        "params and sigma (T x P, T = max(texel) + 1), status (int32, see status_names), cost, "
        "iterations, samples, lambert_only, channels, backend, device. Per-texel, as "
        "`reflcap fit` before lobe transfer, material clusters, albedo fill and diffuse fall-off.");
  m.def("render_view", &RenderView, py::arg("capture"), py::arg("fit"), py::arg("index"),
        py::arg("supersample") = 1, py::arg("cast_shadows") = true, py::arg("mask") = false,
        "Renders capture image `index` from a fit (FIT folder or params.exr) with the CPU "
        "reference renderer: the direct light of `reflcap render` (a normal-map capture's "
        "shadows from its least-squares height field; without the interreflection, stray light, "
        "point spread and L1 height field that `reflcap render` adds when the train photographs "
        "ask for them): H x W x 3 float32 (exposure_s x radiance); with mask=True a tuple "
        "(pixels, H x W mask).");
  m.attr("MAX_LOBES") = reflcap::brdf::kMaxLobes;
}
