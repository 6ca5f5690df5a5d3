#pragma once
// Materials and their BSDFs. A BSDF works in the local shading frame (z = shading normal);
// f() excludes the cosine factor, so the integrator multiplies by |wi.z|.
//
// Diffuse and conductor are two-sided: they reflect on whichever side wo lies. The dielectric
// needs the caller to orient the frame's normal to the outside (the geometric normal's
// side): wo.z > 0 means the ray arrives from outside, where the index is 1.

#include <memory>
#include <optional>
#include <string>

#include "core/math/vec.h"
#include "core/scene/shot.h"
#include "core/scene/texture.h"

namespace pbgi {

struct Material {
  std::string name;
  MaterialType type = MaterialType::kDiffuse;
  Rgb albedo{0.8f, 0.8f, 0.8f};
  std::shared_ptr<const Texture> albedoTexture;  // overrides albedo where set
  float roughness = 0.0f;                         // microfacet alpha
  MicrofacetDistribution distribution = MicrofacetDistribution::kGgx;
  bool complexIor = false;  // conductor: eta/k when true, else Schlick with `specular`
  Rgb specular{1.0f, 1.0f, 1.0f};
  Rgb eta{1.0f, 1.0f, 1.0f};
  Rgb k{0.0f, 0.0f, 0.0f};
  Rgb tint{1.0f, 1.0f, 1.0f};
  float ior = 1.5f;
  Rgb radiance{0.0f, 0.0f, 0.0f};  // emissive

  bool isEmissive() const { return type == MaterialType::kEmissive; }
};

// Radiance transport scales refracted radiance by 1/eta^2; importance transport does not.
enum class TransportMode { kRadiance, kImportance };

struct BsdfSample {
  Rgb f{0.0f, 0.0f, 0.0f};  // BSDF value (no cosine)
  Vec3f wi{0.0f, 0.0f, 1.0f};
  float pdf = 0.0f;          // solid-angle density; for delta lobes, the lobe's probability
  bool delta = false;        // a specular (Dirac) lobe: not evaluable by f()/pdf()
  bool transmission = false;
};

// The albedo a material's BSDF takes where no texture applies: a diffuse material's own, a
// conductor's Fresnel colour (its tint, times `specular` for Schlick), 1 for dielectrics, 0 for
// emitters.
Rgb untexturedAlbedo(const Material& m);

// The BSDF of a material at one shading point (texture already looked up into `albedo`).
class Bsdf {
 public:
  Bsdf(const Material& material, const Rgb& albedo,
       TransportMode mode = TransportMode::kRadiance);

  Rgb f(const Vec3f& wo, const Vec3f& wi) const;
  float pdf(const Vec3f& wo, const Vec3f& wi) const;
  // uc picks a lobe, u samples it; nullopt when the sample carries no energy.
  std::optional<BsdfSample> sample(const Vec3f& wo, float uc, const Vec2f& u) const;

  // True when every lobe is a delta (smooth conductor or dielectric): no light sampling.
  bool isDelta() const;
  // True for emissive materials, which reflect nothing.
  bool isBlack() const;

 private:
  const Material* material_;
  Rgb albedo_;
  TransportMode mode_;
};

}  // namespace pbgi
