#include "services/render/frame_assembly.h"

#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "core/util/status.h"
#include "formats/image/image_io.h"

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

}  // namespace

std::string regionText(const TileRect& r) {
  return fmt::format("{} {} {} {}", r.x0, r.y0, r.x1, r.y1);
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

absl::StatusOr<Image> cropImage(const Image& image, const TileRect& r) {
  if (r.x0 < 0 || r.y0 < 0 || r.x1 > image.width() || r.y1 > image.height() || r.x1 <= r.x0 ||
      r.y1 <= r.y0) {
    return absl::OutOfRangeError(fmt::format("region {} leaves the {}x{} image", regionText(r),
                                             image.width(), image.height()));
  }
  Image out(r.width(), r.height(), image.channels());
  copyBlock(image, r.x0, r.y0, out, 0, 0, r.width(), r.height());
  out.metadata() = image.metadata();
  return out;
}

absl::StatusOr<Image> assembleFrame(const std::vector<std::string>& tilePaths,
                           const std::vector<TileRect>& regions, int width, int height,
                           const std::string& outPath) {
  if (tilePaths.size() != regions.size() || regions.empty()) {
    return absl::InvalidArgumentError(fmt::format(
        "assemble {}: {} tile files for {} tiles", outPath, tilePaths.size(), regions.size()));
  }
  Image frame;
  for (size_t i = 0; i < regions.size(); ++i) {
    const TileRect& r = regions[i];
    auto where = [&] { return fmt::format("assemble {}: tile {} ({})", outPath, i, tilePaths[i]); };
    if (r.x0 < 0 || r.y0 < 0 || r.x1 > width || r.y1 > height || r.x1 <= r.x0 || r.y1 <= r.y0) {
      return absl::OutOfRangeError(
          fmt::format("{}: region {} leaves the {}x{} frame", where(), regionText(r), width, height));
    }
    if (!std::filesystem::exists(tilePaths[i])) {
      return absl::NotFoundError(fmt::format("{}: missing", where()));
    }
    absl::StatusOr<Image> tile = readImage(tilePaths[i]);
    if (!tile.ok()) {
      return absl::DataLossError(fmt::format("{}: {}", where(), tile.status().message()));
    }
    if (tile->width() != r.width() || tile->height() != r.height()) {
      return absl::DataLossError(fmt::format("{}: {}x{} pixels, expected {}x{} for region {}",
                                             where(), tile->width(), tile->height(), r.width(),
                                             r.height(), regionText(r)));
    }
    if (i == 0) {
      frame = Image(width, height, tile->channels());
      for (const MetadataEntry& m : tile->metadata()) {
        if (m.name != "pbgi/region") frame.setMetadata(m.name, m.value);
      }
    } else if (tile->channels() != frame.channels()) {
      return absl::DataLossError(fmt::format("{}: channels differ from tile 0's", where()));
    }
    copyBlock(*tile, 0, 0, frame, r.x0, r.y0, r.width(), r.height());
  }
  frame.setMetadata("pbgi/assembledTiles", static_cast<int>(regions.size()));
  PBGI_RETURN_IF_ERROR(writeExr(frame, outPath));
  return frame;
}

}  // namespace pbgi
