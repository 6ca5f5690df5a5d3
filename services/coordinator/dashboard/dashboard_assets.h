#pragma once
// The dashboard's page, script and style (services/coordinator/dashboard/), compiled into the
// coordinator at build time (services/embed_assets.cmake writes dashboard_assets.cpp), so that
// a coordinator serves them wherever it is installed, without the repository.
#include <string_view>
#include <vector>

namespace pbgi::farm {

struct DashboardAsset {
  std::string_view name;         // "index.html", "dashboard.js", ...
  std::string_view contentType;  // "text/html; charset=utf-8", ...
  std::string_view content;
};

const std::vector<DashboardAsset>& dashboardAssets();

}  // namespace pbgi::farm
