#include "services/coordinator/dashboard/frame_previews.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/rgb_channels.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

FramePreviews::FramePreviews(std::string ocioConfig, int maxEdge, size_t keep)
    : ocioConfig_(std::move(ocioConfig)), maxEdge_(maxEdge), keep_(keep) {}

FramePreviews::Canvas& FramePreviews::canvas(Key key, const ParsedJob& view) {
  recent_.remove(key);
  recent_.push_front(key);
  while (recent_.size() > keep_) {
    canvases_.erase(recent_.back());
    recent_.pop_back();
  }
  auto [it, made] = canvases_.try_emplace(key);
  Canvas& c = it->second;
  if (made) {
    const int w = view.shot.width * view.shot.camera.views.x;
    const int h = view.shot.height * view.shot.camera.views.y;
    c.scale = std::min(1.0, double(maxEdge_) / std::max({w, h, 1}));
    c.width = std::max(1, static_cast<int>(w * c.scale));
    c.height = std::max(1, static_cast<int>(h * c.scale));
    c.sum.assign(size_t(c.width) * c.height * 3, 0.0f);
    c.count.assign(size_t(c.width) * c.height, 0.0f);
  }
  return c;
}

// Adds the tile's pixels to the canvas: rectangle r of the tile is rows [sum of the heights
// before it, + its height) of the file, left-aligned (frame_assembly.h).
void FramePreviews::draw(Canvas& c, const Image& image, const FarmTile& rects) {
  const auto rgb = detail::rgbChannelIndices(image);
  const int channels = image.channelCount();
  int row = 0;
  for (const TileRect& r : rects) {
    for (int y = 0; y < r.height() && row + y < image.height(); ++y) {
      const int cy = std::min(c.height - 1, static_cast<int>((r.y0 + y) * c.scale));
      for (int x = 0; x < r.width() && x < image.width(); ++x) {
        const int cx = std::min(c.width - 1, static_cast<int>((r.x0 + x) * c.scale));
        const float* p = &image.pixels()[(size_t(row + y) * image.width() + x) * channels];
        const size_t at = size_t(cy) * c.width + cx;
        for (int k = 0; k < 3; ++k) {
          // A non-finite pixel must not blacken its whole canvas cell's neighbours' sums.
          const float v = p[rgb[k]];
          c.sum[at * 3 + k] += std::isfinite(v) ? v : 0.0f;
        }
        c.count[at] += 1.0f;
      }
    }
    row += r.height();
  }
}

absl::StatusOr<std::string> FramePreviews::encode(const Canvas& c, const std::string& what) {
  Image image(c.width, c.height, {"R", "G", "B"});
  for (size_t p = 0; p < c.count.size(); ++p) {
    const float n = std::max(c.count[p], 1.0f);
    for (int k = 0; k < 3; ++k) image.pixels()[p * 3 + k] = c.sum[p * 3 + k] / n;
  }
  return encodePreviewPng(image, what, ocioConfig_);
}

absl::StatusOr<std::string> FramePreviews::frame(int64_t job, const ParsedJob& view,
                                                 const std::string& workDir, int frame,
                                                 bool assembled,
                                                 const std::vector<int>& doneTiles) {
  std::lock_guard lock(mutex_);
  Canvas& c = canvas({job, frame}, view);
  const std::string what = fmt::format("job {} frame {}", job, frame);
  if (assembled && !c.assembled) {
    const std::string path = ParsedJobCache::frameOutput(view, frame);
    PBGI_ASSIGN_OR_RETURN(const Image image, readImage(path));
    std::fill(c.sum.begin(), c.sum.end(), 0.0f);
    std::fill(c.count.begin(), c.count.end(), 0.0f);
    draw(c, image, {TileRect{0, 0, image.width(), image.height()}});
    c.assembled = true;
    c.png.clear();
  }
  if (!c.assembled) {
    bool added = false;
    for (const int t : doneTiles) {
      if (t < 0 || static_cast<size_t>(t) >= view.tiles.size() || c.drawn.contains(t)) continue;
      // A tile that cannot be read (written on another machine, or removed) stays black.
      auto image = readImage(farmTilePath(workDir, frame, t));
      if (image.ok()) {
        draw(c, *image, view.tiles[static_cast<size_t>(t)]);
        c.drawn.insert(t);
        added = true;
      }
    }
    if (c.drawn.empty()) {
      return absl::NotFoundError(fmt::format(
          "{}: no tile of it can be read here yet (done: {})", what, doneTiles.size()));
    }
    if (added) c.png.clear();
  }
  if (c.png.empty()) {
    PBGI_ASSIGN_OR_RETURN(c.png, encode(c, what));
  }
  return c.png;
}

absl::StatusOr<std::string> FramePreviews::tile(const std::string& workDir, int frame, int tile) {
  const std::string path = farmTilePath(workDir, frame, tile);
  PBGI_ASSIGN_OR_RETURN(Image image, readImage(path));
  return encodePreviewPng(image, path, ocioConfig_);
}

}  // namespace pbgi::farm
