#pragma once
// A log-log line plot written as PNG: how the accuracy tools show error against run time.
// Axes span the data's decades; each series is a polyline with a marker per point and a
// legend entry. Labels need a TrueType font (DejaVu Sans, Debian's fonts-dejavu-core); without
// one the plot is drawn without text and the call says so in `warning`.
#include <string>
#include <utility>
#include <vector>

#include <absl/status/status.h>

#include "core/math/vec.h"

namespace pbgi {

struct PlotSeries {
  std::string name;
  Rgb color{1.0f};
  std::vector<std::pair<double, double>> points;  // (x, y), both > 0; others are skipped
};

struct PlotOptions {
  std::string title;
  std::string xLabel;
  std::string yLabel;
  int width = 960;
  int height = 640;
};

// Writes the plot atomically. InvalidArgument when no series has a positive point; the
// writer's error otherwise. `warning` (may be null) receives why labels are missing.
absl::Status writeLogLogPlot(const std::vector<PlotSeries>& series, const PlotOptions& options,
                             const std::string& path, std::string* warning = nullptr);

}  // namespace pbgi
