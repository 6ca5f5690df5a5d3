#include "formats/image/image_io.h"
#include "formats/util/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <mutex>
#include <random>
#include <string_view>
#include <system_error>
#include <vector>

#include <OpenColorIO/OpenColorIO.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <absl/strings/ascii.h>
#include <absl/strings/match.h>
#include <absl/strings/str_cat.h>
#include <absl/strings/str_format.h>
#include <absl/strings/str_join.h>
#include <absl/strings/strip.h>

#include "core/util/status.h"
#include "formats/image/rgb_channels.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
namespace OCIO = OCIO_NAMESPACE;

// Limits on what a file header may claim before we allocate for it. A 64K x 64K frame is far
// beyond any render we make; 2^31 floats (8 GiB) bounds a single image in memory.
constexpr int kMaxDimension = 65536;
constexpr uint64_t kMaxFloats = uint64_t{1} << 31;

// OIIO's messages sometimes end in a newline or hold several lines; one line reads better
// after "pbgi: error:".
std::string oneLine(std::string message) {
  std::replace(message.begin(), message.end(), '\n', ' ');
  return std::string(absl::StripAsciiWhitespace(message));
}

std::string oiioError(const std::string& message) {
  std::string m = oneLine(message);
  return m.empty() ? std::string("unknown OIIO error") : m;
}

// The code follows errno (ENOENT is NotFound, EACCES PermissionDenied, ...); absl appends
// strerror to the message.
absl::Status errnoStatus(int error, const std::string& message) {
  return absl::ErrnoToStatus(error, message);
}

absl::Status writeAtomically(const std::string& path, const char* format,
                             const OIIO::ImageSpec& spec, OIIO::TypeDesc pixelType,
                             const void* pixels) {
  auto file = AtomicFile::begin(path);
  if (!file.ok()) return file.status();
  const std::string& tmp = file->tempPath();
  // On every early return the temporary goes with `file`.
  try {
    std::unique_ptr<OIIO::ImageOutput> out = OIIO::ImageOutput::create(format);
    if (!out) {
      return absl::InternalError(
          absl::StrCat(path, ": OIIO has no ", format, " writer: ", oiioError(OIIO::geterror())));
    }
    if (!out->open(tmp, spec)) {
      return absl::UnavailableError(
          absl::StrCat(path, ": cannot open ", tmp, " for writing: ", oiioError(out->geterror())));
    }
    const bool wrote = out->write_image(pixelType, pixels);
    const bool closed = out->close();
    if (!wrote || !closed) {
      // OIIO's message rarely says why; a full disk is the usual reason, and worth saying.
      const uint64_t needed = uint64_t(spec.image_bytes());
      std::error_code ec;
      const fs::space_info space = fs::space(fs::path(tmp).parent_path(), ec);
      const std::string full =
          !ec && space.available < needed
              ? absl::StrFormat(" (the disk is full: %d bytes free in %s, %d needed)",
                                space.available, fs::path(tmp).parent_path().string(), needed)
              : "";
      return absl::ResourceExhaustedError(absl::StrCat(path, ": writing ", format, " failed: ",
                                                       oiioError(out->geterror()), full));
    }
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(path, ": writing ", format, ": ", e.what()));
  }
  return file->commit();
}

// Attributes that say how the file was encoded, not what the image is: they stop being true
// once the pixels are floats in memory, and writeExr sets them itself.
bool isEncodingAttribute(std::string_view name) {
  return name.starts_with("oiio:") || name == "compression";
}

struct ReadResult {
  Image image;
  std::string colorSpace;  // OIIO's guess at the file's encoding ("sRGB", "Linear", ...)
};

// OpenEXR sizes its line buffers and compressors from the header when a file is opened,
// before OIIO hands us the spec; its own limit makes it refuse absurd sizes at that point.
// Process-wide, but the same limit we apply to every format anyway.
void limitOpenExrHeaders() {
  static std::once_flag once;
  std::call_once(once, [] {
    Imf::Header::setMaxImageSize(kMaxDimension, kMaxDimension);
    Imf::Header::setMaxTileSize(kMaxDimension, kMaxDimension);
  });
}

