#include "formats/vdb/surfel_vdb.h"
#include "formats/util/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <new>
#include <optional>
#include <random>
#include <system_error>

#include <absl/strings/str_cat.h>
#include <absl/strings/str_format.h>
#include <absl/strings/str_join.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <openvdb/points/PointAttribute.h>
#include <openvdb/points/PointConversion.h>
#include <openvdb/points/PointDataGrid.h>
#include <xxhash.h>

#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
namespace vdbp = openvdb::points;

static_assert(std::endian::native == std::endian::little,
              "the checksum hashes the host's float bytes as little-endian");

constexpr char kGridName[] = "surfels";
// 2: radiance_back (surfels are two-sided).
constexpr int32_t kFormatVersion = 2;

constexpr char kP[] = "P";
constexpr char kN[] = "N";
constexpr char kRadius[] = "radius";
constexpr char kPscale[] = "pscale";
constexpr char kAlbedo[] = "albedo";
constexpr char kRadiance[] = "radiance";
constexpr char kRadianceBack[] = "radiance_back";
constexpr char kMaterialClass[] = "materialClass";
constexpr char kTriangle[] = "triangle";
constexpr char kBarycentric[] = "barycentric";
constexpr char kId[] = "id";

constexpr char kMetaFormatVersion[] = "pbgi_format_version";
constexpr char kMetaPointCount[] = "pbgi_point_count";
constexpr char kMetaChecksum[] = "pbgi_checksum";
constexpr char kMetaShot[] = "pbgi_shot";
constexpr char kMetaFrame[] = "pbgi_frame";
constexpr char kMetaSeed[] = "pbgi_seed";
constexpr char kMetaVersion[] = "pbgi_version";

// Voxel coordinates are int32; staying below 2^29 leaves OpenVDB's tree room at the edges.
constexpr double kMaxVoxelCoordinate = double(1 << 29);
// math::ScaleMap refuses voxels smaller than this volume (3e-15), i.e. edges below ~1.44e-5.
constexpr double kMinVoxelSize = 1.5e-5;
// The largest finite half float, the limit of the albedo codec.
constexpr float kMaxHalf = 65504.0f;
// Normals are unit vectors; stored as half floats their length may drift by 2^-11 more.
constexpr float kWriteUnitTolerance = 1e-3f;
constexpr float kReadUnitTolerance = 2e-3f;

void ensureOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::Vec3f toVdb(const Vec3f& v) { return {v.x, v.y, v.z}; }
Vec3f fromVdb(const openvdb::Vec3f& v) { return {v.x(), v.y(), v.z()}; }

// One Surfel field seen as the array that OpenVDB's point conversion wants (the
// PointAttributeVector interface), without copying it out of the span.
template <typename T, typename Field>
class SurfelFieldArray {
 public:
  using PosType = T;
  using value_type = T;

  SurfelFieldArray(std::span<const Surfel> surfels, Field field)
      : surfels_(surfels), field_(field) {}
  size_t size() const { return surfels_.size(); }
  void getPos(size_t n, T& xyz) const { xyz = field_(surfels_[n]); }
  void get(T& value, size_t n) const { value = field_(surfels_[n]); }
  void get(T& value, size_t n, openvdb::Index) const { value = field_(surfels_[n]); }

 private:
  std::span<const Surfel> surfels_;
  Field field_;
};

template <typename T, typename Field>
SurfelFieldArray<T, Field> fieldArray(std::span<const Surfel> surfels, Field field) {
  return SurfelFieldArray<T, Field>(surfels, field);
}

std::string formatVec(const Vec3f& v) { return absl::StrFormat("(%g, %g, %g)", v.x, v.y, v.z); }

// What no surfel holds, in a file or on its way to one; the message names the field.
absl::Status checkSurfel(const Surfel& s, float unitTolerance) {
  if (!isFinite(s.position)) {
    return absl::InvalidArgumentError("position " + formatVec(s.position) + " is not finite");
  }
  if (const float l = length(s.normal); !(std::abs(l - 1.0f) <= unitTolerance)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("normal %s has length %g; expected a unit vector", formatVec(s.normal), l));
  }
  if (!std::isfinite(s.radius) || s.radius < 0.0f) {
    return absl::InvalidArgumentError(
        absl::StrFormat("radius %g; expected a finite value >= 0", s.radius));
  }
  if (!isFinite(s.albedo)) {
    return absl::InvalidArgumentError("albedo " + formatVec(s.albedo) + " is not finite");
  }
  if (!isFinite(s.radiance)) {
    return absl::InvalidArgumentError("radiance " + formatVec(s.radiance) + " is not finite");
  }
  if (!isFinite(s.backRadiance)) {
    return absl::InvalidArgumentError("radiance_back " + formatVec(s.backRadiance) +
                                      " is not finite");
  }
  if (static_cast<uint8_t>(s.materialClass) > static_cast<uint8_t>(MaterialClass::kEmissive)) {
    return absl::InvalidArgumentError(absl::StrFormat("material class %d; expected 0 to %d",
                                                      static_cast<int>(s.materialClass),
                                                      static_cast<int>(MaterialClass::kEmissive)));
  }
  if (!std::isfinite(s.barycentric.x) || !std::isfinite(s.barycentric.y)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("barycentric (%g, %g) is not finite", s.barycentric.x, s.barycentric.y));
  }
  return absl::OkStatus();
}

