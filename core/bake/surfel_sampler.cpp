#include "core/bake/surfel_sampler.h"

#include <cmath>
#include <optional>

#include "core/bake/surfel_shading.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

// Keys that keep these streams apart from every other user of (seed, frame, ...).
constexpr uint64_t kSurfelOffsetDomain = 0x5355524f46465345ull;  // the systematic offset u
constexpr uint64_t kSurfelTriangleDomain = 0x53555254524953ull;  // a triangle's rotation

// More surfels than this is a typo in a shot, not a bake (1.7e9 was the largest published).
constexpr double kMaxSurfels = 1e12;

float toUnitFloat(double x) {
  // Below 1 whatever rounding does, as sampleUniformTriangle expects.
  return std::min(static_cast<float>(x), 0x1.fffffep-1f);
}

double radicalInverse2(uint64_t i) {
  i = (i << 32) | (i >> 32);
  i = ((i & 0x0000ffff0000ffffull) << 16) | ((i >> 16) & 0x0000ffff0000ffffull);
  i = ((i & 0x00ff00ff00ff00ffull) << 8) | ((i >> 8) & 0x00ff00ff00ff00ffull);
  i = ((i & 0x0f0f0f0f0f0f0f0full) << 4) | ((i >> 4) & 0x0f0f0f0f0f0f0f0full);
  i = ((i & 0x3333333333333333ull) << 2) | ((i >> 2) & 0x3333333333333333ull);
  i = ((i & 0x5555555555555555ull) << 1) | ((i >> 1) & 0x5555555555555555ull);
  return static_cast<double>(i >> 11) * 0x1p-53;
}

double triangleArea(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2) {
  // In double: a long thin triangle's area is a small difference of large products.
  const double ax = double(p1.x) - p0.x, ay = double(p1.y) - p0.y, az = double(p1.z) - p0.z;
  const double bx = double(p2.x) - p0.x, by = double(p2.y) - p0.y, bz = double(p2.z) - p0.z;
  const double cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
  return 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
}

// Visits every triangle in the fixed order with its area; the one accumulation order both
// passes share, so that the second pass ends exactly on the first pass's total.
template <typename Visit>
void forEachTriangle(const Scene& scene, Visit&& visit) {
  const std::vector<MeshData>& meshes = scene.meshes();
  for (size_t m = 0; m < meshes.size(); ++m) {
    const MeshData& mesh = meshes[m];
    for (size_t t = 0; t < mesh.triangleCount(); ++t) {
      const Vec3f& p0 = mesh.positions[mesh.indices[3 * t]];
      const Vec3f& p1 = mesh.positions[mesh.indices[3 * t + 1]];
      const Vec3f& p2 = mesh.positions[mesh.indices[3 * t + 2]];
      visit(m, t, p0, p1, p2, triangleArea(p0, p1, p2));
    }
  }
}

}  // namespace

MaterialClass materialClassOf(const Material& material) {
  // The scene makes a light of every triangle whose material has radiance, whatever its type.
  if (material.isEmissive() || (!isBlack(material.radiance) && isFinite(material.radiance))) {
    return MaterialClass::kEmissive;
  }
  const bool rough = !needsWavelets(material);
  switch (material.type) {
    case MaterialType::kDiffuse:
      return MaterialClass::kDiffuse;
    case MaterialType::kConductor:
      return rough ? MaterialClass::kDiffuse : MaterialClass::kGlossy;
    case MaterialType::kDielectric:
      return rough ? MaterialClass::kDiffuse : MaterialClass::kTransmissive;
    case MaterialType::kEmissive:
      return MaterialClass::kEmissive;
  }
  return MaterialClass::kDiffuse;
}