absl::StatusOr<ReadResult> readWithOiio(const std::string& path) {
  limitOpenExrHeaders();
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) return absl::NotFoundError(absl::StrCat(path, ": no such file"));
  if (fs::is_directory(status)) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": is a folder, not an image"));
  }
  if (::access(path.c_str(), R_OK) != 0) {
    const int error = errno;
    return errnoStatus(error, absl::StrCat(path, ": cannot read"));
  }

  try {
    std::unique_ptr<OIIO::ImageInput> in = OIIO::ImageInput::open(path);
    if (!in) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": not a readable image: ", oiioError(OIIO::geterror())));
    }
    const OIIO::ImageSpec& spec = in->spec();
    // Everything below is checked before a single pixel is allocated: the header is the
    // attacker's to choose.
    if (spec.deep) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": deep images are not supported (", in->format_name(), ")"));
    }
    if (spec.width <= 0 || spec.height <= 0 || spec.depth != 1 || spec.nchannels <= 0) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: header claims %dx%dx%d pixels with %d channels; expected a 2D image with at "
          "least one pixel and one channel",
          path, spec.width, spec.height, spec.depth, spec.nchannels));
    }
    if (spec.width > kMaxDimension || spec.height > kMaxDimension) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: header claims %dx%d pixels; the maximum accepted is %d in "
                          "each dimension",
                          path, spec.width, spec.height, kMaxDimension));
    }
    const uint64_t floats = static_cast<uint64_t>(spec.width) * static_cast<uint64_t>(spec.height) *
                            static_cast<uint64_t>(spec.nchannels);
    if (floats > kMaxFloats) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: header claims %dx%d pixels with %d channels (%d floats); the maximum accepted "
          "is %d floats",
          path, spec.width, spec.height, spec.nchannels, floats, kMaxFloats));
    }

    std::vector<std::string> names(spec.channelnames.begin(), spec.channelnames.end());
    names.resize(spec.nchannels);
    for (int c = 0; c < spec.nchannels; ++c) {
      if (names[c].empty()) names[c] = absl::StrCat("channel", c);
    }
    ReadResult result{Image(spec.width, spec.height, std::move(names)),
                      spec.get_string_attribute("oiio:ColorSpace")};
    // The data window in the display window (a farm tile's place in its frame).
    const ImageWindow window{spec.x - spec.full_x, spec.y - spec.full_y, spec.full_width,
                             spec.full_height};
    if (window != ImageWindow{0, 0, spec.width, spec.height}) result.image.setWindow(window);
    if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT,
                        result.image.pixels().data())) {
      return absl::InvalidArgumentError(absl::StrCat(
          path, ": cannot read pixels (", in->format_name(), "): ", oiioError(in->geterror())));
    }
    for (const OIIO::ParamValue& p : spec.extra_attribs) {
      const std::string name = p.name().string();
      if (isEncodingAttribute(name) || p.nvalues() != 1) continue;
      // Only the types an Image can hold come back; matrices, vectors, timecodes and the
      // like are dropped rather than flattened into something a writer would misread.
      if (p.type() == OIIO::TypeString) {
        result.image.setMetadata(name, p.get_string());
      } else if (p.type() == OIIO::TypeInt) {
        result.image.setMetadata(name, p.get_int());
      } else if (p.type() == OIIO::TypeFloat) {
        result.image.setMetadata(name, p.get_float());
      }
    }
    in->close();
    return result;
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": cannot read image: ", e.what()));
  }
}

// The IEC 61966-2-1 decoding curve, for 8-bit maps that OIIO reports as sRGB-encoded.
float srgbToLinear(float v) {
  return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

// InvalidArgument naming `path` for an image without pixels or channels.
absl::Status checkNotEmpty(const Image& image, const std::string& path) {
  if (image.width() > 0 && image.height() > 0 && image.channelCount() > 0) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrFormat("%s: cannot write an empty image (%dx%d, %d channels)", path, image.width(),
                      image.height(), image.channelCount()));
}

}  // namespace

const std::vector<std::string>& exrCompressions() {
  static const std::vector<std::string> names = {"none",  "rle", "zips", "zip",  "piz",
                                                 "pxr24", "b44", "b44a", "dwaa", "dwab"};
  return names;
}

absl::Status checkExrCompression(const std::string& name, const std::string& where) {
  const auto& names = exrCompressions();
  if (std::find(names.begin(), names.end(), name) != names.end()) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrCat(where, " '", name, "': expected one of ", absl::StrJoin(names, ", ")));
}