absl::Status validateSurfels(const std::string& path, std::span<const Surfel> surfels) {
  for (size_t i = 0; i < surfels.size(); ++i) {
    const Surfel& s = surfels[i];
    absl::Status status = checkSurfel(s, kWriteUnitTolerance);
    if (status.ok() && maxAbsComponent(s.albedo) > kMaxHalf) {
      status = absl::InvalidArgumentError(
          absl::StrFormat("albedo %s; expected values within +-%g (stored as half floats)",
                          formatVec(s.albedo), kMaxHalf));
    }
    if (!status.ok()) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": surfel ", i, ": ", status.message()));
    }
  }
  return absl::OkStatus();
}

float maxAbsCoordinate(std::span<const Surfel> surfels) {
  float m = 0.0f;
  for (const Surfel& s : surfels) m = std::max(m, maxAbsComponent(s.position));
  return m;
}

absl::StatusOr<double> chooseVoxelSize(const std::string& path, std::span<const Surfel> surfels,
                                       const SurfelVdbOptions& options) {
  const double reach = maxAbsCoordinate(surfels);
  if (options.voxelSize != 0.0f) {
    if (!std::isfinite(options.voxelSize) || options.voxelSize < kMinVoxelSize) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: voxel size %g; expected 0 (chosen from the points) or at least %g",
                          path, options.voxelSize, kMinVoxelSize));
    }
    if (reach / options.voxelSize > kMaxVoxelCoordinate) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: voxel size %g is too small for points %g from the origin: voxel coordinates "
          "would pass %g; expected a voxel size of at least %g",
          path, options.voxelSize, reach, kMaxVoxelCoordinate, reach / kMaxVoxelCoordinate));
    }
    return double(options.voxelSize);
  }
  if (options.pointsPerVoxel == 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": points per voxel is 0; expected at least 1"));
  }
  const auto positions =
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.position); });
  const double chosen = vdbp::computeVoxelSize(positions, options.pointsPerVoxel);
  // A far-flung cloud of few points could otherwise get voxel coordinates past int32.
  return std::max({chosen, reach / kMaxVoxelCoordinate, kMinVoxelSize});
}

using PositionCodec = vdbp::FixedPointCodec</*OneByte=*/false, vdbp::PositionRange>;

template <typename T, typename Codec, typename Array>
void addAttribute(vdbp::PointDataTree& tree, const openvdb::tools::PointIndexTree& indexTree,
                  const char* name, const Array& values) {
  vdbp::appendAttribute<T, Codec>(tree, name);
  vdbp::populateAttribute(tree, indexTree, name, values);
}

vdbp::PointDataGrid::Ptr buildGrid(std::span<const Surfel> surfels, double voxelSize,
                                   SurfelVdbNormals normalEncoding) {
  const openvdb::math::Transform::Ptr transform =
      openvdb::math::Transform::createLinearTransform(voxelSize);
  const auto positions =
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.position); });
  const auto index =
      openvdb::tools::createPointIndexGrid<openvdb::tools::PointIndexGrid>(positions, *transform);
  vdbp::PointDataGrid::Ptr grid =
      vdbp::createPointDataGrid<PositionCodec, vdbp::PointDataGrid>(*index, positions, *transform);
  vdbp::PointDataTree& tree = grid->tree();
  const auto& indexTree = index->tree();

  using vdbp::NullCodec;
  const auto normals =
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.normal); });
  switch (normalEncoding) {
    case SurfelVdbNormals::kUnitVector16:
      addAttribute<openvdb::Vec3f, vdbp::UnitVecCodec>(tree, indexTree, kN, normals);
      break;
    case SurfelVdbNormals::kHalf:
      addAttribute<openvdb::Vec3f, vdbp::TruncateCodec>(tree, indexTree, kN, normals);
      break;
    case SurfelVdbNormals::kFloat:
      addAttribute<openvdb::Vec3f, NullCodec>(tree, indexTree, kN, normals);
      break;
  }
  const auto radii = fieldArray<float>(surfels, [](const Surfel& s) { return s.radius; });
  addAttribute<float, NullCodec>(tree, indexTree, kRadius, radii);
  addAttribute<float, NullCodec>(tree, indexTree, kPscale, radii);
  addAttribute<openvdb::Vec3f, vdbp::TruncateCodec>(
      tree, indexTree, kAlbedo,
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.albedo); }));
  addAttribute<openvdb::Vec3f, NullCodec>(
      tree, indexTree, kRadiance,
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.radiance); }));
  addAttribute<openvdb::Vec3f, NullCodec>(
      tree, indexTree, kRadianceBack,
      fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) { return toVdb(s.backRadiance); }));
  addAttribute<int32_t, NullCodec>(tree, indexTree, kMaterialClass,
                                   fieldArray<int32_t>(surfels, [](const Surfel& s) {
                                     return static_cast<int32_t>(s.materialClass);
                                   }));
  addAttribute<int32_t, NullCodec>(tree, indexTree, kTriangle,
                                   fieldArray<int32_t>(surfels, [](const Surfel& s) {
                                     return std::bit_cast<int32_t>(s.triangle);
                                   }));
  addAttribute<openvdb::Vec3f, NullCodec>(
      tree, indexTree, kBarycentric, fieldArray<openvdb::Vec3f>(surfels, [](const Surfel& s) {
        return openvdb::Vec3f(s.barycentric.x, s.barycentric.y, 0.0f);
      }));
  // The id is the position in the span; the wrapper is handed indices, not surfels.
  const Surfel* base = surfels.data();
  addAttribute<int64_t, NullCodec>(
      tree, indexTree, kId,
      fieldArray<int64_t>(surfels, [base](const Surfel& s) { return int64_t(&s - base); }));
  // Attributes constant over a leaf (often materialClass) shrink to one value.
  vdbp::compactAttributes(tree);
  grid->setName(kGridName);
  return grid;
}

