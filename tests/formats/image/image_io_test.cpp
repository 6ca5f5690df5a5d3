#include "formats/image/image_io.h"

#include <stdlib.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <OpenColorIO/OpenColorIO.h>
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include "formats/image/ocio_config.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::filesIn;

namespace fs = std::filesystem;
namespace OCIO = OCIO_NAMESPACE;

fs::path shippedOcioConfig() { return testing::sourceDir() / "config" / "ocio" / "config.ocio"; }
fs::path hostile(const std::string& name) { return testing::testDataDir() / "images" / name; }

// The attributes of a single-part scanline OpenEXR header, parsed by hand so that the test
// checks the file itself rather than what OIIO makes of it.
struct ExrHeader {
  uint32_t version = 0;
  std::map<std::string, std::pair<std::string, std::string>> attributes;  // name -> type, bytes
};

ExrHeader parseExrHeader(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ExrHeader header;
  EXPECT_GE(bytes.size(), 8u);
  uint32_t magic = 0;
  std::memcpy(&magic, bytes.data(), 4);
  EXPECT_EQ(magic, 20000630u) << path;
  std::memcpy(&header.version, bytes.data() + 4, 4);
  size_t pos = 8;
  auto readString = [&] {
    const size_t end = bytes.find('\0', pos);
    std::string s = bytes.substr(pos, end - pos);
    pos = end + 1;
    return s;
  };
  while (pos < bytes.size() && bytes[pos] != '\0') {
    const std::string name = readString();
    const std::string type = readString();
    int32_t size = 0;
    std::memcpy(&size, bytes.data() + pos, 4);
    pos += 4;
    header.attributes[name] = {type, bytes.substr(pos, size)};
    pos += size;
  }
  return header;
}

// Channel name -> OpenEXR pixel type (0 uint, 1 half, 2 float) from a "chlist" attribute.
std::map<std::string, int> exrChannelTypes(const std::string& chlist) {
  std::map<std::string, int> types;
  size_t pos = 0;
  while (pos < chlist.size() && chlist[pos] != '\0') {
    const size_t end = chlist.find('\0', pos);
    const std::string name = chlist.substr(pos, end - pos);
    int32_t type = 0;
    std::memcpy(&type, chlist.data() + end + 1, 4);
    types[name] = type;
    pos = end + 1 + 16;  // pixel type, pLinear + reserved, x and y sampling
  }
  return types;
}

const MetadataValue* findMetadata(const Image& image, const std::string& name) {
  for (const auto& m : image.metadata())
    if (m.name == name) return &m.value;
  return nullptr;
}

Image aovImage() {
  Image image(7, 5,
              {"R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y",
               "normal.Z", "depth.Z"});
  // Random bit patterns cover denormals, infinities, NaNs with payloads and -0: a writer that
  // converted, clamped or compressed lossily would change some of them.
  std::mt19937 rng(12345);
  for (float& v : image.pixels()) v = std::bit_cast<float>(static_cast<uint32_t>(rng()));
  image.at(0, 0, 0) = 0.18f;
  image.at(6, 4, 10) = -0.0f;
  image.setMetadata("pbgi:integrator", std::string("pbgi"));
  image.setMetadata("pbgi:shot", std::string("shots/cornell box.toml"));
  image.setMetadata("pbgi:spp", 64);
  image.setMetadata("pbgi:frame", -3);
  image.setMetadata("pbgi:exposure", 0.1f);
  return image;
}

