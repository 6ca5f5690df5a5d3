#include "formats/vdb/surfel_vdb.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::filesIn;

namespace fs = std::filesystem;

// A temporary folder that goes away with the test.
class TempDir {
 public:
  TempDir() : path_(testing::makeTempDir("surfel-vdb")) {}
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::string hostile(const std::string& name) {
  return (testing::testDataDir() / "vdb" / name).string();
}

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
}

bool mentions(const absl::Status& status, const std::string& text) {
  return status.message().find(text) != std::string_view::npos;
}

// Random surfels over the whole range of every field: a 20 m box, random directions, albedo
// in [0, 1], HDR radiance over 8 decades, every material class, full-range triangle ids.
std::vector<Surfel> randomSurfels(size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::normal_distribution<float> gauss;
  std::vector<Surfel> surfels(count);
  for (Surfel& s : surfels) {
    s.position = Vec3f(unit(rng), unit(rng), unit(rng)) * 20.0f - Vec3f(10.0f);
    Vec3f n;
    do {
      n = Vec3f(gauss(rng), gauss(rng), gauss(rng));
    } while (length(n) < 1e-3f);
    s.normal = normalize(n);
    s.radius = 0.001f + 0.05f * unit(rng);
    s.albedo = Vec3f(unit(rng), unit(rng), unit(rng));
    s.radiance = Vec3f(std::pow(10.0f, 8.0f * unit(rng) - 4.0f), unit(rng), 0.0f);
    s.backRadiance = Vec3f(unit(rng), 0.0f, std::pow(10.0f, 6.0f * unit(rng) - 3.0f));
    s.materialClass = static_cast<MaterialClass>(rng() % 4);
    s.triangle = rng();
    const float b1 = unit(rng);
    s.barycentric = Vec2f(b1, (1.0f - b1) * unit(rng));
  }
  return surfels;
}

float angleBetween(const Vec3f& a, const Vec3f& b) {
  // atan2 of |a x b| and a.b keeps precision at tiny angles, where acos does not.
  return std::atan2(length(cross(a, b)), dot(a, b));
}

// The largest error of each lossy field, and whether every exact field came back exactly.
struct Errors {
  float position = 0.0f;        // per axis, world units
  float normal = 0.0f;          // radians
  float albedo = 0.0f;          // relative, over albedos in half's normal range (>= 2^-14)
  float albedoAbsolute = 0.0f;  // over all albedos
  size_t inexact = 0;           // surfels with an exact field that differs
};

Errors compare(const std::vector<Surfel>& written, const std::vector<Surfel>& read) {
  Errors e;
  EXPECT_EQ(read.size(), written.size());
  for (size_t i = 0; i < std::min(read.size(), written.size()); ++i) {
    const Surfel& w = written[i];
    const Surfel& r = read[i];
    e.position = std::max(e.position, maxAbsComponent(r.position - w.position));
    e.normal = std::max(e.normal, angleBetween(r.normal, w.normal));
    for (int c = 0; c < 3; ++c) {
      const float error = std::abs(r.albedo[c] - w.albedo[c]);
      e.albedoAbsolute = std::max(e.albedoAbsolute, error);
      if (w.albedo[c] >= 0x1p-14f) e.albedo = std::max(e.albedo, error / w.albedo[c]);
    }
    const bool exact = r.radius == w.radius && r.radiance == w.radiance &&
                       r.backRadiance == w.backRadiance && r.materialClass == w.materialClass && r.triangle == w.triangle &&
                       r.barycentric == w.barycentric;
    if (!exact) ++e.inexact;
  }
  return e;
}

TEST(SurfelVdbTest, RoundTripKeepsEveryFieldWithinTheDocumentedPrecisionAndTheOrder) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  const std::vector<Surfel> surfels = randomSurfels(10000, 7);
  ASSERT_TRUE(writeSurfelVdb(path, surfels).ok());
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();

  const Errors e = compare(surfels, *read);
  const float voxel = info->voxelSize.x;
  std::cout << "10k surfels: voxel size " << voxel << ", max position error " << e.position << " ("
            << e.position / voxel << " voxels), max normal error " << e.normal
            << " rad, max albedo error " << e.albedo << " relative, " << e.albedoAbsolute
            << " absolute; " << info->fileBytes << " bytes (" << info->fileBytesPerPoint()
            << " per point)\n";
  // The position codec truncates to 1/65535 of a voxel; the rest is float rounding at |p| <= 10.
  EXPECT_LE(e.position, voxel / 65535.0f + 2e-6f);
  EXPECT_LE(e.normal, 0.035f);
  EXPECT_LE(e.albedo, 0x1p-11f);
  EXPECT_LE(e.albedoAbsolute, 0x1p-12f);
  EXPECT_EQ(e.inexact, 0u)
      << "radius, radiance, back radiance, material class, triangle or barycentric changed";
  // Order: the exact fields of every surfel match at the same index.
  for (size_t i = 0; i < surfels.size(); ++i) {
    ASSERT_EQ((*read)[i].triangle, surfels[i].triangle) << "surfel " << i << " moved";
  }
}

