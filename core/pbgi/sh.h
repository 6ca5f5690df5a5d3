#pragma once
// Real spherical harmonics of bands 0..2 (9 coefficients), the directional functions that
// PBGI keeps per node (Christensen 2008): the projected area of the node's surfels and the
// intensity (power per steradian) they send out.
//
// Convention: Sloan, "Stupid Spherical Harmonics (SH) Tricks" (GDC 2008), appendix A2: the
// real basis orthonormal over the sphere (integral of Y_i Y_j = delta_ij), with the
// Condon-Shortley phase, coefficient index i = l (l + 1) + m. For a unit direction (x, y, z):
//   Y0 = 0.282095                      (l = 0)
//   Y1 = -0.488603 y, Y2 = 0.488603 z, Y3 = -0.488603 x          (l = 1)
//   Y4 = 1.092548 xy, Y5 = -1.092548 yz, Y6 = 0.315392 (3z^2 - 1),
//   Y7 = -1.092548 xz, Y8 = 0.546274 (x^2 - y^2)                  (l = 2)
// Every producer and consumer of coefficients in pbgi goes through evalShBasis, so the sign
// convention only has to agree with itself; it is stated because files store coefficients.

#include <array>
#include <functional>

#include "core/math/vec.h"

namespace pbgi {

inline constexpr int kShCoefficients = 9;
// The constant basis function, sqrt(1 / (4 pi)) (in double so that floats round once).
inline constexpr double kY00 = 0.28209479177387814;

// Fills out[0..8] with the basis at unit direction dir.
void evalShBasis(const Vec3f& dir, float out[kShCoefficients]);
// The gradients of the basis polynomials above at dir (in 3D; project onto the tangent plane,
// (I - dir dir^T) g, for the gradient on the sphere): how a function changes as the direction
// moves, for first-order expansions.
void evalShBasisGradient(const Vec3f& dir, Vec3f out[kShCoefficients]);

// A scalar spherical function.
struct Sh9 {
  std::array<float, kShCoefficients> c{};

  Sh9& operator+=(const Sh9& o) {
    for (int i = 0; i < kShCoefficients; ++i) c[i] += o.c[i];
    return *this;
  }
  Sh9& operator*=(float s) {
    for (float& v : c) v *= s;
    return *this;
  }
  friend Sh9 operator+(Sh9 a, const Sh9& b) { return a += b; }
  friend Sh9 operator*(Sh9 a, float s) { return a *= s; }
  friend Sh9 operator*(float s, Sh9 a) { return a *= s; }
  bool operator==(const Sh9&) const = default;
};

// An RGB spherical function: 9 coefficients per channel (27 floats), the vectors that
// quantization turns into codebook indices.
struct Sh9Rgb {
  static constexpr int kFloats = 3 * kShCoefficients;
  std::array<Rgb, kShCoefficients> c{};

  Sh9Rgb() { c.fill(Rgb(0.0f)); }
  // Colour `colour` times the scalar function `sh`.
  Sh9Rgb(const Sh9& sh, const Rgb& colour) {
    for (int i = 0; i < kShCoefficients; ++i) c[i] = colour * sh.c[i];
  }

  Sh9Rgb& operator+=(const Sh9Rgb& o) {
    for (int i = 0; i < kShCoefficients; ++i) c[i] += o.c[i];
    return *this;
  }
  Sh9Rgb& operator*=(float s) {
    for (Rgb& v : c) v *= s;
    return *this;
  }
  friend Sh9Rgb operator+(Sh9Rgb a, const Sh9Rgb& b) { return a += b; }
  friend Sh9Rgb operator*(Sh9Rgb a, float s) { return a *= s; }
  friend Sh9Rgb operator*(float s, Sh9Rgb a) { return a *= s; }
  bool operator==(const Sh9Rgb& o) const { return c == o.c; }

  // Flat layout, coefficient-major: c0.r c0.g c0.b c1.r ... c8.b (the order quantization
  // and the page format see).
  void toFloats(float out[kFloats]) const;
  static Sh9Rgb fromFloats(const float in[kFloats]);
};

float evaluate(const Sh9& sh, const Vec3f& dir);
Rgb evaluate(const Sh9Rgb& sh, const Vec3f& dir);

// max(0, dot(normal, w)) projected exactly onto bands 0..2 (normal: unit). The clamped
// cosine is zonal around the normal with zonal coefficients z_l = sqrt(pi)/2, sqrt(pi/3),
// sqrt(5 pi)/8; rotating a zonal function to axis n gives c_lm = sqrt(4 pi / (2l + 1)) z_l
// Y_lm(n) = A_l Y_lm(n) with A_l = pi, 2 pi / 3, pi / 4 (Ramamoorthi and Hanrahan 2001).
Sh9 projectClampedCosine(const Vec3f& normal);

// Projected area, seen from direction w, of a one-sided disk of area `area` facing `normal`:
// area * max(0, dot(normal, w)).
Sh9 projectedAreaSh(const Vec3f& normal, float area);

// Radiant intensity (W/sr) towards w of a Lambertian emitter of area `area`, normal `normal`
// and outgoing radiance `radiance`: radiance * area * max(0, dot(normal, w)). This is what
// Christensen's nodes call outgoing power; dividing it by the projected area gives back the
// mean radiance seen from w.
Sh9Rgb lambertianIntensitySh(const Vec3f& normal, float area, const Rgb& radiance);

// The rotation of spherical functions into a local frame: local(d) = world(frame.toWorld(d)).
// Rotations keep each band to itself and are orthogonal in this orthonormal basis, so the way
// back is the transpose. The matrix is found by a quadrature exact for products of band-2
// functions (3 Gauss-Legendre nodes in z, 5 in phi), not by Wigner recurrences: 15 basis
// evaluations per rotation.
struct ShRotation {
  float m[kShCoefficients][kShCoefficients] = {};

  static ShRotation toLocal(const Frame& frame);
  Sh9 apply(const Sh9& sh) const;
  Sh9 applyInverse(const Sh9& sh) const;
  Sh9Rgb apply(const Sh9Rgb& sh) const;
  Sh9Rgb applyInverse(const Sh9Rgb& sh) const;
};

// Projects any scalar function by quadrature: Gauss-Legendre in cos(theta) (`zNodes` nodes)
// times the trapezoid rule in phi (`phiNodes` nodes). Exact for band-limited functions of
// band <= 2 once zNodes >= 3 and phiNodes >= 5; converges like the function's smoothness
// otherwise. For tests and for projecting tabulated emitters (environment maps).
Sh9 projectNumerically(const std::function<float(const Vec3f&)>& f, int zNodes, int phiNodes);

}  // namespace pbgi
