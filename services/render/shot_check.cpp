#include "services/render/shot_check.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "core/bake/surfel_shading.h"
#include "core/pbgi/microbuffer.h"
#include "core/pbgi/product_gather.h"
#include "core/pbgi/wavelet_bsdf.h"
#include "core/render/integrators.h"
#include "core/util/status.h"
#include "formats/scene/frame_scene.h"

namespace pbgi {

std::string toString(OutputFormat format) {
  switch (format) {
    case OutputFormat::kExr:
      return "exr";
    case OutputFormat::kFloatRgb:
      return "float RGB";
    case OutputFormat::kDisplay8:
      return "8-bit";
  }
  return "unknown";
}

namespace {

absl::StatusOr<std::vector<GlossyMaterialCheck>> glossyMaterials(const Scene& scene) {
  std::vector<GlossyMaterialCheck> out;
  WaveletBsdfCache cache;
  // As the product gather of the default preset projects them for its receivers.
  const WaveletBsdfOptions options = productGatherOptions(GatherOptions{}).bsdf;
  for (const Material& m : scene.materials()) {
    // Conductors only: the first hit on a dielectric, rough or not, is path traced.
    if (m.type != MaterialType::kConductor || !needsWavelets(m) ||
        Bsdf(m, untexturedAlbedo(m)).isDelta()) {
      continue;
    }
    PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const WaveletBsdf> projected,
                          cache.get(m, options));
    float least = std::numeric_limits<float>::infinity(), most = 0.0f;
    for (int b = 0; b < projected->bins(); ++b) {
      const float texels = projected->lobeTexels(std::cos(projected->binElevation(b)));
      least = std::min(least, texels);
      most = std::max(most, texels);
    }
    out.push_back({.name = m.name,
                   .roughness = m.roughness,
                   .keptCoefficients = projected->keptCoefficients(),
                   .denseCoefficients = static_cast<size_t>(projected->bins()) * kCubeFaces * 3 *
                                        options.resolution * options.resolution,
                   .relativeError = projected->maxRelativeError(),
                   .lobeTexelsMin = least,
                   .lobeTexelsMax = most,
                   .gather = least >= kMinProductLobeTexels ? "product"
                             : most < kMinProductLobeTexels ? "adaptive"
                                                            : "product or adaptive, by view"});
  }
  return out;
}

// A glossy receiver whose lobe spans fewer texels than the product gather's cube holds is
// gathered by the adaptive microbuffer, refined towards the lobe per camera sample: on a frame
// filled by such surfaces PBGI spends more per sample than a path traced sample costs.
std::vector<std::string> narrowLobeAdvice(const std::vector<GlossyMaterialCheck>& glossy) {
  std::vector<std::string> out;
  for (const GlossyMaterialCheck& g : glossy) {
    if (g.lobeTexelsMin >= kMinProductLobeTexels) continue;
    out.push_back(fmt::format(
        "glossy material '{}' (roughness {:g}): its lobe spans {:.0f} texels{} (the wavelet "
        "product needs {:.0f}), so its receivers take the adaptive microbuffer; where such "
        "surfaces fill the frame, PBGI renders slower than the path tracer at equal error: "
        "render those shots with --integrator path",
        g.name, g.roughness, g.lobeTexelsMin,
        g.lobeTexelsMax >= kMinProductLobeTexels ? " at grazing views" : "",
        static_cast<double>(kMinProductLobeTexels)));
  }
  return out;
}

}  // namespace

std::string describeGlossyMaterial(const GlossyMaterialCheck& g) {
  return fmt::format(
      "glossy material '{}' (roughness {:g}): its BSDF in wavelets keeps {} of {} coefficients, "
      "{:.2f} % L2 error; its lobe spans {:.0f} to {:.0f} texels: {}",
      g.name, g.roughness, g.keptCoefficients, g.denseCoefficients, 100.0 * g.relativeError,
      g.lobeTexelsMin, g.lobeTexelsMax, g.gather);
}

absl::StatusOr<ShotCheck> checkShot(const ShotDesc& shot, const std::vector<int>& frames,
                                    bool glossy) {
  ShotCheck check;
  std::vector<int> wanted = frames;
  if (wanted.empty()) {
    for (int f = shot.firstFrame; f <= shot.lastFrame; ++f) wanted.push_back(f);
  }
  for (const int f : wanted) PBGI_RETURN_IF_ERROR(checkShotFrame(shot, f));
  // The integrator and its settings were validated when the shot was parsed (and again by any
  // override applied to it): only what it is and needs is read here.
  PBGI_ASSIGN_OR_RETURN(const IntegratorInfo* integrator, findIntegrator(shot.render.integrator));
  check.integrator = integrator->name;
  check.needsTree = integrator->needsTree;
  check.output = outputPathForFrame(shot.output, wanted.front(), shot.lastFrame > shot.firstFrame);
  absl::StatusOr<OutputFormat> format = outputFormatFor(check.output);
  if (!format.ok()) {
    return absl::Status(format.status().code(),
                        fmt::format("{}: output: {}", shot.path, format.status().message()));
  }
  check.format = *format;
  for (const int f : wanted) {
    absl::StatusOr<FrameScene> loaded = loadFrameScene(shot, f);
    if (!loaded.ok()) {
      return absl::Status(loaded.status().code(),
                          fmt::format("{} frame {}: {}", shot.path, f, loaded.status().message()));
    }
    FrameCheck frame{.frame = f,
                     .stats = loaded->scene->stats(),
                     .materials = loaded->scene->materials().size(),
                     .bounds = loaded->scene->bounds(),
                     .warnings = loaded->warnings};
    if (frame.stats.lights == 0) {
      frame.warnings.push_back(
          "nothing emits light (no light, emissive surface or environment): the frame renders "
          "black");
    }
    if (glossy && check.frames.empty()) {
      PBGI_ASSIGN_OR_RETURN(check.glossy, glossyMaterials(*loaded->scene));
      if (check.needsTree) check.slowerThanPathTraced = narrowLobeAdvice(check.glossy);
    }
    check.frames.push_back(std::move(frame));
  }
  return check;
}

}  // namespace pbgi