// ---- Metadata --------------------------------------------------------------------------

template <typename T>
absl::StatusOr<std::optional<T>> findMeta(const openvdb::GridBase& grid, const std::string& name,
                                          const std::string& path) {
  const openvdb::Metadata::ConstPtr meta = grid[name];
  if (!meta) return std::nullopt;
  using MetaT = openvdb::TypedMetadata<T>;
  const auto* typed = dynamic_cast<const MetaT*>(meta.get());
  if (!typed) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": grid metadata \"", name, "\" is a ",
                                                   meta->typeName(), "; expected ",
                                                   MetaT::staticTypeName()));
  }
  return typed->value();
}

template <typename T>
absl::StatusOr<T> requireMeta(const openvdb::GridBase& grid, const std::string& name,
                              const std::string& path) {
  absl::StatusOr<std::optional<T>> value = findMeta<T>(grid, name, path);
  if (!value.ok()) return value.status();
  if (!value->has_value()) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": grid \"", kGridName, "\" has no \"", name,
                     "\" metadata; expected a file written by pbgi's writeSurfelVdb"));
  }
  return **value;
}

absl::StatusOr<SurfelVdbMetadata> readProvenance(const openvdb::GridBase& grid,
                                                 const std::string& path) {
  SurfelVdbMetadata m;
  absl::StatusOr<std::string> shot = requireMeta<std::string>(grid, kMetaShot, path);
  if (!shot.ok()) return shot.status();
  absl::StatusOr<int32_t> frame = requireMeta<int32_t>(grid, kMetaFrame, path);
  if (!frame.ok()) return frame.status();
  absl::StatusOr<int64_t> seed = requireMeta<int64_t>(grid, kMetaSeed, path);
  if (!seed.ok()) return seed.status();
  absl::StatusOr<std::string> version = requireMeta<std::string>(grid, kMetaVersion, path);
  if (!version.ok()) return version.status();
  m.shot = *shot;
  m.frame = *frame;
  m.seed = std::bit_cast<uint64_t>(*seed);
  m.pbgiVersion = *version;
  return m;
}

// ---- Decoding --------------------------------------------------------------------------

using PointLeaf = vdbp::PointDataTree::LeafNodeType;

std::string leafName(const std::string& path, const PointLeaf& leaf) {
  const openvdb::Coord o = leaf.origin();
  return absl::StrFormat("%s: leaf at (%d, %d, %d)", path, o.x(), o.y(), o.z());
}

// One attribute of one leaf, checked for presence, value type and stride before OpenVDB's
// handle (which would throw, or read past the end) is made for it.
template <typename T>
absl::StatusOr<vdbp::AttributeHandle<T>> attributeHandle(const PointLeaf& leaf, const char* name,
                                                         const std::string& path) {
  const size_t pos = leaf.attributeSet().find(name);
  const std::string where = leafName(path, leaf);
  if (pos == vdbp::AttributeSet::INVALID_POS) {
    return absl::InvalidArgumentError(absl::StrCat(
        where, ": no \"", name, "\" attribute; expected a ", openvdb::typeNameAsString<T>(),
        " attribute \"", name, "\" as written by pbgi's writeSurfelVdb"));
  }
  const vdbp::AttributeArray& array = leaf.constAttributeArray(pos);
  if (!array.hasValueType<T>()) {
    return absl::InvalidArgumentError(absl::StrCat(where, ": attribute \"", name, "\" holds ",
                                                   array.valueType(), "; expected ",
                                                   openvdb::typeNameAsString<T>()));
  }
  if (!array.hasConstantStride() || array.stride() != 1) {
    return absl::InvalidArgumentError(absl::StrCat(
        where, ": attribute \"", name, "\" has stride ",
        array.hasConstantStride() ? absl::StrCat(array.stride()) : std::string("(varying)"),
        "; expected 1"));
  }
  return vdbp::AttributeHandle<T>(array, /*collapseOnDestruction=*/false);
}

absl::Status badPoint(const std::string& path, int64_t id, absl::string_view what) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": surfel id ", id, ": ", what));
}

