#include "core/pbgi/sh.h"

#include <cmath>
#include <vector>

#include "core/util/check.h"

namespace pbgi {

namespace {

// sqrt(3 / (4 pi)), sqrt(15 / (4 pi)), sqrt(5 / (16 pi)), sqrt(15 / (16 pi)): with kY00, the
// normalisation constants of Sloan's table, in double so the floats round once.
constexpr double kY1 = 0.4886025119029199;
constexpr double kY2a = 1.0925484305920792;
constexpr double kY20 = 0.31539156525252005;
constexpr double kY22 = 0.5462742152960396;

// Gauss-Legendre nodes and weights on [-1, 1] by Newton's method on P_n (Numerical
// Recipes' gauleg): accurate to double precision for any n this code asks for.
void gaussLegendre(int n, std::vector<double>* nodes, std::vector<double>* weights) {
  nodes->assign(n, 0.0);
  weights->assign(n, 0.0);
  for (int i = 0; i < (n + 1) / 2; ++i) {
    double x = std::cos(std::numbers::pi * (i + 0.75) / (n + 0.5));
    double dp = 0.0;
    for (int iter = 0; iter < 100; ++iter) {
      double p0 = 1.0, p1 = 0.0;
      for (int j = 1; j <= n; ++j) {
        const double p2 = p1;
        p1 = p0;
        p0 = ((2.0 * j - 1.0) * x * p1 - (j - 1.0) * p2) / j;
      }
      dp = n * (x * p0 - p1) / (x * x - 1.0);
      const double dx = p0 / dp;
      x -= dx;
      if (std::abs(dx) < 1e-15) break;
    }
    (*nodes)[i] = -x;
    (*nodes)[n - 1 - i] = x;
    const double w = 2.0 / ((1.0 - x * x) * dp * dp);
    (*weights)[i] = w;
    (*weights)[n - 1 - i] = w;
  }
}

}  // namespace

void evalShBasis(const Vec3f& dir, float out[kShCoefficients]) {
  const float x = dir.x, y = dir.y, z = dir.z;
  out[0] = static_cast<float>(kY00);
  out[1] = static_cast<float>(-kY1) * y;
  out[2] = static_cast<float>(kY1) * z;
  out[3] = static_cast<float>(-kY1) * x;
  out[4] = static_cast<float>(kY2a) * x * y;
  out[5] = static_cast<float>(-kY2a) * y * z;
  out[6] = static_cast<float>(kY20) * (3.0f * z * z - 1.0f);
  out[7] = static_cast<float>(-kY2a) * x * z;
  out[8] = static_cast<float>(kY22) * (x * x - y * y);
}

void evalShBasisGradient(const Vec3f& dir, Vec3f out[kShCoefficients]) {
  const float x = dir.x, y = dir.y, z = dir.z;
  const float a = static_cast<float>(kY1), b = static_cast<float>(kY2a);
  const float c = static_cast<float>(kY20), e = static_cast<float>(kY22);
  out[0] = Vec3f(0.0f);
  out[1] = Vec3f(0.0f, -a, 0.0f);
  out[2] = Vec3f(0.0f, 0.0f, a);
  out[3] = Vec3f(-a, 0.0f, 0.0f);
  out[4] = Vec3f(b * y, b * x, 0.0f);
  out[5] = Vec3f(0.0f, -b * z, -b * y);
  out[6] = Vec3f(0.0f, 0.0f, 6.0f * c * z);
  out[7] = Vec3f(-b * z, 0.0f, -b * x);
  out[8] = Vec3f(2.0f * e * x, -2.0f * e * y, 0.0f);
}

void Sh9Rgb::toFloats(float out[kFloats]) const {
  for (int i = 0; i < kShCoefficients; ++i) {
    out[3 * i] = c[i].x;
    out[3 * i + 1] = c[i].y;
    out[3 * i + 2] = c[i].z;
  }
}

Sh9Rgb Sh9Rgb::fromFloats(const float in[kFloats]) {
  Sh9Rgb sh;
  for (int i = 0; i < kShCoefficients; ++i) sh.c[i] = Rgb(in[3 * i], in[3 * i + 1], in[3 * i + 2]);
  return sh;
}

float evaluate(const Sh9& sh, const Vec3f& dir) {
  float y[kShCoefficients];
  evalShBasis(dir, y);
  float sum = 0.0f;
  for (int i = 0; i < kShCoefficients; ++i) sum += sh.c[i] * y[i];
  return sum;
}

Rgb evaluate(const Sh9Rgb& sh, const Vec3f& dir) {
  float y[kShCoefficients];
  evalShBasis(dir, y);
  Rgb sum(0.0f);
  for (int i = 0; i < kShCoefficients; ++i) sum += sh.c[i] * y[i];
  return sum;
}

Sh9 projectClampedCosine(const Vec3f& normal) {
  // A_l per band (see the header); index i belongs to band 0, 1, 1, 1, 2, 2, 2, 2, 2.
  constexpr float kBand[kShCoefficients] = {
      kPi,        2.0f * kPi / 3.0f, 2.0f * kPi / 3.0f, 2.0f * kPi / 3.0f, kPi / 4.0f,
      kPi / 4.0f, kPi / 4.0f,        kPi / 4.0f,        kPi / 4.0f};
  float y[kShCoefficients];
  evalShBasis(normal, y);
  Sh9 sh;
  for (int i = 0; i < kShCoefficients; ++i) sh.c[i] = kBand[i] * y[i];
  return sh;
}

Sh9 projectedAreaSh(const Vec3f& normal, float area) { return projectClampedCosine(normal) * area; }

Sh9Rgb lambertianIntensitySh(const Vec3f& normal, float area, const Rgb& radiance) {
  return Sh9Rgb(projectedAreaSh(normal, area), radiance);
}

namespace {

// Directions, weights and basis values of the rotation quadrature, computed once.
struct RotationQuadrature {
  static constexpr int kZ = 3, kPhi = 5, kCount = kZ * kPhi;
  Vec3f dirs[kCount];
  float weights[kCount];
  float basis[kCount][kShCoefficients];

