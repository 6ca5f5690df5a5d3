#pragma once
// Image textures for the renderer through one process-wide OIIO TextureSystem, which caches
// tiles under a memory cap and is safe to query from many threads.

#include <memory>
#include <string>

#include <absl/status/statusor.h>

#include "core/scene/texture.h"

namespace pbgi {

// Opens an image (PNG, JPEG, OpenEXR, ... anything OIIO reads) as a texture. The file is
// opened and the texels at its centre decoded here (all of an untiled file), so that a
// missing or corrupt texture is an error at load time rather than black texels mid-render:
// NotFound when the path does not exist, InvalidArgument when OIIO cannot read it or its
// header claims more than the cache can hold (sides past 65536, a tile past 1 GiB; an
// untiled file is one tile).
//
// evaluate(uv) is bilinear, without MIP-mapping, periodic in u and v, with v = 0 at the
// bottom row (OBJ convention). Texels are decoded to linear before they are blended, as the
// reference renders were made (Cycles, "bilinear in linear space"):
// the file's "oiio:ColorSpace" says how (sRGB, linear, or a
// PNG gAMA power law); without one, integer formats are sRGB and float formats linear.
// One- and two-channel images are grey (plus alpha); alpha is ignored.
absl::StatusOr<std::shared_ptr<const Texture>> loadImageTexture(const std::string& path);

}  // namespace pbgi