TEST(SurfelVdbTest, NormalEncodingsTradePrecisionForSize) {
  TempDir dir;
  const std::vector<Surfel> surfels = randomSurfels(10000, 8);
  struct Case {
    SurfelVdbNormals encoding;
    const char* codec;
    float maxError;
  };
  const Case cases[] = {{SurfelVdbNormals::kUnitVector16, "uvec", 0.035f},
                        {SurfelVdbNormals::kHalf, "trnc", 1e-3f},
                        {SurfelVdbNormals::kFloat, "null", 0.0f}};
  uint64_t previousBytes = 0;
  for (const Case& c : cases) {
    const std::string path = dir.file(std::string(c.codec) + ".vdb");
    SurfelVdbOptions options;
    options.normals = c.encoding;
    ASSERT_TRUE(writeSurfelVdb(path, surfels, options).ok());
    absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
    ASSERT_TRUE(read.ok()) << read.status();
    absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
    ASSERT_TRUE(info.ok()) << info.status();
    float error = 0.0f;
    bool exact = true;
    for (size_t i = 0; i < surfels.size(); ++i) {
      error = std::max(error, angleBetween((*read)[i].normal, surfels[i].normal));
      exact = exact && (*read)[i].normal == surfels[i].normal;
    }
    std::cout << "normals as " << c.codec << ": max error " << error << " rad, "
              << info->fileBytesPerPoint() << " bytes per point\n";
    EXPECT_EQ(info->attributes.at(1).name, "N");
    EXPECT_EQ(info->attributes.at(1).codec, c.codec);
    EXPECT_LE(error, c.maxError) << c.codec;
    if (c.maxError == 0.0f) {
      EXPECT_TRUE(exact);
    }
    EXPECT_GT(info->fileBytes, previousBytes) << c.codec << " should be larger";
    previousBytes = info->fileBytes;
  }
}

TEST(SurfelVdbTest, ChosenVoxelSizeGivesAboutEightPointsPerActiveVoxel) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  // Points on a plane, as surfels are: a density guess from the bounding volume would fail.
  std::vector<Surfel> surfels = randomSurfels(10000, 3);
  for (Surfel& s : surfels) s.position.z = 0.25f;
  ASSERT_TRUE(writeSurfelVdb(path, surfels).ok());
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  const double perVoxel = double(info->pointCount) / double(info->activeVoxelCount);
  EXPECT_GE(perVoxel, 4.0) << info->toString();
  EXPECT_LE(perVoxel, 16.0) << info->toString();
}

TEST(SurfelVdbTest, ExplicitVoxelSizeIsUsedAndBoundsPositionError) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  const std::vector<Surfel> surfels = randomSurfels(2000, 11);
  SurfelVdbOptions options;
  options.voxelSize = 0.5f;
  ASSERT_TRUE(writeSurfelVdb(path, surfels, options).ok());
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->voxelSize, Vec3f(0.5f));
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_LE(compare(surfels, *read).position, 0.5f * 0x1p-15f);
}

TEST(SurfelVdbTest, EmptyCloudWritesAndReadsBack) {
  TempDir dir;
  const std::string path = dir.file("empty.vdb");
  ASSERT_TRUE(writeSurfelVdb(path, {}).ok());
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_TRUE(read->empty());
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->pointCount, 0u);
  EXPECT_TRUE(info->bounds.empty());
  EXPECT_TRUE(info->attributes.empty()) << "OpenVDB keeps attributes in leaves; none here";
  EXPECT_EQ(info->problem, "");
}

