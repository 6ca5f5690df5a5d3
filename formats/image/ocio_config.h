#pragma once
// Where the OCIO config that pbgi ships (config/ocio/config.ocio) is found at run time.

#include <string>

namespace pbgi {

// $OCIO when it is set and not empty (the convention every OCIO application follows, so an
// artist's studio config wins), else `<folder of the running executable>/../share/pbgi/ocio/
// config.ocio` when that file exists (the build tree and an install both put it there), else
// an empty string; writePreviewPng turns an empty path into an error that says what to set.
std::string defaultOcioConfigPath();

}  // namespace pbgi
