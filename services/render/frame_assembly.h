#pragma once
// Farm tiles: a frame split into tiles that render as separate tasks, each its own EXR, and the
// assembly that puts them back together. A farm tile is a list of rectangles of the (mosaic)
// frame: one square of the view, in every view of a camera array, so that the views of a tile
// render together (an integrator that shares work across views, the bidirectional cut, shares
// it within the tile). Tile t of a frame is farmTiles(...)[t]; its EXR holds its rectangles
// stacked top to bottom, left-aligned. Pixels do not depend on the tiling (ARCHITECTURE
// invariant 1), so an assembled frame equals, pixel for pixel, the frame rendered whole.
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/render/image.h"
#include "core/render/renderer.h"
#include "core/scene/shot.h"

namespace pbgi {

using FarmTile = std::vector<TileRect>;

// The farm tiles of a frame: makeTiles over one view with `tileSize`, each square taken in
// every view (row by row of the array).
std::vector<FarmTile> farmTiles(int viewWidth, int viewHeight, Vec2i views, int tileSize);
std::vector<FarmTile> farmTiles(const ShotDesc& shot, int tileSize);

// "x0 y0 x1 y1", and back (InvalidArgument naming the text); lists joined by ';'.
std::string regionText(const TileRect& region);
absl::StatusOr<TileRect> parseRegion(const std::string& text);
std::string regionsText(const std::vector<TileRect>& regions);

// Reads every tile EXR (tilePaths[i] holds tiles[i]), checks each is present, readable, of its
// rectangles' stacked size, where they lie (a tile of one rectangle is an EXR whose data
// window is that rectangle of the frame's display window; one of several, the rectangles
// stacked from the corner) and of the same channels, and writes the width x height frame to
// `outPath` atomically (temporary then rename) with the first tile's metadata (less its
// regions). A missing or wrong tile fails the frame naming the tile and its file; nothing is
// written then. Returns the frame as written.
// The pixels of `regions` of a whole frame, stacked top to bottom and left-aligned as a tile's
// EXR holds them (the inverse of assembly, for comparing a frame with a tile rendered alone).
// InvalidArgument when a rectangle leaves the frame.
absl::StatusOr<Image> cropRegions(const Image& frame, const std::vector<TileRect>& regions);

// Writes the frame to `outPath` in the format its extension names (writeRender: .exr keeps
// every AOV; what another format drops is said in `warnings`).
// `output` chooses the AOV layers kept and the EXR compression.
absl::StatusOr<Image> assembleFrame(const std::vector<std::string>& tilePaths,
                                    const std::vector<FarmTile>& tiles, int width, int height,
                                    const std::string& outPath,
                                    std::vector<std::string>* warnings = nullptr,
                                    const OutputOptions& output = {});

}  // namespace pbgi
