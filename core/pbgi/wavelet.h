#pragma once
// Directional radiance as Haar wavelets on a cube map (Wang, Meng and Boubekeur 2015, "Wavelet
// Point-Based Global Illumination", section 3.1): the light a glossy or refractive surfel
// sends out, sampled at the texel centres of a small cube map (six faces of n x n, n a power
// of two), each face and channel Haar-transformed, and only the detail coefficients that
// matter kept. Diffuse surfels keep spherical harmonics alone (sh.h).
//
// The transform is the non-standard 2D Haar decomposition, orthonormal: a face's pixels become
// one scaling coefficient and, for each node of a quadtree over the face (level l = 0 at the
// top, 2^l x 2^l nodes at level l, down to n / 2 x n / 2), three details (horizontal, vertical,
// diagonal). Orthonormal, so the squared error of dropping coefficients is the sum of their
// squares (the reconstruction error reported is exact, not estimated) and a threshold on a
// node's detail norm bounds what each dropped node costs. A quadtree node is dropped when the
// Euclidean norm of its nine numbers (three details x RGB) is at most the threshold; Sun and
// Mukherjee's trees (which the paper follows) drop a node only with all its descendants, which
// keeps the same coefficients whenever a node's details are no smaller than its children's;
// here each node stands alone, so a sharp highlight's fine details survive under a smooth
// coarse level.
//
// A direction's radiance is reconstructed point-wise, without decoding the face: the scaling
// coefficient plus, per level, the node above the direction's texel's details times the sign
// of the quadrant it falls in.
//
// The cube is the microbuffer's (microbuffer.h): its faces, texel layout ((f n + y) n + x),
// centre directions, exact solid angles and direction-to-texel lookup.
#include <array>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/pbgi/microbuffer.h"

namespace pbgi {

// In place, on an n x n image in row-major order (n a power of two, at least 1): the
// orthonormal non-standard Haar transform and its inverse. Layout after the forward transform:
// [0] the scaling coefficient; the node (x, y) of level l (2^l nodes a side) keeps its
// horizontal, vertical and diagonal details at (2^l + x, y), (x, 2^l + y) and
// (2^l + x, 2^l + y) (the usual pyramid layout).
void haarForward(std::span<float> image, int n);
void haarInverse(std::span<float> image, int n);

// One face's kept coefficients: its scaling coefficient and the quadtree nodes whose details
// were kept, in the order of their pyramid index.
struct WaveletFace {
  Rgb scaling{0.0f};
  struct Node {
    uint16_t level = 0;
    uint16_t x = 0, y = 0;
    std::array<Rgb, 3> detail{};  // horizontal, vertical, diagonal
  };
  std::vector<Node> nodes;
};

// How far a spherical function is from its projection onto the tree's spherical harmonics
// (bands 0-2, sh.h): the L2 norm of the difference over the sphere relative to the
// function's own, by quadrature over the texels of six n x n faces (n up to
// kMaxMicrobufferResolution; 0 for a function that is 0 everywhere). What decides whether a
// surfel's light needs wavelets at all.
float shProjectionError(const std::function<float(const Vec3f&)>& f, int n);

class WaveletRadiance {
 public:
  WaveletRadiance() = default;

  // Samples `radiance` (of a unit direction) at the texel centres of six n x n faces, Haar
  // transforms each face and keeps each quadtree node whose nine detail values have a norm
  // above `threshold` (0 keeps every nonzero node). n: a power of two up to
  // kMaxMicrobufferResolution (64; the paper uses 32). Non-finite samples count as black (and
  // in nonFiniteSamples()).
  static WaveletRadiance project(const std::function<Rgb(const Vec3f&)>& radiance, int n,
                                 float threshold);
  // The same from values already at the texel centres, in the cube's layout (6 n n of them).
  static WaveletRadiance fromTexels(std::span<const Rgb> texels, int n, float threshold);

  // The coefficients of every face, dense: face-major, then channel, then the n x n pyramid
  // layout of haarForward (6 x 3 x n x n floats), dropped ones 0.
  std::vector<float> dense() const;
  // Keeps, of dense coefficients, the quadtree nodes whose nine detail values have a norm
  // above `threshold`, less the smallest of them as long as what is dropped in all stays
  // within `relativeError` of the norm of every coefficient (the L2 error of the function,
  // relative, is then at most relativeError, whatever the threshold dropped besides), and of
  // those at most `maxNodes`, the largest (0: no limit). What is dropped counts in rmsError()
  // and relativeError().
  static WaveletRadiance fromDense(std::span<const float> dense, int n, float threshold,
                                   float relativeError = 0.0f, size_t maxNodes = 0);
  // The sum of vectors of one resolution (a tree node's, from its children's: the Haar
  // transform is linear), kept as fromDense keeps it. Empty input: an empty vector.
  static WaveletRadiance sum(std::span<const WaveletRadiance* const> parts, float threshold,
                             float relativeError = 0.0f, size_t maxNodes = 0);
  // A vector read back from storage: faces as kept, checked (n a power of two up to
  // kMaxMicrobufferResolution, every node inside its level and in pyramid order, no node
  // twice, every value finite); the error names what is wrong.
  static absl::StatusOr<WaveletRadiance> fromFaces(int n, std::array<WaveletFace, 6> faces);

  // The product of two functions in the wavelet domain (Wang et al. section 3.3): the sum
  // over their common coefficients of the products, which for an orthonormal basis is the sum
  // over texels of the products of their values (Parseval). With one of them a BSDF slice
  // projected with each texel's solid angle as weight, f(wi) cos(wi) dOmega, it is the
  // reflected radiance, integral of f L cos dOmega, over only the coefficients both keep.
  // Both must have the same resolution.
  Rgb dot(const WaveletRadiance& other) const;

  int resolution() const { return n_; }
  bool empty() const { return n_ == 0; }
  const std::array<WaveletFace, 6>& faces() const { return faces_; }
  // The radiance towards a direction (need not be unit): the texel it falls in, reconstructed.
  Rgb evaluate(const Vec3f& dir) const;
  // A whole face, reconstructed (n x n, row-major, RGB).
  std::vector<Rgb> reconstructFace(int face) const;

  size_t keptNodes() const;
  // Coefficients kept: one scaling and three details per kept node, per channel.
  size_t keptCoefficients() const { return 3 * (6 + 3 * keptNodes()); }
  // The root-mean-square over all texels and channels of what thresholding dropped (exact).
  float rmsError() const { return rmsError_; }
  // What thresholding dropped over the norm of every coefficient before it (exact; 0 when
  // nothing was dropped or the function is black).
  float relativeError() const { return relativeError_; }
  // Whether every kept detail is zero: the face is its average (a diffuse surfel's radiance,
  // to the cube map's resolution, or black).
  bool isConstantPerFace() const { return keptNodes() == 0; }
  uint64_t nonFiniteSamples() const { return nonFinite_; }

 private:
  int n_ = 0;
  std::array<WaveletFace, 6> faces_{};
  float rmsError_ = 0.0f;
  float relativeError_ = 0.0f;
  uint64_t nonFinite_ = 0;
};

}  // namespace pbgi
