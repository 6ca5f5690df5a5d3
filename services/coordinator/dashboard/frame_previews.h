#pragma once
// Pictures of frames while they render, for the dashboard: a frame's preview is its assembled
// EXR once written, and before that the tiles done so far, each read from its file once and
// box-filtered into a small canvas, the rest black. Both are PNGs in memory through the OCIO
// config's display view (formats/image/image_io.h). Tiles and frames live under the
// coordinator's state folder and output root; on a farm whose workers write elsewhere there is
// nothing to show and the preview says so (NotFound).
#include <cstdint>
#include <list>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <absl/status/statusor.h>

#include "services/coordinator/parsed_job_cache.h"

namespace pbgi::farm {

class FramePreviews {
 public:
  // Previews are at most `maxEdge` pixels on their longer side; `keep` frames are kept.
  FramePreviews(std::string ocioConfig, int maxEdge = 512, size_t keep = 32);

  // The frame's PNG: its assembled output when `assembled`, else its tiles in `doneTiles`
  // (indices into view.tiles) over black. NotFound when there is nothing to show yet.
  absl::StatusOr<std::string> frame(int64_t job, const ParsedJob& view, const std::string& workDir,
                                    int frame, bool assembled, const std::vector<int>& doneTiles);
  // One done tile's PNG, its rectangles stacked as in its file.
  absl::StatusOr<std::string> tile(const std::string& workDir, int frame, int tile);

 private:
  struct Canvas {
    int width = 0, height = 0;
    double scale = 1.0;             // canvas pixels per frame pixel
    std::vector<float> sum;         // RGB sums per canvas pixel
    std::vector<float> count;       // frame pixels summed into each
    std::set<int> drawn;            // tiles already in the sums
    bool assembled = false;
    std::string png;                // encoded for `drawn` (or the assembled frame)
  };
  using Key = std::pair<int64_t, int>;  // job, frame

  Canvas& canvas(Key key, const ParsedJob& view);
  static void draw(Canvas& c, const Image& image, const FarmTile& rects);
  absl::StatusOr<std::string> encode(const Canvas& c, const std::string& what);

  const std::string ocioConfig_;
  const int maxEdge_;
  const size_t keep_;
  std::mutex mutex_;
  std::map<Key, Canvas> canvases_;
  std::list<Key> recent_;  // most recent first
};

}  // namespace pbgi::farm