Rgb hemisphericalAlbedo(const Material& material) {
  if (material.type == MaterialType::kDiffuse) return material.albedo;
  const Bsdf bsdf(material, untexturedAlbedo(material));
  if (bsdf.isBlack()) return Rgb(0.0f);
  constexpr int kSamples = 4096;
  Rng rng = Rng::forKeys(0x48454d49ull, kSamples);
  Rgb sum(0.0f);
  for (int k = 0; k < kSamples; ++k) {
    const Vec3f wi = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
    const float uc = rng.uniform();
    const Vec2f u(rng.uniform(), rng.uniform());
    // Reciprocity: the light reflected out of wi's side, sampled from wi.
    const std::optional<BsdfSample> bs = bsdf.sample(wi, uc, u);
    if (!bs || !(bs->pdf > 0.0f) || bs->wi.z <= 0.0f) continue;
    const Rgb w = bs->f * (bs->wi.z / bs->pdf);
    if (isFinite(w)) sum += w;
  }
  return vmin(sum / static_cast<float>(kSamples), Rgb(1.0f));
}

absl::Status planSurfels(const Scene& scene, const SurfelSamplingOptions& options,
                         SurfelSamplingStats* plan) {
  const bool byCount = options.targetCount > 0;
  const bool byRadius = options.targetRadius > 0.0f;
  if (byCount == byRadius) {
    return absl::InvalidArgumentError(fmt::format(
        "surfel sampling needs exactly one of a target count and a target radius (got count {}, "
        "radius {})",
        options.targetCount, options.targetRadius));
  }
  if (byRadius && !std::isfinite(options.targetRadius)) {
    return absl::InvalidArgumentError(
        fmt::format("surfel target radius must be finite (got {})", options.targetRadius));
  }
  *plan = SurfelSamplingStats{};
  forEachTriangle(scene, [&](size_t, size_t, const Vec3f&, const Vec3f&, const Vec3f&, double a) {
    plan->totalArea += a;
    ++plan->triangles;
  });
  if (!(plan->totalArea > 0.0) || !std::isfinite(plan->totalArea)) {
    return absl::InvalidArgumentError(
        fmt::format("the scene has no surface to place surfels on ({} triangles, total area {})",
                    plan->triangles, plan->totalArea));
  }
  double count = static_cast<double>(options.targetCount);
  if (byRadius) {
    const double r = options.targetRadius;
    count = std::max(1.0, std::round(plan->totalArea / (std::numbers::pi * r * r)));
  }
  if (count > kMaxSurfels) {
    return absl::InvalidArgumentError(fmt::format(
        "{:.3g} surfels requested (total area {:.6g}, radius {}), more than the limit of {:.0e}",
        count, plan->totalArea, options.targetRadius, kMaxSurfels));
  }
  plan->surfels = static_cast<uint64_t>(count);
  plan->radius = static_cast<float>(
      std::sqrt(plan->totalArea / (std::numbers::pi * static_cast<double>(plan->surfels))));
  return absl::OkStatus();
}

