#pragma once
// Farm tiles: a frame split into regions (makeTiles with the farm's tile size; a tile's
// index is its position in that list) that render as separate tasks, each its own EXR, and
// the assembly that puts them back together. Pixels do not depend on the tiling
// (ARCHITECTURE invariant 1), so an assembled frame equals, pixel for pixel, the frame
// rendered whole.
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/render/image.h"
#include "core/render/renderer.h"

namespace pbgi {

// "x0 y0 x1 y1", and back (InvalidArgument naming the text).
std::string regionText(const TileRect& region);
absl::StatusOr<TileRect> parseRegion(const std::string& text);

// The pixels of `region` as an image of its own (metadata kept); OutOfRange when the region
// leaves the image.
absl::StatusOr<Image> cropImage(const Image& image, const TileRect& region);

// Reads every tile EXR (tilePaths[i] holds regions[i]), checks each is present, readable,
// of its region's size and of the same channels, and writes the width x height frame to
// `outPath` atomically (temporary then rename) with the first tile's metadata (less its
// region). A missing or wrong tile fails the frame naming the tile and its file; nothing is
// written then. Returns the frame as written.
absl::StatusOr<Image> assembleFrame(const std::vector<std::string>& tilePaths,
                           const std::vector<TileRect>& regions, int width, int height,
                           const std::string& outPath);

}  // namespace pbgi
