#pragma once
// Reading and writing images. OpenEXR output is written to a temporary file in the same
// folder and renamed, so a reader never sees a partial file.

#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/render/image.h"
#include "core/scene/texture.h"

namespace pbgi {

// Writes every channel of `image` as 32-bit float into one OpenEXR part, with the image's
// metadata as EXR attributes and its window as the data window inside the display window.
// Channel names are EXR layer names ("albedo.R").
// `compression` is one of exrCompressions() (OpenEXR's names); ZIP by default.
absl::Status writeExr(const Image& image, const std::string& path,
                      const std::string& compression = "zip");
// OpenEXR's compressions as OIIO names them: none, rle, zips, zip, piz, pxr24, b44, b44a,
// dwaa, dwab.
const std::vector<std::string>& exrCompressions();
// InvalidArgument naming `where` (a flag) and the known names unless `name` is one of them.
absl::Status checkExrCompression(const std::string& name, const std::string& where);

// What a render's output path asks for, by its extension (any case): OpenEXR (.exr: every
// channel as float, with the metadata), the beauty's colour in float (.tif, .tiff, .hdr), or
// 8-bit through the OCIO view like the preview (.png, .jpg, .jpeg). InvalidArgument naming
// the path and the known extensions for any other.
enum class OutputFormat { kExr, kFloatRgb, kDisplay8 };
absl::StatusOr<OutputFormat> outputFormatFor(const std::string& path);
// Writes a render to `path` in the format its extension names; what that format cannot hold
// (AOVs, metadata, the high dynamic range) is said in `warnings`.
absl::Status writeRender(const Image& image, const std::string& path, const std::string& ocioConfig,
                         std::vector<std::string>* warnings,
                         const std::string& exrCompression = "zip");

// Reads any image OIIO can read (EXR, PNG, JPEG, ...) into float channels with its metadata;
// its pixels are the data window's, whose place in the display window is the image's window.
absl::StatusOr<Image> readImage(const std::string& path);

// Reads a lat-long environment map (RGB of the first three channels).
absl::StatusOr<LatLongImage> readLatLong(const std::string& path);

// Writes an 8-bit sRGB PNG preview of the image's R, G, B channels, converted from the
// scene-linear colour space to the display through the OCIO config at `ocioConfig`.
absl::Status writePreviewPng(const Image& image, const std::string& path,
                             const std::string& ocioConfig);
// The same preview as PNG bytes in memory (a page serves them without a file); `what` names it
// in errors.
absl::StatusOr<std::string> encodePreviewPng(const Image& image, const std::string& what,
                                             const std::string& ocioConfig);

}  // namespace pbgi