absl::Status writeExr(const Image& image, const std::string& path, const std::string& compression) {
  PBGI_RETURN_IF_ERROR(checkExrCompression(compression, path + ": compression"));
  if (absl::Status s = checkNotEmpty(image, path); !s.ok()) return s;
  PBGI_CHECK_EQ(image.pixels().size(),
                static_cast<size_t>(image.width()) * image.height() * image.channelCount());
  const auto& channels = image.channels();
  for (size_t i = 0; i < channels.size(); ++i) {
    if (channels[i].empty()) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": channel ", i, " has no name"));
    }
    if (std::find(channels.begin(), channels.begin() + i, channels[i]) != channels.begin() + i) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": channel name \"", channels[i], "\" appears twice"));
    }
  }

  OIIO::ImageSpec spec(image.width(), image.height(), image.channelCount(), OIIO::TypeDesc::FLOAT);
  if (!image.wholeFrame()) {
    // A part of a frame (a farm tile): its data window inside the frame's display window.
    const ImageWindow w = image.window();
    spec.x = w.x;
    spec.y = w.y;
    spec.full_x = 0;
    spec.full_y = 0;
    spec.full_width = w.fullWidth;
    spec.full_height = w.fullHeight;
  }
  spec.channelnames = channels;
  spec.alpha_channel = image.channelIndex("A");
  for (const MetadataEntry& entry : image.metadata()) {
    if (entry.name.empty() || isEncodingAttribute(entry.name)) {
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": metadata name \"", entry.name,
                       "\" is reserved: it describes the file encoding, which writeExr chooses"));
    }
    std::visit([&](const auto& v) { spec.attribute(entry.name, v); }, entry.value);
  }
  // ZIP (the default) compresses rendered images well and losslessly, and decodes fast in every
  // EXR reader.
  spec.attribute("compression", compression);
  return writeAtomically(path, "openexr", spec, OIIO::TypeDesc::FLOAT, image.pixels().data());
}

absl::StatusOr<Image> readImage(const std::string& path) {
  absl::StatusOr<ReadResult> result = readWithOiio(path);
  if (!result.ok()) return result.status();
  return std::move(result->image);
}

absl::StatusOr<LatLongImage> readLatLong(const std::string& path) {
  absl::StatusOr<ReadResult> result = readWithOiio(path);
  if (!result.ok()) return result.status();
  const Image& image = result->image;
  // PNG and JPEG maps hold display-encoded values; the renderer needs radiance.
  const bool decode = absl::EqualsIgnoreCase(result->colorSpace, "sRGB");
  const auto rgb = detail::rgbChannelIndices(image);
  LatLongImage map;
  map.width = image.width();
  map.height = image.height();
  map.texels.resize(static_cast<size_t>(map.width) * map.height);
  for (int y = 0; y < map.height; ++y) {
    for (int x = 0; x < map.width; ++x) {
      Rgb c(image.at(x, y, rgb[0]), image.at(x, y, rgb[1]), image.at(x, y, rgb[2]));
      if (decode) c = Rgb(srgbToLinear(c.x), srgbToLinear(c.y), srgbToLinear(c.z));
      map.texels[static_cast<size_t>(y) * map.width + x] = c;
    }
  }
  return map;
}

namespace {

// The image's R, G, B as 8-bit display values: scene-linear through the OCIO config's default
// display and view. `what` names the preview in errors (its path, or what it shows).
absl::StatusOr<std::vector<uint8_t>> displayRgb8(const Image& image, const std::string& what,
                                                 const std::string& ocioConfig) {
  if (image.width() <= 0 || image.height() <= 0 || image.channelCount() == 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: cannot write a preview of an empty image (%dx%d, %d channels)", what,
                        image.width(), image.height(), image.channelCount()));
  }
  if (ocioConfig.empty()) {
    return absl::FailedPreconditionError(
        absl::StrCat(what,
                     ": no OCIO config to make the preview with: set $OCIO, or install "
                     "share/pbgi/ocio/config.ocio beside the bin/ folder of pbgi"));
  }

  std::vector<float> linear = detail::packRgb(image);

  try {
    OCIO::ConstConfigRcPtr config = OCIO::Config::CreateFromFile(ocioConfig.c_str());
    const char* display = config->getDefaultDisplay();
    const char* view = config->getDefaultView(display);
    OCIO::ConstProcessorRcPtr processor =
        config->getProcessor(OCIO::ROLE_SCENE_LINEAR, display, view, OCIO::TRANSFORM_DIR_FORWARD);
    OCIO::PackedImageDesc desc(linear.data(), image.width(), image.height(), 3);
    processor->getDefaultCPUProcessor()->apply(desc);
  } catch (const std::exception& e) {
    return absl::FailedPreconditionError(
        absl::StrCat(what, ": OCIO config ", ocioConfig, ": ", oneLine(e.what())));
  }

  std::vector<uint8_t> encoded(linear.size());
  for (size_t i = 0; i < linear.size(); ++i) {
    const float v = linear[i];
    // NaN previews as black rather than as whatever a cast of NaN happens to give.
    const float clamped = std::isnan(v) ? 0.0f : std::clamp(v, 0.0f, 1.0f);
    encoded[i] = static_cast<uint8_t>(std::lround(clamped * 255.0f));
  }
  return encoded;
}

OIIO::ImageSpec previewSpec(const Image& image) {
  OIIO::ImageSpec spec(image.width(), image.height(), 3, OIIO::TypeDesc::UINT8);
  spec.attribute("oiio:ColorSpace", "sRGB");
  return spec;
}

}  // namespace

