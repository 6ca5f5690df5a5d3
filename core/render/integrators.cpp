#include "core/render/integrators.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "core/bake/surfel_bounce.h"
#include "core/render/pbgi_integrator.h"
#include "core/render/pbgi_receiver.h"
#include "core/render/renderer.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr double kFourPi = 4.0 * 3.14159265358979323846;

// ---- path ---------------------------------------------------------------------------------

std::unique_ptr<Integrator> createPath(const IntegratorContext& c) {
  return std::make_unique<PathIntegrator>(
      c.scene, PathTracerSettings{c.settings.maxDepth, c.settings.rouletteDepth});
}

// ---- pbgi ---------------------------------------------------------------------------------

const std::vector<ParamSpec>& pbgiParams() {
  static const std::vector<ParamSpec> specs = {
      {.key = "gather", .type = ParamType::kChoice, .choices = {"bidirectional", "per-pixel"},
       .defaultText = "bidirectional",
       .help = "how diffuse receivers gather: one bidirectional cut per block of pixels, or a "
               "microbuffer per pixel"},
      {.key = "glossy_gather", .type = ParamType::kChoice,
       .choices = {"adaptive", "warped", "product", "traced"},
       .defaultText = "product",
       .help = "how glossy receivers gather: a quadtree microbuffer refined by the BSDF and the "
               "light, one warped by the BSDF, the light gathered once per footprint and "
               "reflected by the wavelet product with each sample's BSDF (lobes too narrow for "
               "its cube by the quadtree), or rays drawn from each sample's BSDF that read the "
               "tree's light where they land (glossy_rays of them)"},
      {.key = "glossy_rays", .type = ParamType::kInt, .lo = 1, .hi = 1024, .defaultText = "8",
       .help = "traced glossy gather: BSDF-sampled rays per camera sample on a glossy surface"},
      {.key = "quality", .type = ParamType::kChoice, .choices = {"draft", "default", "high"},
       .defaultText = "default", .help = "preset of every threshold below"},
      {.key = "light_solid_angle", .type = ParamType::kFloat, .lo = 0.0, .hi = kFourPi,
       .defaultText = "the preset's",
       .help = "bidirectional: eps_L, largest SH projected solid angle (sr) of a light cluster"},
      {.key = "light_bound", .type = ParamType::kFloat, .lo = 0.0, .hi = kFourPi,
       .defaultText = "the preset's",
       .help = "bidirectional: eps~_L, largest solid angle (sr) of a light cluster's bounding "
               "sphere"},
      {.key = "receiver_bound", .type = ParamType::kFloat, .lo = 0.0, .hi = kFourPi,
       .defaultText = "the preset's",
       .help = "bidirectional: eps~_E, largest solid angle (sr) of a receiver cluster's bounding "
               "sphere seen from the light"},
      {.key = "normal_angle_deg", .type = ParamType::kFloat, .lo = 0.0, .hi = 180.0,
       .defaultText = "the preset's",
       .help = "bidirectional: alpha, widest half-angle (degrees) of a receiver cluster's normals"},
      {.key = "near_rays", .type = ParamType::kInt, .lo = 0, .hi = kMaxNearRays,
       .defaultText = "the preset's",
       .help = "bidirectional: rays per record that take the light of what lies within four "
               "surfel radii from the surfaces they meet (0: those surfels, as disks)"},
      {.key = "cluster_rays", .type = ParamType::kInt, .lo = 1, .hi = kMaxClusterRays,
       .defaultText = "the preset's",
       .help = "bidirectional: shadow rays, each from its own part of the records under a "
               "receiver cluster, that decide a light cluster's light there (more: smaller "
               "patches' contrast)"},
      {.key = "light_samples", .type = ParamType::kInt, .lo = 1, .hi = 1024, .defaultText = "16",
       .help = "light samples for the direct light at each camera sample's first hit (a camera "
               "sample costs a gather; a light sample is one shadow ray)"},
      {.key = "glossy_bsdf_samples", .type = ParamType::kInt, .lo = 1, .hi = 1024,
       .defaultText = "16",
       .help = "BSDF samples for the direct light at a camera sample's first hit on a rough "
               "conductor (a near-mirror lobe reflects a small light through them; each is one "
               "ray)"},
      {.key = "cut_block", .type = ParamType::kInt, .lo = 8, .hi = 1024, .defaultText = "64",
       .help = "bidirectional: pixels a side of the blocks whose samples share one cut"},
      {.key = "record_spacing", .type = ParamType::kInt, .lo = 1, .hi = 8, .defaultText = "2",
       .help = "bidirectional: pixels between the records that gather (1: a record per pixel "
               "footprint; n: on every nth pixel of each axis, the pixels between interpolating "
               "the records on their surface, and gathering their own where none is)"},
      {.key = "sky", .type = ParamType::kChoice, .choices = {"records", "samples"},
       .defaultText = "records",
       .help = "environment light on diffuse surfaces: once per record (or per-pixel gather), "
               "one ray per cell of a cube map, shared by every sample that reads it; or light "
               "samples at each camera sample, as the path tracer takes it"},
      {.key = "cut_blocks_together", .type = ParamType::kInt, .lo = 1, .hi = 64,
       .defaultText = "16",
       .help = "bidirectional: blocks whose cuts sweep the tree's pages together (more: each "
               "page loaded once for more of them; fewer: less memory); never changes pixels"},
      {.key = "max_solid_angle", .type = ParamType::kFloat, .lo = 0.0, .hi = kFourPi,
       .loOpen = true, .defaultText = "the preset's",
       .help = "per-pixel: largest solid angle (sr) splatted as one cluster"},
      {.key = "microbuffer_resolution", .type = ParamType::kInt, .lo = 1,
       .hi = kMaxMicrobufferResolution, .defaultText = "the preset's",
       .help = "per-pixel and warped glossy: microbuffer pixels per cube face side"},
      {.key = "gathers_per_pixel", .type = ParamType::kInt, .lo = 1, .hi = 64, .defaultText = "4",
       .help = "most microbuffer gathers the samples of one pixel make"},
      {.key = "cache_mb", .type = ParamType::kInt, .lo = 1, .hi = 1 << 24, .defaultText = "256",
       .help = "tree page cache budget in MiB"},
      {.key = "bake_points", .type = ParamType::kInt, .lo = 1000, .hi = 1e11,
       .defaultText = "1000000", .help = "surfels per frame in the bake"},
      {.key = "bake_bounces", .type = ParamType::kInt, .lo = 0, .hi = 16, .defaultText = "3",
       .help = "indirect bounces baked into the tree"},
      {.key = "bake_quality", .type = ParamType::kChoice, .choices = {"draft", "default", "high"},
       .defaultText = "draft", .help = "gather preset of the baked bounces"},
      {.key = "bake_wavelet_error", .type = ParamType::kFloat, .lo = 0.0, .hi = 0.99,
       .defaultText = "0.2",
       .help = "glossy light: relative L2 error each tree node's wavelet vector is coded within"},
      {.key = "bake_wavelet_resolution", .type = ParamType::kChoice,
       .choices = {"4", "8", "16", "32", "64"}, .defaultText = "16",
       .help = "glossy light: texels a side of each face of a glossy surfel's cube map"},
  };
  return specs;
}