// Every point of the grid, in id order, with every check a hostile file calls for. The
// writer runs it on its own grid too, so that the checksum describes exactly what a reader
// will decode.
absl::StatusOr<std::vector<Surfel>> decodeSurfels(const vdbp::PointDataGrid& grid,
                                                  const std::string& path) {
  absl::StatusOr<int32_t> version = requireMeta<int32_t>(grid, kMetaFormatVersion, path);
  if (!version.ok()) return version.status();
  if (*version != kFormatVersion) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: surfel format version %d; this pbgi reads version %d", path, *version,
                        kFormatVersion));
  }
  absl::StatusOr<int64_t> claimed = requireMeta<int64_t>(grid, kMetaPointCount, path);
  if (!claimed.ok()) return claimed.status();

  const vdbp::PointDataTree& tree = grid.tree();
  uint64_t total = 0;
  for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
    try {
      leaf->validateOffsets();
    } catch (const openvdb::Exception& e) {
      return absl::InvalidArgumentError(
          absl::StrCat(leafName(path, *leaf), " is inconsistent: ", e.what()));
    }
    total += leaf->pointCount();
  }
  if (*claimed < 0 || static_cast<uint64_t>(*claimed) != total) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the grid holds %d points; metadata %s says %d", path, total,
                        kMetaPointCount, *claimed));
  }

  std::vector<Surfel> surfels(total);
  std::vector<uint8_t> seen(total, 0);
  const openvdb::math::Transform& transform = grid.transform();
  for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
    if (leaf->pointCount() == 0) continue;
    auto p = attributeHandle<openvdb::Vec3f>(*leaf, kP, path);
    auto n = attributeHandle<openvdb::Vec3f>(*leaf, kN, path);
    auto radius = attributeHandle<float>(*leaf, kRadius, path);
    auto albedo = attributeHandle<openvdb::Vec3f>(*leaf, kAlbedo, path);
    auto radiance = attributeHandle<openvdb::Vec3f>(*leaf, kRadiance, path);
    auto radianceBack = attributeHandle<openvdb::Vec3f>(*leaf, kRadianceBack, path);
    auto material = attributeHandle<int32_t>(*leaf, kMaterialClass, path);
    auto triangle = attributeHandle<int32_t>(*leaf, kTriangle, path);
    auto barycentric = attributeHandle<openvdb::Vec3f>(*leaf, kBarycentric, path);
    auto id = attributeHandle<int64_t>(*leaf, kId, path);
    for (const absl::Status& s :
         {p.status(), n.status(), radius.status(), albedo.status(), radiance.status(),
          radianceBack.status(), material.status(), triangle.status(), barycentric.status(), id.status()}) {
      if (!s.ok()) return s;
    }
    // Points are stored voxel by voxel: voxel v holds indices [offset(v-1), offset(v)).
    openvdb::Index begin = 0;
    for (openvdb::Index v = 0; v < PointLeaf::SIZE; ++v) {
      const openvdb::Index end = leaf->getValue(v);
      const openvdb::Vec3d voxel = leaf->offsetToGlobalCoord(v).asVec3d();
      for (openvdb::Index i = begin; i < end; ++i) {
        const int64_t key = id->get(i);
        if (key < 0 || static_cast<uint64_t>(key) >= total) {
          return badPoint(path, key, absl::StrCat("out of range; expected ids 0 to ", total - 1));
        }
        if (seen[key]) return badPoint(path, key, "appears twice");
        seen[key] = 1;
        Surfel& s = surfels[key];
        const openvdb::Vec3d world = transform.indexToWorld(voxel + openvdb::Vec3d(p->get(i)));
        s.position = Vec3f(float(world.x()), float(world.y()), float(world.z()));
        s.normal = fromVdb(n->get(i));
        s.radius = radius->get(i);
        s.albedo = fromVdb(albedo->get(i));
        s.radiance = fromVdb(radiance->get(i));
        s.backRadiance = fromVdb(radianceBack->get(i));
        const int32_t m = material->get(i);
        if (m < 0 || m > static_cast<int32_t>(MaterialClass::kEmissive)) {
          return badPoint(path, key,
                          absl::StrFormat("material class %d; expected 0 to %d", m,
                                          static_cast<int>(MaterialClass::kEmissive)));
        }
        s.materialClass = static_cast<MaterialClass>(m);
        s.triangle = std::bit_cast<uint32_t>(triangle->get(i));
        const openvdb::Vec3f b = barycentric->get(i);
        s.barycentric = Vec2f(b.x(), b.y());

        if (absl::Status st = checkSurfel(s, kReadUnitTolerance); !st.ok())
          return badPoint(path, key, st.message());
      }
      begin = end;
    }
  }
  return surfels;
}