TEST(ImageIoTest, ExrRoundTripKeepsAovChannelsMetadataAndExactBits) {
  const fs::path dir = testing::makeTempDir("image-io");
  const std::string path = (dir / "frame.exr").string();
  const Image written = aovImage();
  ASSERT_TRUE(writeExr(written, path).ok());

  absl::StatusOr<Image> read = readImage(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->width(), 7);
  EXPECT_EQ(read->height(), 5);
  ASSERT_EQ(read->channelCount(), written.channelCount());
  // EXR stores channels sorted by name, so the order may change; every name must survive.
  for (int c = 0; c < written.channelCount(); ++c) {
    const std::string& name = written.channels()[c];
    const int rc = read->channelIndex(name);
    ASSERT_GE(rc, 0) << "channel " << name << " lost";
    for (int y = 0; y < 5; ++y) {
      for (int x = 0; x < 7; ++x) {
        EXPECT_EQ(std::bit_cast<uint32_t>(read->at(x, y, rc)),
                  std::bit_cast<uint32_t>(written.at(x, y, c)))
            << name << " at " << x << "," << y;
      }
    }
  }

  for (const auto& entry : written.metadata()) {
    const MetadataValue* value = findMetadata(*read, entry.name);
    ASSERT_NE(value, nullptr) << "metadata " << entry.name << " lost";
    EXPECT_EQ(*value, entry.value) << entry.name;
  }
  EXPECT_EQ(findMetadata(*read, "compression"), nullptr) << "encoding leaked into metadata";

  // The file itself: one scanline part, ZIP, every channel 32-bit float, typed attributes.
  const ExrHeader header = parseExrHeader(path);
  EXPECT_EQ(header.version & 0xff, 2u);
  EXPECT_EQ(header.version & 0x200, 0u) << "tiled";
  EXPECT_EQ(header.version & 0x1000, 0u) << "multi-part";
  ASSERT_TRUE(header.attributes.count("compression"));
  EXPECT_EQ(header.attributes.at("compression").second, std::string(1, '\3')) << "not ZIP";
  const auto types = exrChannelTypes(header.attributes.at("channels").second);
  EXPECT_EQ(types.size(), written.channels().size());
  for (const auto& [name, type] : types) EXPECT_EQ(type, 2) << name << " is not float";
  EXPECT_EQ(header.attributes.at("pbgi:integrator").first, "string");
  EXPECT_EQ(header.attributes.at("pbgi:spp").first, "int");
  EXPECT_EQ(header.attributes.at("pbgi:exposure").first, "float");
}

// The first bytes of a file: which format it really is, whatever its name says.
std::string magic(const std::string& path, size_t n) {
  std::ifstream f(path, std::ios::binary);
  std::string bytes(n, '\0');
  f.read(bytes.data(), static_cast<std::streamsize>(n));
  return bytes.substr(0, static_cast<size_t>(f.gcount()));
}

// A render's output path picks its format: .exr keeps everything; .tif and .hdr the colour
// in float (HDR kept, the AOVs said dropped); .png and .jpg 8 bits through the OCIO view (the
// range said dropped); anything else is refused before anything is written.
TEST(ImageIoTest, ARendersExtensionChoosesItsFormatAndSaysWhatItDrops) {
  const fs::path dir = testing::makeTempDir("image-io");
  Image image = aovImage();
  const int r = image.channelIndex("R");
  image.at(0, 0, r) = 7.5f;  // past what 8 bits hold (G and B near it: RGBE shares an exponent)
  image.at(0, 0, image.channelIndex("G")) = 0.5f;
  image.at(0, 0, image.channelIndex("B")) = 0.25f;
  const std::string ocio = defaultOcioConfigPath();
  struct Case {
    const char* name;
    std::string magic;
    bool hdr;
  };
  for (const Case& c :
       {Case{"frame.exr", std::string("\x76\x2f\x31\x01", 4), true}, Case{"frame.tif", "", true},
        Case{"FRAME.TIFF", "", true}, Case{"frame.hdr", "#?", true},
        Case{"frame.png", "\x89PNG", false}, Case{"frame.JPG", "\xff\xd8\xff", false}}) {
    SCOPED_TRACE(c.name);
    const std::string path = (dir / c.name).string();
    std::vector<std::string> warnings;
    ASSERT_TRUE(writeRender(image, path, ocio, &warnings).ok());
    if (!c.magic.empty()) EXPECT_EQ(magic(path, c.magic.size()), c.magic);
    if (std::string(c.name).find("TIF") != std::string::npos ||
        std::string(c.name).find("tif") != std::string::npos) {
      const std::string m = magic(path, 4);
      EXPECT_TRUE(m == std::string("II*\0", 4) || m == std::string("MM\0*", 4));
    }
    absl::StatusOr<Image> read = readImage(path);
    ASSERT_TRUE(read.ok()) << read.status();
    EXPECT_EQ(read->width(), image.width());
    const float back = read->at(0, 0, read->channelIndex("R") >= 0 ? read->channelIndex("R") : 0);
    if (c.hdr) {
      EXPECT_NEAR(back, 7.5f, 0.1f);  // RGBE rounds to 8 bits of mantissa
    } else {
      EXPECT_LE(back, 1.0f);
    }
    const bool exr = std::string(c.name) == "frame.exr";
    EXPECT_EQ(warnings.empty(), exr);
    if (!exr) {
      ASSERT_EQ(warnings.size(), 1u);
      EXPECT_NE(warnings[0].find("AOV channels"), std::string::npos) << warnings[0];
      EXPECT_NE(warnings[0].find(".exr"), std::string::npos) << warnings[0];
    }
  }
  for (const char* bad : {"frame.bmp", "frame", "frame.exr.gz"}) {
    const std::string path = (dir / bad).string();
    std::vector<std::string> warnings;
    const absl::Status s = writeRender(image, path, ocio, &warnings);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(s.message().find("unknown image format"), std::string::npos) << s;
    EXPECT_NE(s.message().find(".exr"), std::string::npos) << s;
    EXPECT_FALSE(fs::exists(path)) << bad;
    EXPECT_EQ(outputFormatFor(path).status().code(), absl::StatusCode::kInvalidArgument);
  }
  fs::remove_all(dir);
}