PbgiSettings pbgiSettings(const RenderSettings& r) {
  const IntegratorParams& p = r.params;
  PbgiSettings s;
  s.gather = p.choiceOr("gather", "bidirectional") == "per-pixel" ? PbgiGatherKind::kPerPixel
                                                                  : PbgiGatherKind::kBidirectional;
  const std::string quality = p.choiceOr("quality", "default");
  s.perPixel = *gatherPreset(quality);
  s.perPixel.maxSolidAngle = static_cast<float>(p.floatOr("max_solid_angle", s.perPixel.maxSolidAngle));
  s.perPixel.resolution = static_cast<int>(p.intOr("microbuffer_resolution", s.perPixel.resolution));
  s.glossy = glossyGatherOptions(s.perPixel);
  const std::string glossy = p.choiceOr("glossy_gather", "product");
  s.glossyGather = glossy == "warped"    ? GlossyGatherKind::kWarped
                   : glossy == "product" ? GlossyGatherKind::kProduct
                   : glossy == "traced"  ? GlossyGatherKind::kTraced
                                         : GlossyGatherKind::kAdaptive;
  s.glossyRays = static_cast<int>(p.intOr("glossy_rays", 8));
  s.adaptive = adaptiveGatherOptions(s.perPixel);
  s.product = productGatherOptions(s.perPixel);
  s.maxGathersPerPixel = static_cast<int>(p.intOr("gathers_per_pixel", 4));
  s.cut = *cutPreset(quality);
  s.cut.lightSolidAngle = static_cast<float>(p.floatOr("light_solid_angle", s.cut.lightSolidAngle));
  s.cut.lightBound = static_cast<float>(p.floatOr("light_bound", s.cut.lightBound));
  s.cut.receiverBound = static_cast<float>(p.floatOr("receiver_bound", s.cut.receiverBound));
  s.cut.normalAngle = radians(
      static_cast<float>(p.floatOr("normal_angle_deg", degrees(s.cut.normalAngle))));
  s.cut.nearRays = static_cast<int>(p.intOr("near_rays", s.cut.nearRays));
  s.cut.clusterRays = static_cast<int>(p.intOr("cluster_rays", s.cut.clusterRays));
  s.blockSize = static_cast<int>(p.intOr("cut_block", 64));
  s.recordSpacing = static_cast<int>(p.intOr("record_spacing", 2));
  s.skyAtRecords = p.choiceOr("sky", "records") == "records";
  s.blocksPerUnit = static_cast<int>(p.intOr("cut_blocks_together", 16));
  s.pathTracer = {.maxDepth = r.maxDepth,
                  .rouletteDepth = r.rouletteDepth,
                  .firstHitLightSamples = static_cast<int>(p.intOr("light_samples", 16)),
                  .firstHitBsdfSamples = static_cast<int>(p.intOr("glossy_bsdf_samples", 16))};
  return s;
}

