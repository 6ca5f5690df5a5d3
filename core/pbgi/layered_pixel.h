#pragma once
// One pixel of a gather's buffer with depth (microbuffer.h and warped_gather.h share it): two
// layers, each a depth range with a coverage and a coverage-weighted radiance. A piece whose
// depth range overlaps a layer's is another piece of that surface and adds to it; a piece in
// front of the front layer becomes the front, the old front going over the back; one behind
// joins the back layer, or goes over or under it. The pixel shows the front and as much of the
// back as fits in what the front leaves open (microbuffer.h's header says why).
#include <algorithm>
#include <cmath>
#include <limits>

#include "core/math/vec.h"

namespace pbgi {

struct DepthLayer {
  static constexpr float kEmpty = std::numeric_limits<float>::infinity();
  float depth = kEmpty;  // nearest distance; a buffer may mark a pixel inactive with 0
  float extent = 0.0f;   // how far the layer reaches in depth beyond `depth`
  float coverage = 0.0f;
  Rgb radiance{0.0f};  // coverage-weighted
};

// How much of `under` shows below `top`: all of it if it fits in what top leaves open, else as
// much as fits. Pieces of different depth in one pixel are taken to lie side by side where they
// can (a surface seen at a grazing angle spans a wide range of depths in one pixel; its pieces
// do not hide each other), and one behind the other where they must.
inline float underScale(const DepthLayer& top, const DepthLayer& under) {
  const float open = std::max(0.0f, 1.0f - top.coverage);
  return under.coverage > open ? open / under.coverage : 1.0f;
}

struct LayeredPixel {
  DepthLayer front, back;

  // Front and as much of the back as shows (above 1 where pieces of one surface overlap).
  float coverage() const { return front.coverage + back.coverage * underScale(front, back); }
  Rgb radiance() const { return front.radiance + back.radiance * underScale(front, back); }

  // Composes a piece covering `coverage` of the pixel with coverage-weighted `radiance` at
  // `distance`, reaching `extent` either way. False when it changed nothing: an inactive pixel
  // (front depth 0), or a piece behind full layers.
  bool compose(float distance, float extent, float coverage, const Rgb& weightedRadiance) {
    if (!(front.depth > 0.0f)) return false;
    const DepthLayer piece{distance, extent, coverage, weightedRadiance};
    auto overlaps = [&](const DepthLayer& layer) {
      return std::abs(distance - layer.depth) <= extent + layer.extent;
    };
    auto add = [&](DepthLayer& layer) {
      layer.depth = std::min(layer.depth, distance);
      layer.extent = std::max(layer.extent, extent);
      layer.coverage += coverage;
      layer.radiance += weightedRadiance;
    };
    // `top` over `under`: under shows through what top leaves open.
    auto over = [](const DepthLayer& top, const DepthLayer& under) {
      const float scale = underScale(top, under);
      return DepthLayer{top.depth, top.extent, top.coverage + under.coverage * scale,
                        top.radiance + under.radiance * scale};
    };
    if (front.depth == DepthLayer::kEmpty) {
      front = piece;
    } else if (overlaps(front)) {
      add(front);
    } else if (distance < front.depth) {
      back = back.depth == DepthLayer::kEmpty ? front : over(front, back);
      front = piece;
    } else if (!(front.coverage < 1.0f)) {
      return false;  // hidden behind a full front layer
    } else if (back.depth == DepthLayer::kEmpty) {
      back = piece;
    } else if (overlaps(back)) {
      add(back);
    } else if (distance < back.depth) {
      back = over(piece, back);
    } else if (!(back.coverage < 1.0f)) {
      return false;
    } else {
      back = over(back, piece);
    }
    return true;
  }
};

}  // namespace pbgi
