#pragma once
// `reflcap render --backend vulkan`: RenderCapture (render/reference/render_capture.h) with the
// Vulkan renderer drawing each photograph — same files, same layout, render_report.json with
// backend "vulkan" and the device's name.
#include <filesystem>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "render/reference/render_capture.h"
#include "render/vulkan/vulkan_renderer.h"

namespace reflcap::render {

// Uploads the geometry and parameter maps of `fitted` (mesh or normal map) to `renderer`.
Status SetFittedScene(VulkanRenderer& renderer, const FittedCapture& fitted);

// RenderCaptureImage on the GPU: image `index` of the capture whose scene SetFittedScene gave
// `renderer`.
StatusOr<RenderResult> RenderCaptureImageVulkan(VulkanRenderer& renderer,
                                                const FittedCapture& fitted, size_t index,
                                                const RenderOptions& options);

// `renderer` as a CaptureRenderBackend (it must outlive the backend's use).
CaptureRenderBackend VulkanCaptureRenderBackend(VulkanRenderer& renderer);

// RenderCapture with the Vulkan renderer.
StatusOr<CaptureRenderSummary> RenderCaptureVulkan(const Capture& capture,
                                                   const std::filesystem::path& params_exr,
                                                   const std::filesystem::path& out_dir,
                                                   const CaptureRenderOptions& options,
                                                   VulkanRenderer& renderer);

}  // namespace reflcap::render