absl::Status validatePbgi(const RenderSettings& r) {
  const PbgiSettings s = pbgiSettings(r);
  if (s.cut.lightSolidAngle > s.cut.lightBound) {
    // One of the two was set (the presets agree with themselves); the error is where.
    const ParamValue* set = r.params.find("light_solid_angle");
    if (set == nullptr) set = r.params.find("light_bound");
    return absl::InvalidArgumentError(fmt::format(
        "{}: 'light_solid_angle' {:g} exceeds 'light_bound' {:g}: the bounding sphere's test is "
        "the weaker one, so eps_L <= eps~_L",
        set != nullptr ? set->where.toString() : std::string("[render]"), s.cut.lightSolidAngle,
        s.cut.lightBound));
  }
  if (absl::Status st = s.perPixel.validate(); !st.ok()) return st;
  if (absl::Status st = s.glossy.validate(); !st.ok()) return st;
  if (absl::Status st = s.adaptive.validate(); !st.ok()) return st;
  return s.cut.validate();
}

TreeSettings pbgiTreeSettings(const RenderSettings& r) {
  TreeSettings t;
  t.cacheBytes = static_cast<size_t>(r.params.intOr("cache_mb", 256)) << 20;
  // Both gathers sweep the tree's pages in step: the cut across a unit's blocks, per-pixel
  // gathers across a batch of a tile's.
  t.cachePolicy = PageCachePolicy::kLeastRecent;
  t.bakePoints = static_cast<uint64_t>(r.params.intOr("bake_points", 0));
  t.bakeBounces = static_cast<int>(r.params.intOr("bake_bounces", 3));
  t.bakeCut = *bounceCutPreset(r.params.choiceOr("bake_quality", "draft"));
  t.bakeWaveletError = static_cast<float>(r.params.floatOr("bake_wavelet_error", 0.2));
  t.bakeWaveletResolution = std::stoi(r.params.choiceOr("bake_wavelet_resolution", "16"));
  return t;
}

std::string describePbgi(const RenderSettings& r) {
  const PbgiSettings s = pbgiSettings(r);
  if (s.gather == PbgiGatherKind::kPerPixel) return "per-pixel " + s.perPixel.toString();
  return fmt::format("bidirectional {} block={}", s.cut.toString(), s.blockSize);
}

