#pragma once
// What the coordinator and its workers agree on about a job without asking each other: where
// its files live under the coordinator's state folder, how a frame splits into farm tiles,
// and how a job's overrides change the shot it was submitted with.
//
//   <state>/jobs/<job>/bake/<image stem>.pbgi      the frame's bake (tiles read it)
//   <state>/jobs/<job>/frame.<NNNN>/tile.<TTTT>.exr   a tile, committed by rename; tile t
//                                                    is makeTiles(width, height, tile size)[t]
//   the shot's output pattern, under the output root   the assembled frame and its preview
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/render/renderer.h"
#include "core/scene/shot.h"

namespace pbgi::farm {

// Tiles large enough that loading the frame's scene is a small part of each.
inline constexpr int kDefaultFarmTileSize = 256;
inline constexpr const char* kDefaultCoordinatorAddress = "127.0.0.1:7411";

std::string jobWorkDir(const std::string& stateDir, int64_t job);
std::string jobBakeDir(const std::string& workDir);
std::string farmTilePath(const std::string& workDir, int frame, int tile);
// The frame's tree in the job's bake folder, where its bake task writes it.
absl::StatusOr<std::string> jobTreePath(const ShotDesc& shot, const std::string& workDir,
                                        int frame);

// The most samples per pixel a job may ask for.
inline constexpr int kMaxOverrideSpp = 1 << 20;

// A job's overrides from "key=value" text (a client or a job store from before they were
// typed): integrator, spp, and any integrator parameter the registry declares (quality,
// gather, cache_mb, bake_points, ...), each parsed and checked against its declaration.
// InvalidArgument names the line and what was expected.
absl::StatusOr<RenderOverrides> parseOverrideLines(const std::vector<std::string>& lines);
// And back, for readers from before the typed form: "integrator=pbgi", "spp=16", "gather=...".
std::vector<std::string> overrideLines(const RenderOverrides& overrides);

// The shot a job renders: the submitted text, parsed as the file at `shotPath`, with the
// job's overrides applied and the result checked by its integrator.
absl::StatusOr<ShotDesc> jobShot(std::string_view shotText, const std::string& shotPath,
                                 const RenderOverrides& overrides);

// The accuracy audit's defaults: tiles per frame (for integrators other than the path tracer;
// a path-traced job is its own reference), the path tracer's samples per pixel on them, and
// the relMSE beyond which a frame is flagged. A 256-spp reference carries noise of its own
// (relMSE about 0.005 on the sample Cornell box), well under the threshold.
inline constexpr int kDefaultAuditTiles = 2;
inline constexpr int kDefaultAuditSpp = 256;
inline constexpr double kDefaultAuditThreshold = 0.05;

// The seeded rule that picks a frame's audited tiles: `count` distinct tiles of `tileCount`
// (all of them when count >= tileCount), from a hash of the shot's name and the frame, so the
// same job audits the same tiles wherever and whenever it is submitted. Sorted.
std::vector<int> chooseAuditTiles(std::string_view shotName, int frame, int tileCount, int count);
// What an audit renders of an audited tile: the central kAuditWindow x kAuditWindow pixels of
// each of its rectangles (all of a smaller one), so that an audit costs the same few seconds
// whatever the farm's tile size.
inline constexpr int kAuditWindow = 64;
std::vector<TileRect> auditWindows(const std::vector<TileRect>& tile);

// `path`, made absolute and normal, when it lies inside `root` (symbolic links resolved as far
// as they exist); PermissionDenied naming both otherwise.
absl::StatusOr<std::string> confineToRoot(const std::string& path, const std::string& root);

}  // namespace pbgi::farm
