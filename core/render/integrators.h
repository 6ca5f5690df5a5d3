#pragma once
// The integrators this build has, by name: the one place that says which integrators exist,
// the parameters each takes (typed, range-checked, validated by the integrator itself), the
// counters each keeps, and what each needs (a baked tree, and so a bake task on the farm; a
// fixed grid of blocks). The shot parser, the command line, the render service, the workers
// and the coordinator all ask here; nothing else compares an integrator's name.
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/statusor.h>

#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/page_cache.h"
#include "core/pbgi/tree_page.h"
#include "core/render/integrator.h"
#include "core/scene/integrator_params.h"
#include "core/scene/scene.h"
#include "core/scene/shot.h"

namespace pbgi {

// What an integrator that renders from a frame's baked PBGI tree needs of it.
struct TreeSettings {
  size_t cacheBytes = size_t{256} << 20;  // the page cache's budget
  PageCachePolicy cachePolicy = PageCachePolicy::kLeastUsed;  // what suits the traversal
  uint64_t bakePoints = 0;                 // surfels; 0: the baker's default
  int bakeBounces = 3;
  CutOptions bakeCut;                      // how the bake's bounces gather
  float bakeWaveletError = 0.2f;           // glossy light: each wavelet vector's coding error
  int bakeWaveletResolution = 16;          // glossy light: cube-map texels a face side
};

struct IntegratorContext {
  const Scene& scene;
  const RenderSettings& settings;  // the shot's, with overrides applied
  TreePageSource* tree = nullptr;  // the frame's tree, for integrators that need one
};

struct IntegratorInfo {
  std::string_view name;
  std::string_view summary;
  std::span<const ParamSpec> params;
  std::span<const CounterSpec> counters;
  bool needsTree = false;  // renders from the frame's baked PBGI tree
  // The parameters as the integrator reads them, cross-checked: InvalidArgument naming where
  // an offending value was set. Called before anything is loaded.
  std::function<absl::Status(const RenderSettings&)> validate;
  // Only with settings that validate (and a tree when needsTree).
  std::function<std::unique_ptr<Integrator>(const IntegratorContext&)> create;
  // needsTree integrators: the page cache and the bake their settings ask for.
  std::function<TreeSettings(const RenderSettings&)> treeSettings;
  // A line for logs and EXR metadata: the gather and its thresholds.
  std::function<std::string(const RenderSettings&)> describe;

  const ParamSpec* param(std::string_view key) const;
};

const std::vector<IntegratorInfo>& integrators();

// The integrator called `name`; InvalidArgument "integrator 'x' unknown (known: path, pbgi)"
// prefixed by `where` when it has a file.
absl::StatusOr<const IntegratorInfo*> findIntegrator(std::string_view name,
                                                     const SourceLocation& where = {});
// The names, for help and messages.
std::vector<std::string_view> integratorNames();

// The declaration of `key` in any integrator (nullptr when none declares it), and the names of
// the integrators that declare it.
const ParamSpec* findParam(std::string_view key, std::vector<std::string_view>* owners = nullptr);
// Every key some integrator declares, sorted, for "expected one of".
std::vector<std::string_view> allParamKeys();

// Sets a parameter from text (`--set key=value`, a farm override, a named flag): the key must
// be declared by some integrator; `where` names the flag or override in errors.
absl::Status setParamText(IntegratorParams& params, std::string_view key, std::string_view value,
                          const SourceLocation& where);
// Sets a typed value (a farm job's, from its wire or its store): the key must be declared,
// the value of its type and in its range.
absl::Status setParamValue(IntegratorParams& params, std::string_view key, ParamValue value);

// Full check of settings against the integrator they name: the integrator exists, and its
// validate() passes. Parameters of other integrators are allowed (a PBGI shot rendered with
// --integrator path keeps its PBGI settings); `unused` receives a warning for each.
absl::Status validateRenderSettings(const RenderSettings& settings,
                                    std::vector<std::string>* unused = nullptr);

// `overrides` applied to `settings`, then the full check above. The parameters' values were
// checked against their declarations when they were set.
absl::Status applyRenderOverrides(RenderSettings& settings, const RenderOverrides& overrides);
// The same for a shot: its render settings, and its resolution, seed and output options.
absl::Status applyShotOverrides(ShotDesc& shot, const RenderOverrides& overrides);

// The PBGI integrator's counters (core/render/pbgi_receiver.h indexes them).
std::span<const CounterSpec> pbgiCounterSpecs();

}  // namespace pbgi
