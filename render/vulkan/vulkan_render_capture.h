#pragma once
// `reflcap render --backend vulkan`: RenderCapture (render/reference/render_capture.h) with the
// Vulkan renderer drawing each photograph — same files, same layout, render_report.json with
// backend "vulkan" and the device's name.
#include <filesystem>
#include <string>
#include <vector>

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

// RenderCaptureImageVulkan for images `indices` of the capture, through
// VulkanRenderer::RenderImages (many images per submission, several submissions in flight):
// sink(k, result) receives image indices[k], in order. Every image is checked before the first
// renders; errors name capture.json and images[i].
Status RenderCaptureImagesVulkan(VulkanRenderer& renderer, const FittedCapture& fitted,
                                 const std::vector<size_t>& indices, const RenderOptions& options,
                                 const CaptureRenderBackend::Sink& sink);

// `renderer` as a CaptureRenderBackend (it must outlive the backend's use); it renders through
// RenderCaptureImagesVulkan.
CaptureRenderBackend VulkanCaptureRenderBackend(VulkanRenderer& renderer);

// RenderCapture with the Vulkan renderer.
StatusOr<CaptureRenderSummary> RenderCaptureVulkan(const Capture& capture,
                                                   const std::filesystem::path& params_exr,
                                                   const std::filesystem::path& out_dir,
                                                   const CaptureRenderOptions& options,
                                                   VulkanRenderer& renderer);

// The render stage of `reflcap run` after a fit on the Vulkan device `device` (ContextOptions::
// device: "" automatic, index or name substring): RenderCaptureVulkan on that device when it is a
// GPU; on a CPU device (lavapipe) the CPU reference renderer, which is as fast there and is the
// reference; and, with a warning, when the device has no Vulkan renderer (no graphics queue).
StatusOr<CaptureRenderSummary> RenderCaptureOnFitDevice(const Capture& capture,
                                                        const std::filesystem::path& params_exr,
                                                        const std::filesystem::path& out_dir,
                                                        const CaptureRenderOptions& options,
                                                        const std::string& device);

}  // namespace reflcap::render