// A farm tile is an EXR of its own pixels whose data window is its place in the frame's
// display window; other readers (OIIO here) see it there.
TEST(ImageIoTest, ExrKeepsAPartOfAFrameAsItsDataWindow) {
  const fs::path dir = testing::makeTempDir("image-io");
  Image tile(3, 2, {"R", "G", "B"});
  for (size_t i = 0; i < tile.pixels().size(); ++i) tile.pixels()[i] = static_cast<float>(i);
  EXPECT_TRUE(tile.wholeFrame());
  tile.setWindow({32, 16, 64, 48});
  EXPECT_FALSE(tile.wholeFrame());
  const std::string path = (dir / "tile.exr").string();
  ASSERT_TRUE(writeExr(tile, path).ok());
  auto in = OIIO::ImageInput::open(path);
  ASSERT_TRUE(in);
  const OIIO::ImageSpec& spec = in->spec();
  EXPECT_EQ(spec.x, 32);
  EXPECT_EQ(spec.y, 16);
  EXPECT_EQ(spec.width, 3);
  EXPECT_EQ(spec.height, 2);
  EXPECT_EQ(spec.full_width, 64);
  EXPECT_EQ(spec.full_height, 48);
  in->close();
  auto back = readImage(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->window(), (ImageWindow{32, 16, 64, 48}));
  EXPECT_TRUE(back->pixels() == tile.pixels());
  // A whole frame stays one: data window and display window the same.
  Image whole(3, 2, {"R", "G", "B"});
  ASSERT_TRUE(writeExr(whole, (dir / "whole.exr").string()).ok());
  auto wholeBack = readImage((dir / "whole.exr").string());
  ASSERT_TRUE(wholeBack.ok());
  EXPECT_TRUE(wholeBack->wholeFrame());
  fs::remove_all(dir);
}

TEST(ImageIoTest, ExrWriteIsAtomicAndCreatesTheFolder) {
  const fs::path dir = testing::makeTempDir("image-io");
  const std::string path = (dir / "renders" / "shot1" / "frame.exr").string();
  Image image(3, 2, {"R", "G", "B"});
  image.at(1, 1, 1) = 2.0f;
  ASSERT_TRUE(writeExr(image, path).ok());
  image.at(1, 1, 1) = 4.0f;
  ASSERT_TRUE(writeExr(image, path).ok()) << "overwriting an existing file";
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"renders/shot1/frame.exr"});
  absl::StatusOr<Image> read = readImage(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->at(1, 1, read->channelIndex("G")), 4.0f);
}

TEST(ImageIoTest, ExrWriteFailureNamesThePathAndLeavesNothing) {
  const fs::path dir = testing::makeTempDir("image-io");
  std::ofstream(dir / "plain-file") << "x";
  const std::string path = (dir / "plain-file" / "frame.exr").string();
  const absl::Status status = writeExr(Image(2, 2, {"R", "G", "B"}), path);
  ASSERT_FALSE(status.ok());
  EXPECT_NE(status.message().find(path), std::string::npos) << status;
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"plain-file"});
}

TEST(ImageIoTest, ExrWriteRejectsBadInput) {
  const fs::path dir = testing::makeTempDir("image-io");
  const std::string path = (dir / "frame.exr").string();
  EXPECT_EQ(writeExr(Image(0, 0, {"R"}), path).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(writeExr(Image(2, 2, {"R", "R"}), path).code(), absl::StatusCode::kInvalidArgument);
  Image reserved(2, 2, {"R"});
  reserved.setMetadata("compression", std::string("none"));
  const absl::Status status = writeExr(reserved, path);
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("compression"), std::string::npos) << status;
  EXPECT_TRUE(filesIn(dir).empty());
}