absl::Status writePreviewPng(const Image& image, const std::string& path,
                             const std::string& ocioConfig) {
  absl::StatusOr<std::vector<uint8_t>> encoded = displayRgb8(image, path, ocioConfig);
  if (!encoded.ok()) return encoded.status();
  return writeAtomically(path, "png", previewSpec(image), OIIO::TypeDesc::UINT8, encoded->data());
}

namespace {

struct FormatByExtension {
  std::string_view extension;
  OutputFormat format;
  const char* oiioName;
};
constexpr FormatByExtension kOutputFormats[] = {
    {".exr", OutputFormat::kExr, "openexr"},    {".tif", OutputFormat::kFloatRgb, "tiff"},
    {".tiff", OutputFormat::kFloatRgb, "tiff"}, {".hdr", OutputFormat::kFloatRgb, "hdr"},
    {".png", OutputFormat::kDisplay8, "png"},   {".jpg", OutputFormat::kDisplay8, "jpeg"},
    {".jpeg", OutputFormat::kDisplay8, "jpeg"},
};

const FormatByExtension* formatOf(const std::string& path) {
  const std::string extension = absl::AsciiStrToLower(fs::path(path).extension().string());
  for (const FormatByExtension& f : kOutputFormats) {
    if (f.extension == extension) return &f;
  }
  return nullptr;
}

}  // namespace

absl::StatusOr<OutputFormat> outputFormatFor(const std::string& path) {
  if (const FormatByExtension* f = formatOf(path)) return f->format;
  return absl::InvalidArgumentError(absl::StrCat(
      path, ": unknown image format '", fs::path(path).extension().string(),
      "' (expected .exr for every AOV in float; .tif, .tiff or .hdr for the beauty in float; "
      ".png, .jpg or .jpeg for 8-bit through the OCIO view)"));
}

absl::Status writeRender(const Image& image, const std::string& path, const std::string& ocioConfig,
                         std::vector<std::string>* warnings, const std::string& exrCompression) {
  const FormatByExtension* f = formatOf(path);
  if (f == nullptr) return outputFormatFor(path).status();
  if (f->format == OutputFormat::kExr) return writeExr(image, path, exrCompression);
  if (absl::Status s = checkNotEmpty(image, path); !s.ok()) return s;
  const std::string dropped =
      image.channelCount() > 3 ? absl::StrFormat(" and %d AOV channels", image.channelCount() - 3)
                               : std::string();
  if (f->format == OutputFormat::kFloatRgb) {
    warnings->push_back(absl::StrCat(path, ": ", std::string(f->extension),
                                     " keeps the image's colour in float; its metadata", dropped,
                                     " are written only to .exr"));
    const std::vector<float> rgb = detail::packRgb(image);
    const OIIO::ImageSpec spec(image.width(), image.height(), 3, OIIO::TypeDesc::FLOAT);
    return writeAtomically(path, f->oiioName, spec, OIIO::TypeDesc::FLOAT, rgb.data());
  }
  warnings->push_back(absl::StrCat(path, ": ", std::string(f->extension),
                                   " is 8-bit, made through the OCIO view as the preview is: the "
                                   "high dynamic range, the metadata",
                                   dropped, " are dropped (write .exr to keep them)"));
  absl::StatusOr<std::vector<uint8_t>> encoded = displayRgb8(image, path, ocioConfig);
  if (!encoded.ok()) return encoded.status();
  return writeAtomically(path, f->oiioName, previewSpec(image), OIIO::TypeDesc::UINT8,
                         encoded->data());
}

absl::StatusOr<std::string> encodePreviewPng(const Image& image, const std::string& what,
                                             const std::string& ocioConfig) {
  absl::StatusOr<std::vector<uint8_t>> encoded = displayRgb8(image, what, ocioConfig);
  if (!encoded.ok()) return encoded.status();
  std::vector<unsigned char> bytes;
  OIIO::Filesystem::IOVecOutput proxy(bytes);
  try {
    std::unique_ptr<OIIO::ImageOutput> out = OIIO::ImageOutput::create("png");
    if (!out || !out->supports("ioproxy")) {
      return absl::InternalError(absl::StrCat(what, ": OIIO cannot write PNG to memory"));
    }
    OIIO::ImageSpec spec = previewSpec(image);
    OIIO::Filesystem::IOProxy* p = &proxy;
    spec.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &p);
    if (!out->open("preview.png", spec) || !out->write_image(OIIO::TypeDesc::UINT8, encoded->data()) ||
        !out->close()) {
      return absl::InternalError(
          absl::StrCat(what, ": encoding the PNG failed: ", oiioError(out->geterror())));
    }
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(what, ": encoding the PNG: ", e.what()));
  }
  return std::string(bytes.begin(), bytes.end());
}

}  // namespace pbgi