absl::Status sampleSurfels(const Scene& scene, const SurfelSamplingOptions& options,
                           const std::function<absl::Status(const Surfel&)>& sink,
                           SurfelSamplingStats* stats) {
  SurfelSamplingStats plan;
  if (absl::Status s = planSurfels(scene, options, &plan); !s.ok()) return s;
  const uint64_t n = plan.surfels;
  const double perArea = static_cast<double>(n) / plan.totalArea;
  const double u = Rng::forKeys(options.seed, options.frame, kSurfelOffsetDomain).uniform();
  // Index of the first surfel at or past cumulative area c: the count of k >= 0 with
  // (k + u) / perArea < c.
  auto surfelsBefore = [&](double c) -> uint64_t {
    const double k = std::ceil(c * perArea - u);
    return k <= 0.0 ? 0 : std::min<uint64_t>(n, static_cast<uint64_t>(k));
  };

  const std::vector<MeshData>& meshes = scene.meshes();
  // Each material's class, once (measuring a glossy lobe against the SH is not free), and the
  // albedo of the rough glossy ones that reflect as diffuse.
  std::vector<MaterialClass> classes(scene.materials().size());
  std::vector<std::optional<Rgb>> diffuseAlbedo(scene.materials().size());
  for (size_t i = 0; i < classes.size(); ++i) {
    const Material& material = scene.material(static_cast<uint32_t>(i));
    classes[i] = materialClassOf(material);
    if (classes[i] == MaterialClass::kDiffuse && material.type != MaterialType::kDiffuse) {
      diffuseAlbedo[i] = hemisphericalAlbedo(material);
    }
  }
  SurfelSamplingStats done = plan;
  done.surfels = 0;
  double cumulative = 0.0;
  uint64_t triangleIndex = 0;
  uint64_t first = 0;
  absl::Status status;
  forEachTriangle(scene, [&](size_t m, size_t t, const Vec3f& p0, const Vec3f& p1, const Vec3f& p2,
                             double area) {
    if (!status.ok()) return;
    cumulative += area;
    ++triangleIndex;
    // The last triangle takes the rest, so that the total is exact whatever the rounding.
    const uint64_t end = triangleIndex == plan.triangles ? n : surfelsBefore(cumulative);
    const uint64_t count = end - first;
    const uint64_t firstHere = first;
    first = end;
    if (count == 0) {
      ++done.trianglesWithoutSurfel;
      return;
    }
    const MeshData& mesh = meshes[m];
    const uint32_t triangleId = static_cast<uint32_t>(scene.triangleIdBase(m) + t);
    const uint32_t materialIndex = mesh.materials[t];
    const MaterialClass materialClass = classes[materialIndex];
    const Vec3f ng = normalize(cross(p1 - p0, p2 - p0));
    const uint32_t i0 = mesh.indices[3 * t], i1 = mesh.indices[3 * t + 1],
                   i2 = mesh.indices[3 * t + 2];
    Rng rng = Rng::forKeys(options.seed, options.frame, triangleId, kSurfelTriangleDomain);
    const double shiftX = rng.uniform();
    const double shiftY = rng.uniform();
    for (uint64_t j = 0; j < count; ++j) {
      double x = (static_cast<double>(j) + 0.5) / static_cast<double>(count) + shiftX;
      double y = radicalInverse2(j) + shiftY;
      if (x >= 1.0) x -= 1.0;
      if (y >= 1.0) y -= 1.0;
      const Vec2f b = sampleUniformTriangle(Vec2f(toUnitFloat(x), toUnitFloat(y)));
      // The warp's (b0, b1) become Embree's (b1, b2): a relabelling of a uniform sample.
      const float b1 = b.x, b2 = b.y, b0 = std::max(0.0f, 1.0f - b1 - b2);
      Surfel surfel;
      surfel.position = p0 * b0 + p1 * b1 + p2 * b2;
      surfel.normal = ng;
      surfel.radius = plan.radius;
      surfel.materialClass = materialClass;
      surfel.triangle = triangleId;
      surfel.barycentric = Vec2f(b1, b2);
      SurfaceHit hit;
      hit.p = surfel.position;
      hit.ng = hit.ns = ng;
      if (!mesh.uvs.empty()) hit.uv = mesh.uvs[i0] * b0 + mesh.uvs[i1] * b1 + mesh.uvs[i2] * b2;
      hit.material = materialIndex;
      surfel.albedo = diffuseAlbedo[materialIndex] ? *diffuseAlbedo[materialIndex] : scene.albedoAt(hit);
      if (absl::Status s = sink(surfel); !s.ok()) {
        status = withContext(s, fmt::format("surfel {}", firstHere + j));
        return;
      }
      ++done.surfels;
    }
  });
  if (stats != nullptr) *stats = done;
  if (!status.ok()) return status;
  PBGI_CHECK_EQ(done.surfels, n);
  return absl::OkStatus();
}

absl::StatusOr<std::vector<Surfel>> collectSurfels(const Scene& scene,
                                                   const SurfelSamplingOptions& options,
                                                   SurfelSamplingStats* stats) {
  std::vector<Surfel> out;
  const absl::Status s = sampleSurfels(
      scene, options,
      [&](const Surfel& surfel) {
        out.push_back(surfel);
        return absl::OkStatus();
      },
      stats);
  if (!s.ok()) return s;
  return out;
}

}  // namespace pbgi