TEST(SurfelVdbTest, OnePointAndCoincidentPointsRoundTrip) {
  TempDir dir;
  for (size_t count : {1, 50}) {
    std::vector<Surfel> surfels = randomSurfels(count, 5);
    for (Surfel& s : surfels) s.position = Vec3f(1e5f, -3.0f, 0.5f);  // far out, all in one spot
    const std::string path = dir.file("cloud" + std::to_string(count) + ".vdb");
    ASSERT_TRUE(writeSurfelVdb(path, surfels).ok()) << count;
    absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
    ASSERT_TRUE(read.ok()) << read.status();
    const Errors e = compare(surfels, *read);
    EXPECT_LE(e.position, 0.02f) << count;  // float spacing at 1e5 is 0.0078
    EXPECT_EQ(e.inexact, 0u) << count;
  }
}

TEST(SurfelVdbTest, MetadataRoundTripsThroughInspect) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  SurfelVdbOptions options;
  options.metadata.shot = "sq010_sh0420 \"hero\"";
  options.metadata.frame = -12;
  options.metadata.seed = 0xfedcba9876543210ULL;  // past INT64_MAX: stored bit for bit
  options.metadata.pbgiVersion = "0.1.0";
  const std::vector<Surfel> surfels = randomSurfels(100, 2);
  ASSERT_TRUE(writeSurfelVdb(path, surfels, options).ok());
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->metadata.shot, options.metadata.shot);
  EXPECT_EQ(info->metadata.frame, -12);
  EXPECT_EQ(info->metadata.seed, 0xfedcba9876543210ULL);
  EXPECT_EQ(info->metadata.pbgiVersion, "0.1.0");
  auto entry = [&](const std::string& name) -> std::string {
    for (const auto& [n, v] : info->gridMetadata) {
      if (n == name) return v;
    }
    return "(absent)";
  };
  EXPECT_EQ(entry("pbgi_point_count"), "100");
  EXPECT_EQ(entry("pbgi_format_version"), "2");
  EXPECT_EQ(entry("pbgi_shot"), options.metadata.shot);
  EXPECT_EQ(entry("pbgi_checksum").substr(0, 8), "xxh3_64:");
}

TEST(SurfelVdbTest, InspectDescribesAttributesCodecsAndSizes) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  const std::vector<Surfel> surfels = randomSurfels(1000, 9);
  ASSERT_TRUE(writeSurfelVdb(path, surfels).ok());
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->problem, "");
  EXPECT_EQ(info->pointCount, 1000u);
  EXPECT_EQ(info->fileBytes, fs::file_size(path));
  EXPECT_NE(info->compression.find("blosc"), std::string::npos) << info->compression;
  EXPECT_GT(info->leafCount, 0u);
  EXPECT_GE(info->activeVoxelCount, info->leafCount);
  EXPECT_GT(info->memoryBytes, 0u);
  EXPECT_NEAR(info->fileBytesPerPoint(), double(info->fileBytes) / 1000.0, 1e-9);
  std::vector<std::string> attributes;
  for (const SurfelVdbAttributeInfo& a : info->attributes) {
    attributes.push_back(a.name + ":" + a.valueType + ":" + a.codec);
    EXPECT_GT(a.memoryBytes, 0u) << a.name;
  }
  EXPECT_EQ(attributes,
            (std::vector<std::string>{
                "P:vec3s:fxpt16", "N:vec3s:uvec", "radius:float:null", "pscale:float:null",
                "albedo:vec3s:trnc", "radiance:vec3s:null", "radiance_back:vec3s:null",
                "materialClass:int32:null", "triangle:int32:null", "barycentric:vec3s:null",
                "id:int64:null"}));
  Bounds3f bounds;
  for (const Surfel& s : surfels) bounds.extend(s.position);
  EXPECT_LE(maxAbsComponent(info->bounds.min - bounds.min), 1e-4f);
  EXPECT_LE(maxAbsComponent(info->bounds.max - bounds.max), 1e-4f);
  const std::string text = info->toString();
  for (const char* expected : {"points: 1000", "albedo", "trnc", "blosc", "status: ok"}) {
    EXPECT_NE(text.find(expected), std::string::npos) << expected << " in\n" << text;
  }
}