  RotationQuadrature() {
    std::vector<double> zs, ws;
    gaussLegendre(kZ, &zs, &ws);
    const double phiWeight = 2.0 * std::numbers::pi / kPhi;
    for (int i = 0; i < kZ; ++i) {
      const double r = std::sqrt(std::max(0.0, 1.0 - zs[i] * zs[i]));
      for (int j = 0; j < kPhi; ++j) {
        const double phi = phiWeight * (j + 0.5);
        const int n = i * kPhi + j;
        dirs[n] = Vec3f(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)),
                        static_cast<float>(zs[i]));
        weights[n] = static_cast<float>(ws[i] * phiWeight);
        evalShBasis(dirs[n], basis[n]);
      }
    }
  }
};

const RotationQuadrature& rotationQuadrature() {
  static const RotationQuadrature q;
  return q;
}

}  // namespace

ShRotation ShRotation::toLocal(const Frame& frame) {
  const RotationQuadrature& q = rotationQuadrature();
  ShRotation r;
  for (int n = 0; n < RotationQuadrature::kCount; ++n) {
    float world[kShCoefficients];
    evalShBasis(frame.toWorld(q.dirs[n]), world);
    for (int i = 0; i < kShCoefficients; ++i) {
      const float wy = q.weights[n] * q.basis[n][i];
      for (int k = 0; k < kShCoefficients; ++k) r.m[i][k] += wy * world[k];
    }
  }
  // Rotations never mix bands: what the quadrature leaves between them is rounding, and
  // clearing it keeps band 0 (a cluster's total) exactly as it was.
  auto band = [](int i) { return i == 0 ? 0 : i < 4 ? 1 : 2; };
  for (int i = 0; i < kShCoefficients; ++i) {
    for (int k = 0; k < kShCoefficients; ++k) {
      if (band(i) != band(k)) r.m[i][k] = 0.0f;
    }
  }
  r.m[0][0] = 1.0f;
  return r;
}

namespace {

// out = M in, or M^T in (the inverse): the same loop for scalar and RGB coefficients.
template <typename Coefficients, typename Value>
Coefficients rotate(const float (&m)[kShCoefficients][kShCoefficients], const Coefficients& in,
                    bool transpose, Value zero) {
  Coefficients out;
  for (int i = 0; i < kShCoefficients; ++i) {
    Value v = zero;
    for (int k = 0; k < kShCoefficients; ++k) v += (transpose ? m[k][i] : m[i][k]) * in.c[k];
    out.c[i] = v;
  }
  return out;
}

}  // namespace

Sh9 ShRotation::apply(const Sh9& sh) const { return rotate(m, sh, false, 0.0f); }
Sh9 ShRotation::applyInverse(const Sh9& sh) const { return rotate(m, sh, true, 0.0f); }
Sh9Rgb ShRotation::apply(const Sh9Rgb& sh) const { return rotate(m, sh, false, Rgb(0.0f)); }
Sh9Rgb ShRotation::applyInverse(const Sh9Rgb& sh) const { return rotate(m, sh, true, Rgb(0.0f)); }

Sh9 projectNumerically(const std::function<float(const Vec3f&)>& f, int zNodes, int phiNodes) {
  PBGI_CHECK_GT(zNodes, 0);
  PBGI_CHECK_GT(phiNodes, 0);
  std::vector<double> zs, ws;
  gaussLegendre(zNodes, &zs, &ws);
  // d(omega) = dz dphi; the phi rule weighs each node 2 pi / phiNodes.
  const double phiWeight = 2.0 * std::numbers::pi / phiNodes;
  double sum[kShCoefficients] = {};
  for (int i = 0; i < zNodes; ++i) {
    const double z = zs[i];
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    for (int j = 0; j < phiNodes; ++j) {
      const double phi = phiWeight * (j + 0.5);
      const Vec3f dir(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)),
                      static_cast<float>(z));
      float y[kShCoefficients];
      evalShBasis(dir, y);
      const double w = ws[i] * phiWeight * f(dir);
      for (int k = 0; k < kShCoefficients; ++k) sum[k] += w * y[k];
    }
  }
  Sh9 sh;
  for (int k = 0; k < kShCoefficients; ++k) sh.c[k] = static_cast<float>(sum[k]);
  return sh;
}

}  // namespace pbgi