TEST(ImageIoTest, ReadMissingFileIsNotFoundNamingThePath) {
  const std::string path = (testing::makeTempDir("image-io") / "absent.exr").string();
  const absl::StatusOr<Image> read = readImage(path);
  EXPECT_EQ(read.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status();
  EXPECT_EQ(readLatLong(path).status().code(), absl::StatusCode::kNotFound);
}

// Hostile and damaged files (tests/data/images/make_hostile_images.py): each must give a
// clear InvalidArgument that names the file, and no crash or huge allocation.
void expectRejected(const std::string& name, const std::string& expectedText) {
  SCOPED_TRACE(name);
  const std::string path = hostile(name).string();
  ASSERT_TRUE(fs::exists(path));
  const absl::StatusOr<Image> read = readImage(path);
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), absl::StatusCode::kInvalidArgument) << read.status();
  EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status();
  EXPECT_NE(read.status().message().find(expectedText), std::string::npos) << read.status();
  EXPECT_EQ(readLatLong(path).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(ImageIoTest, RejectsTruncatedExr) { expectRejected("truncated.exr", "end of file"); }

TEST(ImageIoTest, RejectsTextFileNamedExr) { expectRejected("not_an_image.exr", "OpenEXR"); }

TEST(ImageIoTest, RejectsExrHeaderClaimingHugeImage) {
  // 100000 x 100000: refused on opening, by OpenEXR's limit or ours, both at 65536.
  expectRejected("huge_header.exr", "maximum");
}

TEST(ImageIoTest, RejectsExrHeaderClaimingTooManyFloats) {
  // Each side is within 65536; the 2^32 floats are not.
  expectRejected("too_many_floats.exr", "4294967296 floats");
}

TEST(ImageIoTest, RejectsPngHeaderClaimingHugeImage) {
  expectRejected("huge_header.png", "100000x100000");
}

TEST(ImageIoTest, ReadLatLongTakesRgbRowZeroOnTop) {
  const fs::path dir = testing::makeTempDir("image-io");
  Image env(4, 2, {"R", "G", "B", "A"});
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 4; ++x)
      for (int c = 0; c < 4; ++c) env.at(x, y, c) = 10.0f * y + x + 0.25f * c;
  const std::string path = (dir / "env.exr").string();
  ASSERT_TRUE(writeExr(env, path).ok());
  const absl::StatusOr<LatLongImage> map = readLatLong(path);
  ASSERT_TRUE(map.ok()) << map.status();
  EXPECT_EQ(map->width, 4);
  EXPECT_EQ(map->height, 2);
  ASSERT_EQ(map->texels.size(), 8u);
  EXPECT_EQ(map->texels[0], Rgb(0.0f, 0.25f, 0.5f));
  EXPECT_EQ(map->texels[1 * 4 + 3], Rgb(13.0f, 13.25f, 13.5f));
}

TEST(ImageIoTest, ReadLatLongReplicatesOneChannel) {
  const fs::path dir = testing::makeTempDir("image-io");
  Image grey(2, 1, {"Y"});
  grey.at(0, 0, 0) = 0.5f;
  grey.at(1, 0, 0) = 3.0f;
  const std::string path = (dir / "grey.exr").string();
  ASSERT_TRUE(writeExr(grey, path).ok());
  const absl::StatusOr<LatLongImage> map = readLatLong(path);
  ASSERT_TRUE(map.ok()) << map.status();
  EXPECT_EQ(map->texels[0], Rgb(0.5f, 0.5f, 0.5f));
  EXPECT_EQ(map->texels[1], Rgb(3.0f, 3.0f, 3.0f));
}

