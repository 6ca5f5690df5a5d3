#pragma once
// Setting integrator parameters in tests and benchmarks as a user would, through the registry's
// declarations. A key or value the registry refuses is a mistake in the test itself.
#include <string>
#include <string_view>

#include "core/render/integrators.h"
#include "core/util/check.h"

namespace pbgi::testing {

inline void setParam(IntegratorParams& params, std::string_view key, std::string_view value) {
  const absl::Status s = setParamText(params, key, value, {"test"});
  if (!s.ok()) ::pbgi::detail::checkFailed(__FILE__, __LINE__, std::string(s.message()));
}

}  // namespace pbgi::testing