constexpr std::array<CounterSpec, kPbgiCounterCount> kPbgiCounters = {{
    {"black_receivers", "samples whose first hit reflects nothing: no gather"},
    {"path_traced_receivers", "mirrors and glass: path traced"},
    {"gathers",
     "gathers: diffuse receivers (per-pixel microbuffers, or the cut's shading points) and glossy "
     "microbuffers"},
    {"gather_reuses", "samples that took an earlier gather of their pixel"},
    {"glossy_gathers",
     "of the gathers, a glossy receiver's (its microbuffer, or the product's cube)"},
    {"glossy_products", "glossy samples reflected by the wavelet product with their BSDF"},
    {"glossy_products_skipped",
     "glossy samples whose BSDF slices reflect nothing towards the camera: no product gather"},
    {"glossy_narrow_lobes",
     "glossy samples whose lobe is too narrow for the product's cube: the adaptive gather"},
    {"glossy_as_diffuse",
     "rough glossy samples whose lobe the tree's SH hold: the diffuse gather, by their "
     "directional albedo"},
    {"glossy_traced_rays", "traced glossy gather: BSDF-sampled rays"},
    {"glossy_traced_unread",
     "traced glossy gather: rays that met a surface with no surfel of the tree near the hit (or "
     "a mirror, glass or a light): no light"},
    {"nodes_visited", "microbuffer traversals: nodes visited"},
    {"culled_plane", "nodes behind the receiver's tangent plane"},
    {"clusters", "nodes splatted as clusters"},
    {"clusters_invisible", "small nodes with no projected area towards the receiver"},
    {"disks", "surfels splatted as disks"},
    {"near_field", "surfels ray-cast in the near field"},
    {"surfels_skipped", "surfels on the receiver's own surface"},
    {"surfels_back_facing", "surfels seen from behind: their back side gathered"},
    {"pages_touched", "pages the microbuffer traversals asked for"},
    {"faces_skipped", "microbuffer faces below the horizon"},
    {"pixels_skipped", "microbuffer pixels below the horizon"},
#define PBGI_CUT_COUNTER_SPEC(member, counter, name, what) {name, what},
    PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_SPEC)
#undef PBGI_CUT_COUNTER_SPEC
        {"sky_rays",
         "rays towards the environment from records (one per cube-map cell above each)"},
}};
// One spec per PbgiCounter, in its order: a counter left out here would leave the last unnamed.
static_assert(std::ranges::none_of(kPbgiCounters,
                                   [](const CounterSpec& c) { return c.name.empty(); }));

const std::vector<IntegratorInfo>& registry() {
  static const std::vector<IntegratorInfo> list = {
      IntegratorInfo{
          .name = "path",
          .summary = "the reference: unidirectional path tracing with next-event estimation "
                     "and MIS",
          .params = {},
          .counters = {},
          .needsTree = false,
          .validate = [](const RenderSettings&) { return absl::OkStatus(); },
          .create = createPath,
          .treeSettings = nullptr,
          .describe =
              [](const RenderSettings& r) {
                return fmt::format("path(max_depth={} roulette_depth={})", r.maxDepth,
                                   r.rouletteDepth);
              },
      },
      IntegratorInfo{
          .name = "pbgi",
          .summary = "point-based global illumination from the frame's baked tree: the "
                     "bidirectional cut (default) or the per-pixel microbuffer gather",
          .params = pbgiParams(),
          .counters = kPbgiCounters,
          .needsTree = true,
          .validate = validatePbgi,
          .create =
              [](const IntegratorContext& c) {
                return makePbgiIntegrator(c.scene, *c.tree, pbgiSettings(c.settings));
              },
          .treeSettings = pbgiTreeSettings,
          .describe = describePbgi,
      },
  };
  return list;
}

}  // namespace

std::span<const CounterSpec> pbgiCounterSpecs() { return kPbgiCounters; }

const ParamSpec* IntegratorInfo::param(std::string_view key) const {
  for (const ParamSpec& p : params) {
    if (p.key == key) return &p;
  }
  return nullptr;
}

const std::vector<IntegratorInfo>& integrators() { return registry(); }

