#include "formats/image/plot.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <fmt/format.h>

#include "formats/util/atomic_file.h"

namespace pbgi {

namespace {

namespace IBA = OIIO::ImageBufAlgo;

constexpr int kMarginLeft = 90;
constexpr int kMarginRight = 30;
constexpr int kMarginTop = 50;
constexpr int kMarginBottom = 70;
constexpr int kFontSize = 16;
constexpr const char* kFonts[] = {"/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                                  "DejaVuSans"};

struct Range {
  double lo = std::numeric_limits<double>::infinity();
  double hi = 0.0;
  void add(double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  // Whole decades around the data.
  void snap() {
    lo = std::pow(10.0, std::floor(std::log10(lo)));
    hi = std::pow(10.0, std::ceil(std::log10(hi)));
    if (hi <= lo) hi = lo * 10.0;
  }
};

std::string decadeLabel(double v) {
  const int e = static_cast<int>(std::lround(std::log10(v)));
  if (e >= -3 && e <= 4) return fmt::format("{:g}", std::pow(10.0, e));
  return fmt::format("1e{}", e);
}

}  // namespace

absl::Status writeLogLogPlot(const std::vector<PlotSeries>& series, const PlotOptions& options,
                             const std::string& path, std::string* warning) {
  Range xr, yr;
  for (const PlotSeries& s : series) {
    for (const auto& [x, y] : s.points) {
      if (x > 0.0 && y > 0.0 && std::isfinite(x) && std::isfinite(y)) {
        xr.add(x);
        yr.add(y);
      }
    }
  }
  if (xr.hi <= 0.0) return absl::InvalidArgumentError("plot: no series has a positive point");
  xr.snap();
  yr.snap();

  const int w = options.width, h = options.height;
  OIIO::ImageBuf buf(OIIO::ImageSpec(w, h, 3, OIIO::TypeDesc::UINT8));
  const float white[3] = {1.0f, 1.0f, 1.0f};
  const float black[3] = {0.0f, 0.0f, 0.0f};
  const float grid[3] = {0.85f, 0.85f, 0.85f};
  IBA::fill(buf, white);
  const int x0 = kMarginLeft, x1 = w - kMarginRight, y0 = kMarginTop, y1 = h - kMarginBottom;
  auto px = [&](double x) {
    return x0 + static_cast<int>(std::lround((std::log10(x) - std::log10(xr.lo)) /
                                             (std::log10(xr.hi) - std::log10(xr.lo)) * (x1 - x0)));
  };
  auto py = [&](double y) {
    return y1 - static_cast<int>(std::lround((std::log10(y) - std::log10(yr.lo)) /
                                             (std::log10(yr.hi) - std::log10(yr.lo)) * (y1 - y0)));
  };

  // Text, where a font can be found: each string is rasterized on its own (OIIO sizes the
  // buffer to it) and blended in with bounds checks, so text near an edge is clipped.
  std::string font;
  for (const char* candidate : kFonts) {
    if (IBA::text_size("x", kFontSize, candidate).defined()) {
      font = candidate;
      break;
    }
  }
  if (font.empty() && warning) *warning = "no TrueType font found (install fonts-dejavu-core): plot has no labels";
  auto text = [&](int x, int y, const std::string& s, IBA::TextAlignX ax, IBA::TextAlignY ay) {
    if (font.empty() || s.empty()) return;
    // The string's extent around its origin, then a one-channel buffer just that size.
    const OIIO::ROI extent = IBA::text_size(s, kFontSize, font);
    if (!extent.defined() || extent.width() <= 0 || extent.height() <= 0) return;
    const int gw = extent.width(), gh = extent.height();
    OIIO::ImageBuf glyphs(OIIO::ImageSpec(gw, gh, 1, OIIO::TypeDesc::FLOAT));
    const float one = 1.0f;
    if (!IBA::render_text(glyphs, -extent.xbegin, -extent.ybegin, s, kFontSize, font,
                          OIIO::cspan<float>(&one, 1))) {
      return;
    }
    const int left = ax == IBA::TextAlignX::Left ? x : ax == IBA::TextAlignX::Right ? x - gw : x - gw / 2;
    const int top = ay == IBA::TextAlignY::Top ? y : ay == IBA::TextAlignY::Bottom ? y - gh : y - gh / 2;
    float value[4] = {0, 0, 0, 0}, pixel[3];
    for (int j = 0; j < gh; ++j) {
      for (int i = 0; i < gw; ++i) {
        const int px = left + i, py = top + j;
        if (px < 0 || py < 0 || px >= w || py >= h) continue;
        glyphs.getpixel(i, j, value, 1);
        const float a = std::clamp(value[0], 0.0f, 1.0f);
        if (a <= 0.0f) continue;
        buf.getpixel(px, py, pixel, 3);
        for (float& c : pixel) c *= 1.0f - a;  // black text
        buf.setpixel(px, py, pixel, 3);
      }
    }
  };

  for (double d = xr.lo; d <= xr.hi * 1.0001; d *= 10.0) {
    IBA::render_line(buf, px(d), y0, px(d), y1, grid);
    text(px(d), y1 + 8, decadeLabel(d), IBA::TextAlignX::Center, IBA::TextAlignY::Top);
  }
  for (double d = yr.lo; d <= yr.hi * 1.0001; d *= 10.0) {
    IBA::render_line(buf, x0, py(d), x1, py(d), grid);
    text(x0 - 8, py(d), decadeLabel(d), IBA::TextAlignX::Right, IBA::TextAlignY::Center);
  }
  IBA::render_box(buf, x0, y0, x1, y1, black);
  text(w / 2, 12, options.title, IBA::TextAlignX::Center, IBA::TextAlignY::Top);
  text((x0 + x1) / 2, h - 10, options.xLabel, IBA::TextAlignX::Center, IBA::TextAlignY::Bottom);
  text(8, y0 - 10, options.yLabel, IBA::TextAlignX::Left, IBA::TextAlignY::Bottom);

  int legendY = y0 + 12;
  for (const PlotSeries& s : series) {
    const float color[3] = {s.color.x, s.color.y, s.color.z};
    std::vector<std::pair<double, double>> pts;
    for (const auto& p : s.points) {
      if (p.first > 0.0 && p.second > 0.0 && std::isfinite(p.first) && std::isfinite(p.second)) {
        pts.push_back(p);
      }
    }
    std::sort(pts.begin(), pts.end());
    for (size_t i = 0; i < pts.size(); ++i) {
      const int x = px(pts[i].first), y = py(pts[i].second);
      if (i > 0) IBA::render_line(buf, px(pts[i - 1].first), py(pts[i - 1].second), x, y, color);
      IBA::render_box(buf, x - 3, y - 3, x + 3, y + 3, color, true);
    }
    IBA::render_box(buf, x1 - 200, legendY - 4, x1 - 188, legendY + 4, color, true);
    text(x1 - 180, legendY, s.name, IBA::TextAlignX::Left, IBA::TextAlignY::Center);
    legendY += kFontSize + 6;
  }

  auto file = AtomicFile::begin(path);
  if (!file.ok()) return file.status();
  if (!buf.write(file->tempPath(), OIIO::TypeDesc::UINT8, "png")) {
    return absl::InternalError(fmt::format("{}: cannot write the plot: {}", path, buf.geterror()));
  }
  return file->commit();
}

}  // namespace pbgi