// XXH3-64 over the fields of every surfel in order (77 bytes each, little-endian, no padding),
// then the provenance: a damaged shot name or seed is as wrong as a damaged surfel.
std::string surfelChecksum(const std::vector<Surfel>& surfels, const SurfelVdbMetadata& meta) {
  XXH3_state_t* state = XXH3_createState();
  PBGI_CHECK(state != nullptr);
  XXH3_64bits_reset(state);
  std::array<unsigned char, 77> bytes;
  for (const Surfel& s : surfels) {
    unsigned char* out = bytes.data();
    auto put = [&out](const void* data, size_t size) {
      std::memcpy(out, data, size);
      out += size;
    };
    const float floats[] = {s.position.x, s.position.y, s.position.z, s.normal.x, s.normal.y,
                            s.normal.z,   s.radius,     s.albedo.x,   s.albedo.y, s.albedo.z,
                            s.radiance.x, s.radiance.y, s.radiance.z, s.backRadiance.x,
                            s.backRadiance.y, s.backRadiance.z};
    put(floats, sizeof(floats));
    const uint8_t material = static_cast<uint8_t>(s.materialClass);
    put(&material, 1);
    put(&s.triangle, 4);
    const float bary[] = {s.barycentric.x, s.barycentric.y};
    put(bary, sizeof(bary));
    PBGI_CHECK_EQ(static_cast<size_t>(out - bytes.data()), bytes.size());
    XXH3_64bits_update(state, bytes.data(), bytes.size());
  }
  auto putString = [state](const std::string& text) {
    const uint64_t size = text.size();
    XXH3_64bits_update(state, &size, sizeof(size));
    XXH3_64bits_update(state, text.data(), text.size());
  };
  putString(meta.shot);
  XXH3_64bits_update(state, &meta.frame, sizeof(meta.frame));
  XXH3_64bits_update(state, &meta.seed, sizeof(meta.seed));
  putString(meta.pbgiVersion);
  const XXH64_hash_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return absl::StrFormat("xxh3_64:%016x", hash);
}

// ---- Files -----------------------------------------------------------------------------

// OpenVDB's header (format 218 and later): magic number (8 bytes), format version (4),
// library major and minor version (4 + 4), has-grid-offsets (1), then the file's UUID as 36
// characters.
constexpr size_t kUuidOffset = 21;
constexpr size_t kUuidSize = 36;
constexpr size_t kHeaderSize = kUuidOffset + kUuidSize;

// XXH3-128 of every byte of the file but the UUID's, as an RFC 9562 version 8 ("custom")
// UUID. OpenVDB's own UUID is random, the one thing that differs between two writes of the
// same grid; this one makes writes reproducible, and, since OpenVDB has no checksums and
// trusts every size it reads (a damaged file can make it write past its buffers), lets the
// reader reject any damaged or truncated file before OpenVDB parses a byte of it.
std::string contentUuid(std::istream& in) {
  XXH3_state_t* state = XXH3_createState();
  PBGI_CHECK(state != nullptr);
  XXH3_128bits_reset(state);
  std::vector<char> buffer(1 << 16);
  uint64_t offset = 0;
  while (in.read(buffer.data(), static_cast<std::streamsize>(buffer.size())) || in.gcount() > 0) {
    const uint64_t got = static_cast<uint64_t>(in.gcount());
    // The part of [offset, offset + got) before the UUID, then the part after it.
    const uint64_t before = std::clamp<uint64_t>(kUuidOffset, offset, offset + got) - offset;
    const uint64_t after = std::clamp<uint64_t>(kHeaderSize, offset, offset + got) - offset;
    XXH3_128bits_update(state, buffer.data(), before);
    XXH3_128bits_update(state, buffer.data() + after, got - after);
    offset += got;
  }
  const XXH128_hash_t h = XXH3_128bits_digest(state);
  XXH3_freeState(state);
  const uint64_t hi = (h.high64 & ~uint64_t{0xf000}) | uint64_t{0x8000};
  const uint64_t lo = (h.low64 & ~(uint64_t{3} << 62)) | (uint64_t{2} << 62);
  return absl::StrFormat("%08x-%04x-%04x-%04x-%012x", hi >> 32, (hi >> 16) & 0xffff, hi & 0xffff,
                         lo >> 48, lo & 0xffffffffffffULL);
}

// Replaces the random UUID that OpenVDB wrote into `tmp` (`written`) with contentUuid.
absl::Status writeContentUuid(const std::string& tmp, const std::string& written) {
  std::fstream file(tmp, std::ios::in | std::ios::out | std::ios::binary);
  std::string header(kHeaderSize, '\0');
  file.read(header.data(), static_cast<std::streamsize>(header.size()));
  if (!file || header.substr(kUuidOffset) != written) {
    return absl::InternalError(absl::StrCat("cannot find OpenVDB's file UUID \"", written,
                                            "\" at byte ", kUuidOffset, " of ", tmp));
  }
  file.seekg(0);
  const std::string uuid = contentUuid(file);
  file.clear();
  file.seekp(static_cast<std::streamoff>(kUuidOffset));
  file.write(uuid.data(), static_cast<std::streamsize>(uuid.size()));
  file.flush();
  if (!file) return absl::UnavailableError(absl::StrCat("cannot rewrite the UUID of ", tmp));
  return absl::OkStatus();
}

absl::Status writeGridAtomically(const std::string& path, const vdbp::PointDataGrid::Ptr& grid) {
  auto atomic = AtomicFile::begin(path);
  if (!atomic.ok()) return atomic.status();
  const std::string& tmp = atomic->tempPath();
  std::string uuid;
  try {
    openvdb::io::File file(tmp);
    file.setCompression(openvdb::io::Archive::hasBloscCompression()
                            ? openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK
                            : openvdb::io::COMPRESS_ZIP | openvdb::io::COMPRESS_ACTIVE_MASK);
    file.write(openvdb::GridCPtrVec{grid});
    uuid = file.getUniqueTag();
    file.close();
  } catch (const std::exception& e) {
    return absl::UnavailableError(absl::StrCat(path, ": writing ", tmp, ": ", e.what()));
  }
  if (absl::Status s = writeContentUuid(tmp, uuid); !s.ok()) return withContext(s, path);
  return atomic->commit();
}