TEST(SurfelVdbTest, WritingTheSameSurfelsTwiceGivesIdenticalBytesWhateverTheThreads) {
  TempDir dir;
  const std::vector<Surfel> surfels = randomSurfels(3000, 4);
  SurfelVdbOptions options;
  options.metadata.shot = "det";
  ASSERT_TRUE(writeSurfelVdb(dir.file("a.vdb"), surfels, options).ok());
  {
    // OpenVDB builds the grid with TBB; the file must not depend on how many threads did.
    tbb::global_control oneThread(tbb::global_control::max_allowed_parallelism, 1);
    ASSERT_TRUE(writeSurfelVdb(dir.file("b.vdb"), surfels, options).ok());
  }
  const std::string a = readBytes(dir.file("a.vdb"));
  EXPECT_EQ(a, readBytes(dir.file("b.vdb")));
  // The header's UUID (which OpenVDB makes random) follows the contents.
  options.metadata.frame = 2;
  ASSERT_TRUE(writeSurfelVdb(dir.file("c.vdb"), surfels, options).ok());
  const std::string c = readBytes(dir.file("c.vdb"));
  ASSERT_GE(a.size(), 64u);
  EXPECT_NE(a.substr(0, 64), c.substr(0, 64));
  EXPECT_TRUE(readSurfelVdb(dir.file("c.vdb")).ok());
}

TEST(SurfelVdbTest, WriteIsAtomicOverwritesAndCreatesTheFolder) {
  TempDir dir;
  const std::string path = (dir.path() / "bake" / "shot1" / "frame.vdb").string();
  ASSERT_TRUE(writeSurfelVdb(path, randomSurfels(10, 1)).ok());
  const std::vector<Surfel> second = randomSurfels(20, 2);
  ASSERT_TRUE(writeSurfelVdb(path, second).ok()) << "overwriting an existing file";
  EXPECT_EQ(filesIn(dir.path()), std::vector<std::string>{"bake/shot1/frame.vdb"});
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->size(), 20u);
}

TEST(SurfelVdbTest, WriteFailureNamesThePathAndLeavesNothing) {
  TempDir dir;
  std::ofstream(dir.file("plain-file")) << "x";
  const std::string path = dir.file("plain-file") + "/frame.vdb";
  const absl::Status status = writeSurfelVdb(path, randomSurfels(10, 1));
  ASSERT_FALSE(status.ok());
  EXPECT_TRUE(mentions(status, path)) << status;
  EXPECT_EQ(filesIn(dir.path()), std::vector<std::string>{"plain-file"});
}

TEST(SurfelVdbTest, WriteRejectsBadSurfelsNamingTheFirstAndWritesNothing) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  struct Case {
    const char* what;
    void (*spoil)(Surfel&);
  };
  const Case cases[] = {
      {"position", [](Surfel& s) { s.position.y = std::numeric_limits<float>::infinity(); }},
      {"normal", [](Surfel& s) { s.normal = Vec3f(0.0f); }},
      {"normal", [](Surfel& s) { s.normal *= 1.01f; }},
      {"radius", [](Surfel& s) { s.radius = -1.0f; }},
      {"albedo", [](Surfel& s) { s.albedo.z = 1e6f; }},
      {"radiance", [](Surfel& s) { s.radiance.x = std::numeric_limits<float>::quiet_NaN(); }},
      {"material class", [](Surfel& s) { s.materialClass = static_cast<MaterialClass>(9); }},
      {"barycentric", [](Surfel& s) { s.barycentric.x = std::numeric_limits<float>::quiet_NaN(); }},
  };
  for (const Case& c : cases) {
    std::vector<Surfel> surfels = randomSurfels(10, 1);
    c.spoil(surfels[7]);
    const absl::Status status = writeSurfelVdb(path, surfels);
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << c.what << ": " << status;
    EXPECT_TRUE(mentions(status, "surfel 7")) << status;
    EXPECT_TRUE(mentions(status, c.what)) << status;
  }
  EXPECT_TRUE(filesIn(dir.path()).empty());
}

TEST(SurfelVdbTest, WriteRejectsBadVoxelSizes) {
  TempDir dir;
  const std::string path = dir.file("frame.vdb");
  std::vector<Surfel> surfels = randomSurfels(10, 1);
  for (float bad : {-1.0f, 1e-9f, std::numeric_limits<float>::quiet_NaN()}) {
    SurfelVdbOptions options;
    options.voxelSize = bad;
    const absl::Status status = writeSurfelVdb(path, surfels, options);
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << bad;
    EXPECT_TRUE(mentions(status, "voxel size")) << status;
  }
  // Voxel coordinates are int32: a millimetre voxel cannot reach 1e6 units out.
  surfels[3].position = Vec3f(1e6f, 0.0f, 0.0f);
  SurfelVdbOptions options;
  options.voxelSize = 1e-3f;
  const absl::Status status = writeSurfelVdb(path, surfels, options);
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(mentions(status, "too small")) << status;
  options.voxelSize = 0.0f;
  options.pointsPerVoxel = 0;
  EXPECT_EQ(writeSurfelVdb(path, surfels, options).code(), absl::StatusCode::kInvalidArgument);
  // Chosen automatically, the voxel grows to reach the far point.
  options.pointsPerVoxel = 8;
  ASSERT_TRUE(writeSurfelVdb(path, surfels, options).ok());
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ((*read)[3].position.x, 1e6f);
}

