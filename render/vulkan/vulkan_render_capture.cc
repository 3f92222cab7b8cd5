// Re-rendering a capture with the Vulkan renderer (see vulkan_render_capture.h): the images go to
// VulkanRenderer::RenderImages in one call, so they are batched and pipelined.
#include "render/vulkan/vulkan_render_capture.h"

#include "engine/core/log.h"

namespace reflcap::render {

Status SetFittedScene(VulkanRenderer& renderer, const FittedCapture& fitted) {
  if (fitted.normal_map) {
    const Capture& capture = *fitted.capture;
    return renderer.SetNormalMapScene(fitted.atlas, fitted.maps,
                                      capture.cameras[capture.normal_map->camera],
                                      fitted.height_field.get());
  }
  return renderer.SetScene({fitted.scene.get(), &fitted.atlas, &fitted.maps});
}

StatusOr<RenderResult> RenderCaptureImageVulkan(VulkanRenderer& renderer,
                                                const FittedCapture& fitted, size_t index,
                                                const RenderOptions& options) {
  const Capture& capture = *fitted.capture;
  REFLCAP_CHECK(index < capture.images.size());
  const CaptureImage& image = capture.images[index];
  const Camera& camera = capture.cameras[image.camera];
  const Light& light = capture.lights[image.light];
  StatusOr<RenderResult> result =
      fitted.normal_map ? renderer.RenderNormalMapImage(camera, light, image.exposure_s, options)
                        : renderer.RenderImage(camera, light, capture.WorldFromObject(image),
                                               image.exposure_s, options);
  if (!result.ok()) {
    return result.status().WithContext(StrCat(capture.json_path.string(), ": images[", index, "]"));
  }
  return result;
}

Status RenderCaptureImagesVulkan(VulkanRenderer& renderer, const FittedCapture& fitted,
                                 const std::vector<size_t>& indices, const RenderOptions& options,
                                 const CaptureRenderBackend::Sink& sink) {
  const Capture& capture = *fitted.capture;
  std::vector<RenderRequest> requests(indices.size());
  for (size_t k = 0; k < indices.size(); ++k) {
    const size_t index = indices[k];
    REFLCAP_CHECK(index < capture.images.size());
    const CaptureImage& image = capture.images[index];
    RenderRequest& q = requests[k];
    q.camera = &capture.cameras[image.camera];
    q.light = &capture.lights[image.light];
    q.world_from_object = capture.WorldFromObject(image);
    q.exposure_s = image.exposure_s;
    q.label = StrCat(capture.json_path.string(), ": images[", index, "]");
  }
  return renderer.RenderImages(requests, options, sink);
}

CaptureRenderBackend VulkanCaptureRenderBackend(VulkanRenderer& renderer) {
  CaptureRenderBackend b;
  b.backend = "vulkan";
  b.device = renderer.device().ToString();
  const VulkanRenderOptions& o = renderer.options();
  const char* point = o.shadow_map == ShadowMapKind::kCube ? "cube map"
                      : o.shadow_map == ShadowMapKind::kFitted
                          ? "frustum fitted to the object"
                          : "frustum fitted to the object when "
                            "the light is outside it, else "
                            "cube map";
  b.renderer = StrCat(
      "Vulkan renderer (render/vulkan): rasterised direct light, Lambert + Lafortune shaded ",
      renderer.resolves_pinhole_cameras()
          ? "per pixel from a visibility image by exact camera rays"
          : "per fragment (distorted cameras: per pixel from a visibility image by exact rays)",
      ", shadow maps drawn by ",
      renderer.computes_shadow_maps() ? "compute (texel rays against the triangles)"
                                      : "the depth pass",
      " (point lights: ", point, "; directional: orthographic; ", o.shadow_texels_per_pixel,
      " shadow texels per image pixel, at least ", o.min_shadow_resolution,
      " per side), no interreflection");
  // A GPU renders the auto settings' evidence too; lavapipe leaves it to the CPU reference
  // renderer, ~3x faster on the same cores (bench/RESULTS.md: `reflcap render` medium preset,
  // 19.7 s on the CPU backend against 58.1 s on lavapipe).
  b.renders_evidence = !renderer.device().IsSoftware();
  b.prepare = [&renderer](const FittedCapture& fitted) { return SetFittedScene(renderer, fitted); };
  b.render = [&renderer](const FittedCapture& fitted, size_t index, const RenderOptions& options) {
    return RenderCaptureImageVulkan(renderer, fitted, index, options);
  };
  b.render_many = [&renderer](const FittedCapture& fitted, const std::vector<size_t>& indices,
                              const RenderOptions& options,
                              const CaptureRenderBackend::Sink& sink) {
    return RenderCaptureImagesVulkan(renderer, fitted, indices, options, sink);
  };
  return b;
}

StatusOr<CaptureRenderSummary> RenderCaptureVulkan(const Capture& capture,
                                                   const std::filesystem::path& params_exr,
                                                   const std::filesystem::path& out_dir,
                                                   const CaptureRenderOptions& options,
                                                   VulkanRenderer& renderer) {
  return RenderCapture(capture, params_exr, out_dir, options, VulkanCaptureRenderBackend(renderer));
}

StatusOr<CaptureRenderSummary> RenderCaptureOnFitDevice(const Capture& capture,
                                                        const std::filesystem::path& params_exr,
                                                        const std::filesystem::path& out_dir,
                                                        const CaptureRenderOptions& options,
                                                        const std::string& device) {
  auto renderer = VulkanRenderer::Create(device);
  if (!renderer.ok()) {
    // E.g. a compute-only device: the fit ran there, rasterisation cannot.
    REFLCAP_LOG(kWarning) << "render: no Vulkan renderer on the fit's device ("
                          << renderer.status().message()
                          << "); rendering with the CPU reference renderer";
    return RenderCapture(capture, params_exr, out_dir, options);
  }
  if ((*renderer)->device().IsSoftware()) {
    REFLCAP_LOG(kInfo) << "render: " << (*renderer)->device().name
                       << " is a CPU device; rendering with the CPU reference renderer";
    renderer->reset();
    return RenderCapture(capture, params_exr, out_dir, options);
  }
  return RenderCaptureVulkan(capture, params_exr, out_dir, options, **renderer);
}

}  // namespace reflcap::render