struct LoadedGrid {
  vdbp::PointDataGrid::Ptr grid;
  uint64_t fileBytes = 0;
  std::string vdbVersion;
};

std::string describeGrids(const openvdb::GridPtrVec& grids) {
  if (grids.empty()) return "no grids";
  std::vector<std::string> names;
  for (const auto& g : grids)
    names.push_back(absl::StrCat("\"", g->getName(), "\" (", g->type(), ")"));
  return absl::StrJoin(names, ", ");
}

// Everything that can be checked before OpenVDB parses the file: its magic number, format
// version, and that its contents still hash to the UUID in its header. Leaves `in` at the
// start, so that OpenVDB reads the very bytes that were checked.
absl::Status checkHeaderAndContents(std::istream& in, const std::string& path) {
  std::string header(kHeaderSize, '\0');
  in.read(header.data(), static_cast<std::streamsize>(header.size()));
  const size_t got = static_cast<size_t>(in.gcount());
  int64_t magic = 0;
  uint32_t version = 0;
  std::memcpy(&magic, header.data(), sizeof(magic));
  std::memcpy(&version, header.data() + sizeof(magic), sizeof(version));
  if (got < sizeof(magic) + sizeof(version)) {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": not an OpenVDB file: shorter than its 12-byte magic number and version"));
  }
  if (magic != openvdb::OPENVDB_MAGIC) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: not an OpenVDB file: starts with %#018x; expected the magic "
                        "number %#018x",
                        path, magic, openvdb::OPENVDB_MAGIC));
  }
  // For a format newer than it knows, OpenVDB only logs a warning and reads on.
  if (version < openvdb::OPENVDB_FILE_VERSION_MULTIPASS_IO ||
      version > openvdb::OPENVDB_FILE_VERSION) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: OpenVDB file format version %d; this OpenVDB (%s) reads points grids of versions "
        "%d to %d",
        path, version, openvdb::getLibraryVersionString(),
        openvdb::OPENVDB_FILE_VERSION_MULTIPASS_IO, openvdb::OPENVDB_FILE_VERSION));
  }
  if (got < kHeaderSize) {
    return absl::DataLossError(
        absl::StrFormat("%s: truncated: %d bytes, shorter than the %d-byte OpenVDB header", path,
                        got, kHeaderSize));
  }
  const std::string uuid = header.substr(kUuidOffset);
  if (uuid[14] != '8') {
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": its UUID ", uuid,
        " is not a hash of its contents: it was not written by pbgi's writeSurfelVdb, or "
        "another program has saved it since; pbgi reads only its own surfel files"));
  }
  in.clear();
  in.seekg(0);
  if (const std::string actual = contentUuid(in); actual != uuid) {
    return absl::DataLossError(absl::StrCat(path, ": damaged or truncated: its contents hash to ",
                                            actual, " but its header says ", uuid));
  }
  in.clear();
  in.seekg(0);
  return absl::OkStatus();
}

// Reads the "surfels" points grid from `in` (the whole file, `fileBytes` long, from its first
// byte), turning everything OpenVDB throws into a status that names the file.
absl::StatusOr<LoadedGrid> loadSurfelGrid(std::istream& in, const std::string& path,
                                          uint64_t fileBytes) {
  ensureOpenVdb();
  LoadedGrid loaded;
  loaded.fileBytes = fileBytes;
  if (loaded.fileBytes == 0) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": empty file; expected an OpenVDB file"));
  }
  if (absl::Status s = checkHeaderAndContents(in, path); !s.ok()) return s;
  try {
    // The contents are what pbgi wrote; what follows guards against a writer that went wrong.
    // OpenVDB does not check its reads: from a short file it goes on with sizes it never
    // read, which can be anything (its io::File gave bad_alloc or a decompression error at
    // random). A stream that throws at the first short read stops it there. No delayed
    // loading either: every byte is read, and every error thrown, inside this try.
    in.exceptions(std::ios::failbit | std::ios::badbit | std::ios::eofbit);
    openvdb::io::Stream stream(in, /*delayLoad=*/false);
    loaded.vdbVersion = stream.version();
    const openvdb::GridPtrVecPtr grids = stream.getGrids();
    const auto found = std::find_if(grids->begin(), grids->end(),
                                    [](const auto& g) { return g->getName() == kGridName; });
    if (found == grids->end()) {
      return absl::InvalidArgumentError(absl::StrCat(path, ": no grid named \"", kGridName,
                                                     "\"; the file holds ", describeGrids(*grids)));
    }
    loaded.grid = openvdb::gridPtrCast<vdbp::PointDataGrid>(*found);
    if (!loaded.grid) {
      return absl::InvalidArgumentError(absl::StrCat(
          path, ": grid \"", kGridName, "\" is a ", (*found)->type(),
          "; expected an OpenVDB points grid (", vdbp::PointDataGrid::gridType(), ")"));
    }
  } catch (const std::ios_base::failure&) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: not a readable OpenVDB file: it ends (at %d bytes) before the data it declares", path,
        loaded.fileBytes));
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(
        absl::StrCat(path, ": out of memory reading it (does its header claim too much?)"));
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": not a readable OpenVDB file: ", e.what()));
  }
  return loaded;
}