std::vector<std::string_view> integratorNames() {
  std::vector<std::string_view> names;
  for (const IntegratorInfo& i : integrators()) names.push_back(i.name);
  return names;
}

absl::StatusOr<const IntegratorInfo*> findIntegrator(std::string_view name,
                                                     const SourceLocation& where) {
  for (const IntegratorInfo& i : integrators()) {
    if (i.name == name) return &i;
  }
  const std::string prefix = where.file.empty() ? std::string() : where.toString() + ": ";
  return absl::InvalidArgumentError(fmt::format("{}integrator '{}' unknown (expected one of: {})",
                                                prefix, name, fmt::join(integratorNames(), ", ")));
}

const ParamSpec* findParam(std::string_view key, std::vector<std::string_view>* owners) {
  const ParamSpec* found = nullptr;
  for (const IntegratorInfo& i : integrators()) {
    if (const ParamSpec* p = i.param(key)) {
      if (found == nullptr) found = p;
      if (owners) owners->push_back(i.name);
    }
  }
  return found;
}

std::vector<std::string_view> allParamKeys() {
  std::vector<std::string_view> keys;
  for (const IntegratorInfo& i : integrators()) {
    for (const ParamSpec& p : i.params) keys.push_back(p.key);
  }
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  return keys;
}

namespace {

absl::Status unknownParam(std::string_view key, const SourceLocation& where) {
  return absl::InvalidArgumentError(
      fmt::format("{}: unknown parameter '{}' (integrator parameters: {})", where.toString(), key,
                  fmt::join(allParamKeys(), ", ")));
}

}  // namespace

absl::Status setParamText(IntegratorParams& params, std::string_view key, std::string_view value,
                          const SourceLocation& where) {
  const ParamSpec* spec = findParam(key);
  if (spec == nullptr) return unknownParam(key, where);
  return params.setText(*spec, value, where);
}

absl::Status setParamValue(IntegratorParams& params, std::string_view key, ParamValue value) {
  const ParamSpec* spec = findParam(key);
  if (spec == nullptr) return unknownParam(key, value.where);
  return params.set(*spec, std::move(value));
}

absl::Status validateRenderSettings(const RenderSettings& settings,
                                    std::vector<std::string>* unused) {
  absl::StatusOr<const IntegratorInfo*> info =
      findIntegrator(settings.integrator, settings.integratorWhere);
  if (!info.ok()) return info.status();
  for (const auto& [key, value] : settings.params.values()) {
    if ((*info)->param(key) != nullptr) continue;
    std::vector<std::string_view> owners;
    if (findParam(key, &owners) == nullptr) return unknownParam(key, value.where);
    if (unused) {
      unused->push_back(fmt::format("{}: '{}' is a parameter of {}, not of the {} integrator: "
                                    "ignored in this render",
                                    value.where.toString(), key, fmt::join(owners, ", "),
                                    settings.integrator));
    }
  }
  return (*info)->validate(settings);
}

absl::Status applyRenderOverrides(RenderSettings& settings, const RenderOverrides& overrides) {
  if (!overrides.integrator.empty()) {
    settings.integrator = overrides.integrator;
    settings.integratorWhere = overrides.integratorWhere;
  }
  if (overrides.spp > 0) settings.spp = overrides.spp;
  for (const auto& [key, value] : overrides.params.values()) {
    PBGI_RETURN_IF_ERROR(setParamValue(settings.params, key, value));
  }
  return validateRenderSettings(settings);
}

absl::Status applyShotOverrides(ShotDesc& shot, const RenderOverrides& overrides) {
  if (overrides.width > 0 || overrides.height > 0) {
    PBGI_RETURN_IF_ERROR(checkImageSize(overrides.width, overrides.height, shot.camera.views,
                                        "resolution override"));
    shot.width = overrides.width;
    shot.height = overrides.height;
  }
  if (overrides.seed) shot.render.seed = *overrides.seed;
  if (overrides.output) {
    if (overrides.output->aovs) PBGI_RETURN_IF_ERROR(checkAovs(*overrides.output->aovs));
    shot.outputOptions = *overrides.output;
  }
  return applyRenderOverrides(shot.render, overrides);
}

}  // namespace pbgi
