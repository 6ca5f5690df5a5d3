#pragma once
// A coordinator with nothing to do, started in this process: what its /metrics text declares
// and serves, for tests that hold a deployment file (dashboards, autoscalers) against it.
#include <string>

#include <absl/status/statusor.h>

#include "services/coordinator/coordinator.h"
#include "tests/support/test_paths.h"

namespace pbgi::testing {

inline absl::StatusOr<std::string> idleCoordinatorMetrics(const std::string& tag) {
  const std::filesystem::path dir = makeTempDir(tag);
  farm::CoordinatorOptions options;
  options.stateDir = (dir / "state").string();
  options.outputRoot = dir.string();
  options.token = tag;
  auto coordinator = farm::Coordinator::start(options);
  if (!coordinator.ok()) return coordinator.status();
  return (*coordinator)->metricsText();
}

}  // namespace pbgi::testing
