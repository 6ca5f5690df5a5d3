#include "core/scene/light.h"

#include <algorithm>

#include "core/util/check.h"

namespace pbgi {

namespace {

// Converts an area density at a point seen from p into a solid-angle density.
float areaToSolidAngle(float pdfArea, float dist2, float cosLight) {
  if (cosLight <= 0.0f || dist2 <= 0.0f) return 0.0f;
  return pdfArea * dist2 / cosLight;
}

// A light sample at point q (normal n) of an emitter of the given area sampled uniformly,
// seen from p. One-sided emitters shine along n only.
std::optional<LightSample> areaSample(const Vec3f& p, const Vec3f& q, const Vec3f& n, float area,
                                      bool twoSided, const Rgb& radiance) {
  const Vec3f d = q - p;
  const float dist2 = dot(d, d);
  if (dist2 <= 0.0f) return std::nullopt;
  const float dist = std::sqrt(dist2);
  const Vec3f wi = d / dist;
  const float cosLight = twoSided ? absDot(wi, n) : dot(-wi, n);
  const float pdf = areaToSolidAngle(1.0f / area, dist2, cosLight);
  if (pdf <= 0.0f || !std::isfinite(pdf)) return std::nullopt;
  return LightSample{radiance, wi, dist, pdf, false, q, n};
}

class QuadLight final : public Light {
 public:
  QuadLight(const Vec3f& corner, const Vec3f& eu, const Vec3f& ev, const Rgb& radiance)
      : corner_(corner), eu_(eu), ev_(ev), radiance_(radiance) {
    const Vec3f c = cross(eu, ev);
    area_ = length(c);
    PBGI_CHECK_GT(area_, 0.0f);
    n_ = c / area_;
  }

  std::optional<LightSample> sample(const Vec3f& p, const Vec2f& u) const override {
    return areaSample(p, corner_ + eu_ * u.x + ev_ * u.y, n_, area_, false, radiance_);
  }
  float pdf(const Vec3f& p, const Vec3f& wi, const Vec3f& hit, const Vec3f&) const override {
    const Vec3f d = hit - p;
    return areaToSolidAngle(1.0f / area_, dot(d, d), dot(-wi, n_));
  }
  Rgb emitted(const Vec3f&, const Vec3f& w) const override {
    return dot(n_, w) > 0.0f ? radiance_ : Rgb(0.0f);
  }
  float power() const override { return average(radiance_) * kPi * area_; }

 private:
  Vec3f corner_, eu_, ev_, n_;
  Rgb radiance_;
  float area_ = 0.0f;
};

class TriangleLight final : public Light {
 public:
  TriangleLight(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2, const Rgb& radiance)
      : p0_(p0), p1_(p1), p2_(p2), radiance_(radiance) {
    const Vec3f c = cross(p1 - p0, p2 - p0);
    area_ = 0.5f * length(c);
    n_ = area_ > 0.0f ? normalize(c) : Vec3f(0.0f, 0.0f, 1.0f);
  }

  std::optional<LightSample> sample(const Vec3f& p, const Vec2f& u) const override {
    if (area_ <= 0.0f) return std::nullopt;
    const Vec2f b = sampleUniformTriangle(u);
    const Vec3f q = p0_ * b.x + p1_ * b.y + p2_ * (1.0f - b.x - b.y);
    return areaSample(p, q, n_, area_, true, radiance_);
  }
  float pdf(const Vec3f& p, const Vec3f& wi, const Vec3f& hit, const Vec3f&) const override {
    if (area_ <= 0.0f) return 0.0f;
    const Vec3f d = hit - p;
    return areaToSolidAngle(1.0f / area_, dot(d, d), absDot(wi, n_));
  }
  Rgb emitted(const Vec3f&, const Vec3f&) const override { return radiance_; }
  float power() const override { return average(radiance_) * 2.0f * kPi * area_; }

 private:
  Vec3f p0_, p1_, p2_, n_;
  Rgb radiance_;
  float area_ = 0.0f;
};

class SphereLight final : public Light {
 public:
  SphereLight(const Vec3f& center, float radius, const Rgb& radiance)
      : center_(center), radius_(radius), radiance_(radiance) {
    PBGI_CHECK_GT(radius, 0.0f);
  }