TEST(ImageIoTest, ShippedOcioConfigLoadsAndHasWhatThePreviewNeeds) {
  try {
    OCIO::ConstConfigRcPtr config =
        OCIO::Config::CreateFromFile(shippedOcioConfig().string().c_str());
    config->validate();
    EXPECT_EQ(config->getMajorVersion(), 2u);
    for (const char* role :
         {OCIO::ROLE_SCENE_LINEAR, OCIO::ROLE_DEFAULT, OCIO::ROLE_DATA, OCIO::ROLE_COLOR_PICKING,
          OCIO::ROLE_TEXTURE_PAINT, OCIO::ROLE_COMPOSITING_LOG, OCIO::ROLE_REFERENCE}) {
      EXPECT_TRUE(config->hasRole(role)) << role;
    }
    EXPECT_STREQ(config->getColorSpace(OCIO::ROLE_SCENE_LINEAR)->getName(),
                 "Linear Rec.709 (sRGB)");
    EXPECT_TRUE(config->getColorSpace(OCIO::ROLE_DATA)->isData());
    EXPECT_STREQ(config->getDefaultDisplay(), "sRGB");
    EXPECT_STREQ(config->getDefaultView("sRGB"), "Standard");
    ASSERT_EQ(config->getNumViews("sRGB"), 2);
    EXPECT_STREQ(config->getView("sRGB", 1), "Raw");
    // The sRGB curve: its linear toe, mid grey and white.
    auto cpu =
        config
            ->getProcessor(OCIO::ROLE_SCENE_LINEAR, "sRGB", "Standard", OCIO::TRANSFORM_DIR_FORWARD)
            ->getDefaultCPUProcessor();
    float rgb[3] = {0.0031308f, 0.18f, 1.0f};
    cpu->applyRGB(rgb);
    EXPECT_NEAR(rgb[0], 0.04045f, 1e-4f);
    EXPECT_NEAR(rgb[1], 1.055f * std::pow(0.18f, 1.0f / 2.4f) - 0.055f, 1e-4f);
    EXPECT_NEAR(rgb[2], 1.0f, 1e-5f);
  } catch (const OCIO::Exception& e) {
    FAIL() << shippedOcioConfig() << ": " << e.what();
  }
}

TEST(ImageIoTest, DefaultOcioConfigPathPrefersOcioThenTheShippedConfig) {
  const char* saved = std::getenv("OCIO");
  const std::string savedValue = saved ? saved : "";
  ::setenv("OCIO", "/studio/config.ocio", 1);
  EXPECT_EQ(defaultOcioConfigPath(), "/studio/config.ocio");
  ::unsetenv("OCIO");
  // The test binary lives in <build>/tests, so the build's share/ is one folder up.
  const std::string found = defaultOcioConfigPath();
  if (saved) ::setenv("OCIO", savedValue.c_str(), 1);
  ASSERT_FALSE(found.empty());
  EXPECT_TRUE(fs::is_regular_file(found)) << found;
  EXPECT_TRUE(found.ends_with("share/pbgi/ocio/config.ocio")) << found;
}

TEST(ImageIoTest, PreviewPngMapsMidGreyThroughSrgb) {
  const fs::path dir = testing::makeTempDir("image-io");
  const std::string path = (dir / "preview" / "frame.png").string();
  // Alpha is zero everywhere: a preview that premultiplied or composited would go black.
  Image image(4, 1, {"R", "G", "B", "A"});
  const float values[4] = {0.18f, 0.0f, 1.0f, 5.0f};
  for (int x = 0; x < 4; ++x)
    for (int c = 0; c < 3; ++c) image.at(x, 0, c) = values[x];
  image.at(0, 0, 2) = std::nanf("");
  ASSERT_TRUE(writePreviewPng(image, path, shippedOcioConfig().string()).ok());
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"preview/frame.png"});

  const absl::StatusOr<Image> png = readImage(path);
  ASSERT_TRUE(png.ok()) << png.status();
  ASSERT_EQ(png->channelCount(), 3);
  auto byte = [&](int x, int c) { return static_cast<int>(std::lround(png->at(x, 0, c) * 255)); };
  EXPECT_NEAR(byte(0, 0), 118, 2);
  EXPECT_NEAR(byte(0, 1), 118, 2);
  EXPECT_EQ(byte(0, 2), 0) << "NaN previews as black";
  EXPECT_EQ(byte(1, 0), 0);
  EXPECT_EQ(byte(2, 0), 255);
  EXPECT_EQ(byte(3, 0), 255) << "over-range values clip";
}

TEST(ImageIoTest, PreviewPngNeedsAnOcioConfig) {
  const fs::path dir = testing::makeTempDir("image-io");
  const Image image(2, 2, {"R", "G", "B"});
  EXPECT_EQ(writePreviewPng(image, (dir / "a.png").string(), "").code(),
            absl::StatusCode::kFailedPrecondition);
  std::ofstream(dir / "broken.ocio") << "ocio_profile_version: 2\nroles: [\n";
  const absl::Status status =
      writePreviewPng(image, (dir / "b.png").string(), (dir / "broken.ocio").string());
  EXPECT_EQ(status.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(status.message().find("broken.ocio"), std::string::npos) << status;
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"broken.ocio"});
}

}  // namespace
}  // namespace pbgi
