#include "services/render/frame_assembly.h"

#include <algorithm>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/ocio_config.h"

namespace pbgi {

namespace {

// Copies a w x h block of pixels from `from` at (fx, fy) to `to` at (tx, ty); both images have
// the same channels and the block lies inside both.
void copyBlock(const Image& from, int fx, int fy, Image& to, int tx, int ty, int w, int h) {
  const size_t channels = static_cast<size_t>(from.channelCount());
  const size_t row = static_cast<size_t>(w) * channels;
  for (int y = 0; y < h; ++y) {
    const float* src =
        from.pixels().data() + (static_cast<size_t>(fy + y) * from.width() + fx) * channels;
    std::copy(src, src + row, &to.at(tx, ty + y, 0));
  }
}

bool inside(const TileRect& r, int width, int height) {
  return r.x0 >= 0 && r.y0 >= 0 && r.x1 <= width && r.y1 <= height && r.x1 > r.x0 && r.y1 > r.y0;
}

}  // namespace

std::vector<FarmTile> farmTiles(int viewWidth, int viewHeight, Vec2i views, int tileSize) {
  std::vector<FarmTile> tiles;
  for (const TileRect& t : makeTiles(viewWidth, viewHeight, tileSize)) {
    FarmTile tile;
    for (int row = 0; row < views.y; ++row) {
      for (int col = 0; col < views.x; ++col) {
        tile.push_back({t.x0 + col * viewWidth, t.y0 + row * viewHeight, t.x1 + col * viewWidth,
                        t.y1 + row * viewHeight});
      }
    }
    tiles.push_back(std::move(tile));
  }
  return tiles;
}

std::vector<FarmTile> farmTiles(const ShotDesc& shot, int tileSize) {
  return farmTiles(shot.width, shot.height, shot.camera.views, tileSize);
}

std::string regionText(const TileRect& r) {
  return fmt::format("{} {} {} {}", r.x0, r.y0, r.x1, r.y1);
}

std::string regionsText(const std::vector<TileRect>& regions) {
  std::string text;
  for (const TileRect& r : regions) text += (text.empty() ? "" : ";") + regionText(r);
  return text;
}

absl::StatusOr<TileRect> parseRegion(const std::string& text) {
  std::istringstream in(text);
  TileRect r;
  std::string rest;
  if (!(in >> r.x0 >> r.y0 >> r.x1 >> r.y1) || (in >> rest) || r.x0 < 0 || r.y0 < 0 ||
      r.x1 <= r.x0 || r.y1 <= r.y0) {
    return absl::InvalidArgumentError(
        fmt::format("region '{}': expected 'x0 y0 x1 y1' with 0 <= x0 < x1 and 0 <= y0 < y1", text));
  }
  return r;
}

absl::StatusOr<Image> assembleFrame(const std::vector<std::string>& tilePaths,
                                    const std::vector<FarmTile>& tiles, int width, int height,
                                    const std::string& outPath, std::vector<std::string>* warnings,
                                    const OutputOptions& output) {
  if (tilePaths.size() != tiles.size() || tiles.empty()) {
    return absl::InvalidArgumentError(fmt::format(
        "assemble {}: {} tile files for {} tiles", outPath, tilePaths.size(), tiles.size()));
  }
  Image frame;
  for (size_t i = 0; i < tiles.size(); ++i) {
    auto where = [&] { return fmt::format("assemble {}: tile {} ({})", outPath, i, tilePaths[i]); };
    for (const TileRect& r : tiles[i]) {
      if (!inside(r, width, height)) {
        return absl::OutOfRangeError(fmt::format("{}: region {} leaves the {}x{} frame", where(),
                                                 regionText(r), width, height));
      }
    }
    if (!std::filesystem::exists(tilePaths[i])) {
      return absl::NotFoundError(fmt::format("{}: missing", where()));
    }
    absl::StatusOr<Image> tile = readImage(tilePaths[i]);
    if (!tile.ok()) {
      return absl::DataLossError(fmt::format("{}: {}", where(), tile.status().message()));
    }
    const Vec2i size = stackedSize(tiles[i]);
    if (tile->width() != size.x || tile->height() != size.y) {
      return absl::DataLossError(fmt::format("{}: {}x{} pixels, expected {}x{} for regions {}",
                                             where(), tile->width(), tile->height(), size.x,
                                             size.y, regionsText(tiles[i])));
    }
    // A tile of one rectangle lies at its place in the frame (or, as tiles were written
    // before data windows, at the corner of its own image).
    const ImageWindow w = tile->window();
    const bool placed = tiles[i].size() == 1 &&
                        w == ImageWindow{tiles[i][0].x0, tiles[i][0].y0, width, height};
    if (!placed && !tile->wholeFrame()) {
      return absl::DataLossError(fmt::format(
          "{}: its data window starts at ({}, {}) of a {}x{} frame; expected {}", where(), w.x,
          w.y, w.fullWidth, w.fullHeight,
          tiles[i].size() == 1
              ? fmt::format("({}, {}) of a {}x{} frame", tiles[i][0].x0, tiles[i][0].y0, width,
                            height)
              : fmt::format("the regions {} stacked from (0, 0)", regionsText(tiles[i]))));
    }
    if (i == 0) {
      frame = Image(width, height, tile->channels());
      for (const MetadataEntry& m : tile->metadata()) {
        if (m.name != "pbgi/regions") frame.setMetadata(m.name, m.value);
      }
    } else if (tile->channels() != frame.channels()) {
      return absl::DataLossError(fmt::format("{}: channels differ from tile 0's", where()));
    }
    int y = 0;
    for (const TileRect& r : tiles[i]) {
      copyBlock(*tile, 0, y, frame, r.x0, r.y0, r.width(), r.height());
      y += r.height();
    }
  }
  frame.setMetadata("pbgi/assembledTiles", static_cast<int>(tiles.size()));
  if (output.aovs) {
    PBGI_ASSIGN_OR_RETURN(frame, keepAovs(frame, *output.aovs));
  }
  std::vector<std::string> dropped;
  PBGI_RETURN_IF_ERROR(writeRender(frame, outPath, defaultOcioConfigPath(),
                                   warnings ? warnings : &dropped, output.exrCompression));
  return frame;
}

absl::StatusOr<Image> cropRegions(const Image& frame, const std::vector<TileRect>& regions) {
  int width = 0, height = 0;
  for (const TileRect& r : regions) {
    if (r.x0 < 0 || r.y0 < 0 || r.x1 > frame.width() || r.y1 > frame.height() || r.x1 <= r.x0 ||
        r.y1 <= r.y0) {
      return absl::InvalidArgumentError(fmt::format(
          "region {} is not inside the {}x{} frame", regionText(r), frame.width(), frame.height()));
    }
    width = std::max(width, r.width());
    height += r.height();
  }
  Image out(width, height, frame.channels());
  const size_t channels = static_cast<size_t>(frame.channelCount());
  int row = 0;
  for (const TileRect& r : regions) {
    for (int y = r.y0; y < r.y1; ++y, ++row) {
      const float* from = &frame.pixels()[(size_t(y) * frame.width() + r.x0) * channels];
      std::copy(from, from + size_t(r.width()) * channels,
                &out.pixels()[size_t(row) * width * channels]);
    }
  }
  return out;
}

}  // namespace pbgi