  std::optional<LightSample> sample(const Vec3f& p, const Vec2f& u) const override {
    const Vec3f toCenter = center_ - p;
    const float dc2 = dot(toCenter, toCenter);
    const float r2 = radius_ * radius_;
    if (dc2 <= r2 * 1.0001f) {
      // Inside (or on) the sphere: sample its area uniformly.
      const Vec3f n = sampleUniformSphere(u);
      return areaSample(p, center_ + n * radius_, n, 4.0f * kPi * r2, false, radiance_);
    }
    // Outside: sample the cone the sphere subtends (pbrt-v4's formulation, accurate for
    // small cones where 1 - cos(theta_max) cancels).
    const float dc = std::sqrt(dc2);
    const float sin2Max = r2 / dc2;
    const float cosMax = safeSqrt(1.0f - sin2Max);
    const float oneMinusCosMax = sin2Max < 0.00068523f ? 0.5f * sin2Max : 1.0f - cosMax;
    float cosTheta = (cosMax - 1.0f) * u.x + 1.0f;
    float sin2Theta = 1.0f - cosTheta * cosTheta;
    if (sin2Max < 0.00068523f) {
      sin2Theta = sin2Max * u.x;
      cosTheta = std::sqrt(1.0f - sin2Theta);
    }
    const float cosAlpha = sin2Theta / std::sqrt(sin2Max) +
                           cosTheta * safeSqrt(1.0f - sin2Theta / sin2Max);
    const float sinAlpha = safeSqrt(1.0f - cosAlpha * cosAlpha);
    const float phi = u.y * 2.0f * kPi;
    const Frame frame(-toCenter / dc);  // z points from the centre towards p
    const Vec3f n = frame.toWorld(
        Vec3f(sinAlpha * std::cos(phi), sinAlpha * std::sin(phi), cosAlpha));
    const Vec3f q = center_ + n * radius_;
    const Vec3f d = q - p;
    const float dist = length(d);
    if (dist <= 0.0f) return std::nullopt;
    const float pdf = 1.0f / (2.0f * kPi * oneMinusCosMax);
    return LightSample{radiance_, d / dist, dist, pdf, false, q, n};
  }
  float pdf(const Vec3f& p, const Vec3f& wi, const Vec3f& hit, const Vec3f& n) const override {
    const Vec3f toCenter = center_ - p;
    const float dc2 = dot(toCenter, toCenter);
    const float r2 = radius_ * radius_;
    if (dc2 <= r2 * 1.0001f) {
      const Vec3f d = hit - p;
      return areaToSolidAngle(1.0f / (4.0f * kPi * r2), dot(d, d), dot(-wi, n));
    }
    const float sin2Max = r2 / dc2;
    const float oneMinusCosMax =
        sin2Max < 0.00068523f ? 0.5f * sin2Max : 1.0f - safeSqrt(1.0f - sin2Max);
    return 1.0f / (2.0f * kPi * oneMinusCosMax);
  }
  Rgb emitted(const Vec3f& n, const Vec3f& w) const override {
    return dot(n, w) > 0.0f ? radiance_ : Rgb(0.0f);
  }
  float power() const override {
    return average(radiance_) * kPi * 4.0f * kPi * radius_ * radius_;
  }

 private:
  Vec3f center_;
  float radius_;
  Rgb radiance_;
};

class PointLight final : public Light {
 public:
  PointLight(const Vec3f& position, const Vec3f& axis, float cosCone, const Rgb& intensity)
      : position_(position), axis_(axis), cosCone_(cosCone), intensity_(intensity) {}

  std::optional<LightSample> sample(const Vec3f& p, const Vec2f&) const override {
    const Vec3f d = position_ - p;
    const float dist2 = dot(d, d);
    if (dist2 <= 0.0f) return std::nullopt;
    const float dist = std::sqrt(dist2);
    const Vec3f wi = d / dist;
    if (dot(-wi, axis_) < cosCone_) return std::nullopt;
    return LightSample{intensity_ / dist2, wi, dist, 1.0f, true, position_};
  }
  float power() const override {
    return average(intensity_) * 2.0f * kPi * (1.0f - std::max(cosCone_, -1.0f));
  }
  bool isDelta() const override { return true; }