// ---- Files that are not what they claim ------------------------------------------------

TEST(SurfelVdbTest, MissingFileIsNotFoundAndAFolderIsRejected) {
  TempDir dir;
  const std::string absent = dir.file("absent.vdb");
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(absent);
  EXPECT_EQ(read.status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(mentions(read.status(), absent)) << read.status();
  EXPECT_EQ(inspectSurfelVdb(absent).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(readSurfelVdb(dir.path().string()).status().code(), absl::StatusCode::kInvalidArgument);
  writeBytes(dir.file("empty.vdb"), "");
  read = readSurfelVdb(dir.file("empty.vdb"));
  EXPECT_EQ(read.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(mentions(read.status(), "empty file")) << read.status();
}

// The crafted files of tests/data/vdb (see make_hostile_vdbs.cpp there): each is rejected by
// readSurfelVdb with its own reason.
TEST(SurfelVdbTest, HostileFilesGiveClearErrors) {
  struct Case {
    const char* file;
    absl::StatusCode code;
    const char* says;
  };
  const Case cases[] = {
      {"garbage.vdb", absl::StatusCode::kInvalidArgument, "not an OpenVDB file: starts with"},
      {"magic_then_garbage.vdb", absl::StatusCode::kInvalidArgument, "OpenVDB file format version"},
      {"truncated.vdb", absl::StatusCode::kDataLoss, "damaged or truncated"},
      {"crashes_openvdb.vdb", absl::StatusCode::kDataLoss, "damaged or truncated"},
      {"foreign_writer.vdb", absl::StatusCode::kInvalidArgument, "is not a hash of its contents"},
      {"truncated_rehashed.vdb", absl::StatusCode::kInvalidArgument,
       "ends (at 7023 bytes) before the data it declares"},
      {"float_grid_named_surfels.vdb", absl::StatusCode::kInvalidArgument,
       "expected an OpenVDB points grid"},
      {"no_surfels_grid.vdb", absl::StatusCode::kInvalidArgument, "no grid named \"surfels\""},
      {"missing_radiance.vdb", absl::StatusCode::kInvalidArgument, "no \"radiance\" attribute"},
      {"radiance_is_float.vdb", absl::StatusCode::kInvalidArgument,
       "attribute \"radiance\" holds float; expected vec3s"},
      {"duplicate_id.vdb", absl::StatusCode::kInvalidArgument, "appears twice"},
      {"id_out_of_range.vdb", absl::StatusCode::kInvalidArgument, "out of range"},
      {"bad_material_class.vdb", absl::StatusCode::kInvalidArgument, "material class 7"},
      {"nan_radiance.vdb", absl::StatusCode::kInvalidArgument,
       "radiance (nan, 0, 0) is not finite"},
      {"checksum_mismatch.vdb", absl::StatusCode::kDataLoss, "the file is damaged"},
      {"newer_format_version.vdb", absl::StatusCode::kInvalidArgument, "surfel format version 3"},
      {"no_point_count.vdb", absl::StatusCode::kInvalidArgument,
       "no \"pbgi_point_count\" metadata"},
      {"wrong_point_count.vdb", absl::StatusCode::kInvalidArgument,
       "metadata pbgi_point_count says 65"},
      {"point_count_is_string.vdb", absl::StatusCode::kInvalidArgument,
       "\"pbgi_point_count\" is a string; expected int64"},
  };
  for (const Case& c : cases) {
    const std::string path = hostile(c.file);
    ASSERT_TRUE(fs::exists(path)) << path;
    absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
    EXPECT_EQ(read.status().code(), c.code) << c.file << ": " << read.status();
    EXPECT_TRUE(mentions(read.status(), c.says)) << c.file << ": " << read.status();
    EXPECT_TRUE(mentions(read.status(), path)) << c.file << ": " << read.status();
  }
}

TEST(SurfelVdbTest, InspectDescribesAPointsGridThatDoesNotReadAndRefusesOthers) {
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(hostile("missing_radiance.vdb"));
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->pointCount, 64u);
  EXPECT_TRUE(info->problem.find("no \"radiance\" attribute") != std::string::npos)
      << info->problem;
  EXPECT_NE(info->toString().find("status: " + info->problem), std::string::npos);
  for (const char* file :
       {"garbage.vdb", "float_grid_named_surfels.vdb", "truncated.vdb", "crashes_openvdb.vdb"}) {
    EXPECT_FALSE(inspectSurfelVdb(hostile(file)).ok()) << file;
  }
}

// The committed valid file, written by writeSurfelVdb when the format was made, still
// reads: a change that breaks old files fails here. Its surfels are the formula below.
std::vector<Surfel> smallSurfels() {
  std::vector<Surfel> surfels(64);
  for (size_t i = 0; i < surfels.size(); ++i) {
    Surfel& s = surfels[i];
    const float t = float(i);
    // In one leaf on one side of the origin, so that the file (and those made from it)
    // stays small: each octant that points reach costs OpenVDB 9 KB of node masks.
    s.position = Vec3f(std::sin(t), std::cos(t * 0.7f), 0.03f * t - 1.0f) * 0.05f + Vec3f(0.1f);
    s.normal = normalize(Vec3f(std::cos(t), 0.5f, std::sin(t)));
    s.radius = 0.01f + 0.001f * t;
    s.albedo = Vec3f(0.5f, 0.25f + 0.01f * t, 0.9f);
    s.radiance = Vec3f(t * 100.0f, 1.0f / (t + 1.0f), 0.0f);
    s.materialClass = static_cast<MaterialClass>(i % 4);
    s.triangle = uint32_t(i * 2654435761u);
    s.barycentric = Vec2f(0.25f, 0.5f - 0.005f * t);
  }
  return surfels;
}

TEST(SurfelVdbTest, CommittedFileStillReads) {
  const std::string path = hostile("valid_small.vdb");
  if (std::getenv("PBGI_REGENERATE_VDB_TEST_DATA")) {
    SurfelVdbOptions options;
    options.metadata = {"test_shot", 7, 1234, "0.1.0"};
    ASSERT_TRUE(writeSurfelVdb(path, smallSurfels(), options).ok());
  }
  absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(path);
  ASSERT_TRUE(read.ok()) << read.status();
  const Errors e = compare(smallSurfels(), *read);
  EXPECT_LE(e.position, 1e-6f);
  EXPECT_LE(e.normal, 0.035f);
  EXPECT_LE(e.albedo, 0x1p-11f);
  EXPECT_EQ(e.inexact, 0u);
  absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(path);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->metadata.shot, "test_shot");
  EXPECT_EQ(info->metadata.frame, 7);
  EXPECT_EQ(info->metadata.seed, 1234u);
}

// A file cut anywhere, or with any byte changed, is rejected before OpenVDB parses it (some
// such files make OpenVDB write past its buffers: crashes_openvdb.vdb).
TEST(SurfelVdbTest, TruncatedOrDamagedFilesAreAlwaysRejected) {
  TempDir dir;
  const std::string good = dir.file("good.vdb");
  ASSERT_TRUE(writeSurfelVdb(good, randomSurfels(300, 12)).ok());
  const std::string bytes = readBytes(good);
  const std::string bad = dir.file("bad.vdb");
  auto expectRejected = [&](const std::string& what) {
    const absl::StatusOr<std::vector<Surfel>> read = readSurfelVdb(bad);
    // DataLoss from the content hash; InvalidArgument when the magic number, the version or
    // the header itself is gone. OpenVDB left alone answers some of these with bad_alloc, at
    // random, from sizes it never read, or with heap corruption.
    EXPECT_TRUE(read.status().code() == absl::StatusCode::kDataLoss ||
                read.status().code() == absl::StatusCode::kInvalidArgument)
        << what << ": " << read.status();
  };
  size_t cuts = 0;
  for (size_t size = 0; size < bytes.size(); size += 1 + bytes.size() / 97, ++cuts) {
    writeBytes(bad, bytes.substr(0, size));
    expectRejected("cut at " + std::to_string(size) + " of " + std::to_string(bytes.size()));
  }
  std::mt19937 rng(99);
  size_t changes = 0;
  for (size_t at = 0; at < bytes.size(); at += 1 + bytes.size() / 211, ++changes) {
    std::string damaged = bytes;
    damaged[at] = char(damaged[at] ^ (1 + rng() % 255));
    writeBytes(bad, damaged);
    expectRejected("byte " + std::to_string(at) + " changed");
  }
  EXPECT_GT(cuts, 90u);
  EXPECT_GT(changes, 200u);
}

}  // namespace
}  // namespace pbgi
