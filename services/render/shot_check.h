#pragma once
// What `pbgi check` and the coordinator's submission verify before anything renders: the
// frames asked for, the integrator, the output's format, and each frame's scene loaded as a
// worker loads it (geometry parsed, materials merged, textures and environment maps decoded).

#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/scene/scene.h"
#include "core/scene/shot.h"
#include "formats/image/image_io.h"

namespace pbgi {

struct FrameCheck {
  int frame = 0;
  SceneStats stats;
  size_t materials = 0;
  Bounds3f bounds;
  std::vector<std::string> warnings;  // the loader's, and a frame with nothing that emits
};

// A glossy receiver's material (a rough conductor) whose lobes the tree's SH do not hold
// (needsWavelets), as the default preset's wavelet product would reflect light with it
// (wavelet_bsdf.h): its coefficients kept over every outgoing bin, of how many, the largest
// relative L2 error dropped, how many of the cube's texels its lobe spans (the least and the
// most over the bins), and so which gather its receivers take: "product", "adaptive" (a lobe
// narrower than kMinProductLobeTexels) or "product or adaptive, by view".
struct GlossyMaterialCheck {
  std::string name;
  float roughness = 0;
  size_t keptCoefficients = 0;
  size_t denseCoefficients = 0;
  float relativeError = 0;
  float lobeTexelsMin = 0, lobeTexelsMax = 0;
  std::string gather;
};

struct ShotCheck {
  std::string integrator;
  bool needsTree = false;  // the frames bake a PBGI tree first
  std::string output;      // the first frame's image
  OutputFormat format = OutputFormat::kExr;
  std::vector<FrameCheck> frames;
  std::vector<GlossyMaterialCheck> glossy;  // the first frame's scene's
  // Where the shot's integrator is likely slower than the path tracer at equal error, and why
  // (PBGI: a glossy material whose lobe the wavelet product cannot hold): one line each.
  std::vector<std::string> slowerThanPathTraced;
};

// Checks `frames` of the shot (empty: every frame) as a render of them would meet them, and
// with `glossy`, projects the glossy materials' BSDFs for the report (a few tens of ms each;
// submission, which only refuses, skips it). Errors name the shot, the frame and the file at
// fault.
absl::StatusOr<ShotCheck> checkShot(const ShotDesc& shot, const std::vector<int>& frames,
                                    bool glossy = true);

// One line of what `pbgi check` and `pbgi inspect` print of a glossy material: "glossy material
// 'NAME' (roughness R): its BSDF in wavelets keeps K of N coefficients, E % L2 error; its lobe
// spans A to B texels: GATHER".
std::string describeGlossyMaterial(const GlossyMaterialCheck& g);

// "exr", "float RGB", "8-bit".
std::string toString(OutputFormat format);

}  // namespace pbgi