// Opens `path` (a regular file that can be read) and reads its grid.
absl::StatusOr<LoadedGrid> loadSurfelGrid(const std::string& path) {
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) return absl::NotFoundError(absl::StrCat(path, ": no such file"));
  if (!fs::is_regular_file(status)) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": not a regular file; expected an OpenVDB file"));
  }
  if (::access(path.c_str(), R_OK) != 0) {
    const int error = errno;
    return absl::ErrnoToStatus(error, absl::StrCat(path, ": cannot read"));
  }
  const uint64_t fileBytes = fs::file_size(path, ec);
  if (ec) return absl::ErrnoToStatus(ec.value(), absl::StrCat(path, ": cannot get its size"));
  std::ifstream in(path, std::ios::binary);
  return loadSurfelGrid(in, path, fileBytes);
}

// The grid of a file held by a seekable stream: its size is where the stream ends.
absl::StatusOr<LoadedGrid> loadSurfelGridFromStream(std::istream& in, const std::string& name) {
  in.seekg(0, std::ios::end);
  const std::streamoff end = in.tellg();
  if (end < 0) return absl::InvalidArgumentError(absl::StrCat(name, ": cannot seek in the stream"));
  in.seekg(0);
  return loadSurfelGrid(in, name, static_cast<uint64_t>(end));
}

absl::StatusOr<std::vector<Surfel>> decodeAndVerify(const vdbp::PointDataGrid& grid,
                                                    const std::string& path) {
  absl::StatusOr<SurfelVdbMetadata> provenance = readProvenance(grid, path);
  if (!provenance.ok()) return provenance.status();
  absl::StatusOr<std::vector<Surfel>> surfels = decodeSurfels(grid, path);
  if (!surfels.ok()) return surfels.status();
  absl::StatusOr<std::string> stored = requireMeta<std::string>(grid, kMetaChecksum, path);
  if (!stored.ok()) return stored.status();
  const std::string actual = surfelChecksum(*surfels, *provenance);
  if (*stored != actual) {
    return absl::DataLossError(absl::StrCat(path, ": the surfels and their provenance hash to ",
                                            actual, "; metadata ", kMetaChecksum, " says ", *stored,
                                            ": the file is damaged"));
  }
  return surfels;
}

}  // namespace

absl::Status writeSurfelVdb(const std::string& path, std::span<const Surfel> surfels,
                            const SurfelVdbOptions& options) {
  ensureOpenVdb();
  if (absl::Status s = validateSurfels(path, surfels); !s.ok()) return s;
  absl::StatusOr<double> voxelSize = chooseVoxelSize(path, surfels, options);
  if (!voxelSize.ok()) return voxelSize.status();
  vdbp::PointDataGrid::Ptr grid;
  try {
    grid = buildGrid(surfels, *voxelSize, options.normals);
    grid->insertMeta(kMetaFormatVersion, openvdb::Int32Metadata(kFormatVersion));
    grid->insertMeta(kMetaPointCount, openvdb::Int64Metadata(static_cast<int64_t>(surfels.size())));
    grid->insertMeta(kMetaShot, openvdb::StringMetadata(options.metadata.shot));
    grid->insertMeta(kMetaFrame, openvdb::Int32Metadata(options.metadata.frame));
    grid->insertMeta(kMetaSeed,
                     openvdb::Int64Metadata(std::bit_cast<int64_t>(options.metadata.seed)));
    grid->insertMeta(kMetaVersion, openvdb::StringMetadata(options.metadata.pbgiVersion));
    // The checksum is of what a reader will decode (quantized), so decode our own grid.
    absl::StatusOr<std::vector<Surfel>> stored = decodeSurfels(*grid, path);
    if (!stored.ok()) {
      return absl::InternalError(
          absl::StrCat("the grid just built does not decode: ", stored.status().message()));
    }
    grid->insertMeta(kMetaChecksum,
                     openvdb::StringMetadata(surfelChecksum(*stored, options.metadata)));
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrCat(
        path, ": out of memory building the OpenVDB grid of ", surfels.size(), " surfels"));
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(path, ": building the OpenVDB grid of ", surfels.size(),
                                            " surfels: ", e.what()));
  }
  return writeGridAtomically(path, grid);
}

namespace {

absl::StatusOr<std::vector<Surfel>> readLoaded(absl::StatusOr<LoadedGrid> loaded,
                                               const std::string& path) {
  if (!loaded.ok()) return loaded.status();
  try {
    return decodeAndVerify(*loaded->grid, path);
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrCat(path, ": out of memory decoding surfels"));
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": cannot decode surfels: ", e.what()));
  }
}

}  // namespace

absl::StatusOr<std::vector<Surfel>> readSurfelVdb(const std::string& path) {
  return readLoaded(loadSurfelGrid(path), path);
}

absl::StatusOr<std::vector<Surfel>> readSurfelVdb(std::istream& in, const std::string& name) {
  return readLoaded(loadSurfelGridFromStream(in, name), name);
}