 private:
  Vec3f position_, axis_;
  float cosCone_;  // -1 for an omnidirectional point light
  Rgb intensity_;
};

class DirectionalLight final : public Light {
 public:
  DirectionalLight(const Vec3f& direction, const Rgb& irradiance)
      : wi_(-normalize(direction)), irradiance_(irradiance) {}

  std::optional<LightSample> sample(const Vec3f&, const Vec2f&) const override {
    return LightSample{irradiance_, wi_, std::numeric_limits<float>::infinity(), 1.0f, true};
  }
  void preprocess(const Bounds3f& bounds) override { sceneRadius_ = bounds.radius(); }
  float power() const override { return average(irradiance_) * kPi * sceneRadius_ * sceneRadius_; }
  bool isDelta() const override { return true; }
  bool isInfinite() const override { return true; }

 private:
  Vec3f wi_;
  Rgb irradiance_;
  float sceneRadius_ = 1.0f;
};

// Rotation about +y by the right-hand rule.
Vec3f rotateY(const Vec3f& v, float cosA, float sinA) {
  return {v.x * cosA + v.z * sinA, v.y, -v.x * sinA + v.z * cosA};
}

class EnvironmentLight final : public Light {
 public:
  EnvironmentLight(std::shared_ptr<const LatLongImage> image, float scale, float rotateDeg)
      : image_(std::move(image)), scale_(scale),
        cosR_(std::cos(radians(rotateDeg))), sinR_(std::sin(radians(rotateDeg))) {
    PBGI_CHECK(image_ && image_->width > 0 && image_->height > 0);
    const int w = image_->width, h = image_->height;
    std::vector<float> weights(static_cast<size_t>(w) * h);
    double integral = 0.0;  // of luminance over the sphere
    for (int y = 0; y < h; ++y) {
      const float sinTheta = std::sin(kPi * (static_cast<float>(y) + 0.5f) / static_cast<float>(h));
      for (int x = 0; x < w; ++x) {
        const Rgb& L = image_->texels[static_cast<size_t>(y) * w + x];
        const float lum = isFinite(L) ? std::max(0.0f, average(L)) : 0.0f;
        weights[static_cast<size_t>(y) * w + x] = lum * sinTheta;
        integral += lum * sinTheta;
      }
    }
    integral *= (2.0 * kPi / w) * (kPi / h);
    averageRadiance_ = static_cast<float>(integral / (4.0 * kPi)) * scale_;
    distribution_ = Distribution2D(weights, w, h);
  }

  std::optional<LightSample> sample(const Vec3f&, const Vec2f& u) const override {
    float pdfUv = 0.0f;
    const Vec2f uv = distribution_.sampleContinuous(u, &pdfUv);
    const float sinTheta = std::sin(kPi * uv.y);
    if (pdfUv <= 0.0f || sinTheta <= 0.0f) return std::nullopt;
    const Vec3f wi = rotateY(latLongToDirection(uv), cosR_, sinR_);
    const float pdf = pdfUv / (2.0f * kPi * kPi * sinTheta);
    return LightSample{lookup(uv), wi, std::numeric_limits<float>::infinity(), pdf, false};
  }
  float pdf(const Vec3f&, const Vec3f& wi, const Vec3f&, const Vec3f&) const override {
    const Vec2f uv = directionToLatLong(rotateY(wi, cosR_, -sinR_));
    const float sinTheta = std::sin(kPi * uv.y);
    if (sinTheta <= 0.0f) return 0.0f;
    return distribution_.density(uv) / (2.0f * kPi * kPi * sinTheta);
  }
  Rgb escaped(const Vec3f& d) const override {
    return lookup(directionToLatLong(rotateY(d, cosR_, -sinR_)));
  }
  void preprocess(const Bounds3f& bounds) override { sceneRadius_ = bounds.radius(); }
  float power() const override {
    return kPi * averageRadiance_ * kPi * sceneRadius_ * sceneRadius_;
  }
  bool isInfinite() const override { return true; }