double SurfelVdbInfo::fileBytesPerPoint() const {
  return pointCount == 0 ? 0.0 : double(fileBytes) / double(pointCount);
}

double SurfelVdbInfo::memoryBytesPerPoint() const {
  return pointCount == 0 ? 0.0 : double(memoryBytes) / double(pointCount);
}

std::string SurfelVdbInfo::toString() const {
  std::string s = absl::StrFormat("%s: OpenVDB %s, %d bytes, %s compression\n", path, vdbVersion,
                                  fileBytes, compression.empty() ? "unknown" : compression);
  absl::StrAppendFormat(&s, "  points: %d in %d leaves, %d active voxels, voxel size %s\n",
                        pointCount, leafCount, activeVoxelCount, formatVec(voxelSize));
  if (bounds.empty()) {
    absl::StrAppend(&s, "  bounds: none\n");
  } else {
    absl::StrAppendFormat(&s, "  bounds: %s to %s\n", formatVec(bounds.min), formatVec(bounds.max));
  }
  absl::StrAppendFormat(&s, "  bytes per point: %.2f in the file, %.2f in memory (%d bytes)\n",
                        fileBytesPerPoint(), memoryBytesPerPoint(), memoryBytes);
  absl::StrAppend(&s, "  attributes:", attributes.empty() ? " none (no points)\n" : "\n");
  for (const SurfelVdbAttributeInfo& a : attributes) {
    absl::StrAppendFormat(&s, "    %-14s %-6s %-7s %d bytes in memory\n", a.name, a.valueType,
                          a.codec, a.memoryBytes);
  }
  absl::StrAppendFormat(&s, "  shot \"%s\", frame %d, seed %d, baked by pbgi %s\n", metadata.shot,
                        metadata.frame, metadata.seed,
                        metadata.pbgiVersion.empty() ? "(unknown)" : metadata.pbgiVersion);
  absl::StrAppend(&s, "  metadata:\n");
  for (const auto& [name, value] : gridMetadata) {
    absl::StrAppendFormat(&s, "    %s = %s\n", name, value);
  }
  absl::StrAppend(&s, "  status: ", problem.empty() ? "ok" : problem, "\n");
  return s;
}

namespace {

absl::StatusOr<SurfelVdbInfo> inspectLoaded(absl::StatusOr<LoadedGrid> loaded,
                                            const std::string& path) {
  if (!loaded.ok()) return loaded.status();
  const vdbp::PointDataGrid& grid = *loaded->grid;
  SurfelVdbInfo info;
  info.path = path;
  info.fileBytes = loaded->fileBytes;
  info.vdbVersion = loaded->vdbVersion;
  try {
    const vdbp::PointDataTree& tree = grid.tree();
    info.leafCount = tree.leafCount();
    info.activeVoxelCount = tree.activeVoxelCount();
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) info.pointCount += leaf->pointCount();
    const openvdb::Vec3d voxel = grid.voxelSize();
    info.voxelSize = Vec3f(float(voxel.x()), float(voxel.y()), float(voxel.z()));
    info.memoryBytes = grid.memUsage();
    if (auto leaf = tree.cbeginLeaf()) {
      const vdbp::AttributeSet::Descriptor& descriptor = leaf->attributeSet().descriptor();
      std::vector<std::pair<size_t, std::string>> byPosition;
      for (const auto& [name, pos] : descriptor.map()) byPosition.emplace_back(pos, name);
      std::sort(byPosition.begin(), byPosition.end());
      for (const auto& [pos, name] : byPosition) {
        SurfelVdbAttributeInfo a;
        a.name = name;
        a.valueType = descriptor.valueType(pos);
        a.codec = descriptor.type(pos).second;
        for (auto l = tree.cbeginLeaf(); l; ++l) {
          if (pos < l->attributeSet().size())
            a.memoryBytes += l->constAttributeArray(pos).memUsage();
        }
        info.attributes.push_back(std::move(a));
      }
    }
    for (auto it = grid.beginMeta(); it != grid.endMeta(); ++it) {
      info.gridMetadata.emplace_back(it->first, it->second->str());
    }
    if (auto c = findMeta<std::string>(grid, openvdb::GridBase::META_FILE_COMPRESSION, path);
        c.ok() && c->has_value()) {
      info.compression = **c;
    }
    if (absl::StatusOr<SurfelVdbMetadata> m = readProvenance(grid, path); m.ok()) {
      info.metadata = *m;
    }
    absl::StatusOr<std::vector<Surfel>> surfels = decodeAndVerify(grid, path);
    if (surfels.ok()) {
      for (const Surfel& s : *surfels) info.bounds.extend(s.position);
    } else {
      info.problem = std::string(surfels.status().message());
    }
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrCat(path, ": out of memory inspecting it"));
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": cannot inspect: ", e.what()));
  }
  return info;
}

}  // namespace

absl::StatusOr<SurfelVdbInfo> inspectSurfelVdb(const std::string& path) {
  return inspectLoaded(loadSurfelGrid(path), path);
}

absl::StatusOr<SurfelVdbInfo> inspectSurfelVdb(std::istream& in, const std::string& name) {
  return inspectLoaded(loadSurfelGridFromStream(in, name), name);
}

}  // namespace pbgi