 private:
  // Nearest texel: the radiance is piecewise constant exactly like the sampling density, so
  // the estimator's weights are exact.
  Rgb lookup(const Vec2f& uv) const {
    const int w = image_->width, h = image_->height;
    const int x = std::clamp(static_cast<int>(uv.x * static_cast<float>(w)), 0, w - 1);
    const int y = std::clamp(static_cast<int>(uv.y * static_cast<float>(h)), 0, h - 1);
    const Rgb& L = image_->texels[static_cast<size_t>(y) * w + x];
    return isFinite(L) ? vmax(L, Rgb(0.0f)) * scale_ : Rgb(0.0f);
  }

  std::shared_ptr<const LatLongImage> image_;
  float scale_;
  float cosR_, sinR_;
  Distribution2D distribution_;
  float averageRadiance_ = 0.0f;
  float sceneRadius_ = 1.0f;
};

class UniformEnvironmentLight final : public Light {
 public:
  explicit UniformEnvironmentLight(const Rgb& radiance) : radiance_(radiance) {}
  std::optional<LightSample> sample(const Vec3f&, const Vec2f& u) const override {
    return LightSample{radiance_, sampleUniformSphere(u), std::numeric_limits<float>::infinity(),
                       uniformSpherePdf(), false};
  }
  float pdf(const Vec3f&, const Vec3f&, const Vec3f&, const Vec3f&) const override {
    return uniformSpherePdf();
  }
  Rgb escaped(const Vec3f&) const override { return radiance_; }
  void preprocess(const Bounds3f& bounds) override { sceneRadius_ = bounds.radius(); }
  float power() const override {
    return kPi * average(radiance_) * kPi * sceneRadius_ * sceneRadius_;
  }
  bool isInfinite() const override { return true; }

 private:
  Rgb radiance_;
  float sceneRadius_ = 1.0f;
};

}  // namespace

Vec3f latLongToDirection(const Vec2f& uv) {
  const float phi = 2.0f * kPi * (uv.x - 0.5f);
  const float theta = kPi * uv.y;
  const float sinTheta = std::sin(theta);
  return {std::cos(phi) * sinTheta, std::cos(theta), std::sin(phi) * sinTheta};
}

Vec2f directionToLatLong(const Vec3f& d) {
  // atan2 keeps full precision near the poles, where acos(y) loses half its bits.
  const float theta = std::atan2(std::sqrt(d.x * d.x + d.z * d.z), d.y);
  float u = std::atan2(d.z, d.x) / (2.0f * kPi) + 0.5f;
  if (u >= 1.0f) u -= 1.0f;
  if (u < 0.0f) u += 1.0f;
  return {u, theta * kInvPi};
}

std::unique_ptr<Light> makeQuadLight(const Vec3f& corner, const Vec3f& edgeU, const Vec3f& edgeV,
                                     const Rgb& radiance) {
  return std::make_unique<QuadLight>(corner, edgeU, edgeV, radiance);
}
std::unique_ptr<Light> makeSphereLight(const Vec3f& center, float radius, const Rgb& radiance) {
  return std::make_unique<SphereLight>(center, radius, radiance);
}
std::unique_ptr<Light> makeTriangleLight(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2,
                                         const Rgb& radiance) {
  return std::make_unique<TriangleLight>(p0, p1, p2, radiance);
}
std::unique_ptr<Light> makePointLight(const Vec3f& position, const Rgb& intensity) {
  return std::make_unique<PointLight>(position, Vec3f(0.0f, 0.0f, 1.0f), -2.0f, intensity);
}
std::unique_ptr<Light> makeSpotLight(const Vec3f& position, const Vec3f& direction, float coneDeg,
                                     const Rgb& intensity) {
  return std::make_unique<PointLight>(position, normalize(direction), std::cos(radians(coneDeg)),
                                      intensity);
}
std::unique_ptr<Light> makeDirectionalLight(const Vec3f& direction, const Rgb& irradiance) {
  return std::make_unique<DirectionalLight>(direction, irradiance);
}
std::unique_ptr<Light> makeEnvironmentLight(std::shared_ptr<const LatLongImage> image, float scale,
                                            float rotateDeg) {
  return std::make_unique<EnvironmentLight>(std::move(image), scale, rotateDeg);
}
std::unique_ptr<Light> makeUniformEnvironmentLight(const Rgb& radiance) {
  return std::make_unique<UniformEnvironmentLight>(radiance);
}

}  // namespace pbgi
