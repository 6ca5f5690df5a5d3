#pragma once
// Surfel point clouds as OpenVDB points (a PointDataGrid named "surfels"), the file that
// `pbgi bake` leaves beside each frame's .pbgi tree: Houdini and other OpenVDB tools open it
// to look at what was baked, `pbgi inspect` summarises it, and readSurfelVdb gets the surfels
// back. OpenVDB stays behind this header (its headers are heavy and its exceptions are turned
// into absl::Status here).
//
// What the file holds, one attribute per Surfel field, all of them types that OpenVDB
// registers and that Houdini's VDB points conversion knows (vec3s, float, int32, int64):
//
//   P              vec3s, fxpt16: OpenVDB's 16-bit fixed point, relative to the voxel
//   N              vec3s; by default uvec, OpenVDB's 16-bit unit-vector codec (2 bytes);
//                  SurfelVdbOptions::normals picks half or full floats instead
//   radius         float, full precision
//   pscale         float, a copy of radius: Houdini sizes and instances points by "pscale"
//   albedo         vec3s, trnc: OpenVDB's "truncate" codec, half floats (rounded)
//   radiance       vec3s, full float (HDR: half would clip above 65504 and band the darks): the
//                  front side's (along N)
//   radiance_back  vec3s, full float: the back side's (surfaces are two-sided; format 2)
//   materialClass  int32, MaterialClass's value
//   triangle       int32, the uint32 triangle id bit for bit (ids >= 2^31 look negative in
//                  Houdini, and read back exactly)
//   barycentric    vec3s, (b1, b2, 0) full float: Houdini's primuv convention for triangles
//                  (OpenVDB registers no 2-vector attribute type)
//   id             int64, the surfel's index in the written span: OpenVDB stores points
//                  voxel by voxel, and the reader puts them back in writing order by id
//
// Grid metadata: pbgi_format_version, pbgi_point_count, pbgi_shot, pbgi_frame, pbgi_seed
// (the uint64 bit for bit in an int64), pbgi_version, and pbgi_checksum: XXH3-64 of the
// decoded surfels and those four provenance entries.
//
// Precision of a read-back, as measured by tests/formats/vdb/surfel_vdb_test.cpp on 10,000
// random surfels:
//   position    within voxelSize / 65535 per axis (the codec truncates), plus float rounding
//               at the position's magnitude: 1.54e-5 voxels measured
//   normal      uvec: within 0.035 rad (2 degrees; 0.0324 measured); half: within 1e-3 rad
//               (3.7e-4 measured); float: exact. Stored normals must be unit length (1e-3)
//   albedo      half floats: relative error at most 2^-11 (4.86e-4 measured) for albedos of
//               2^-14 and more, absolute error at most 2^-12 for albedos up to 1
//   everything else exact.
// Size: about 29 bytes a point in the file (48 in memory) for a million surfels on
// surfaces, 59 for 10,000 random ones in a box, where neither blosc nor the voxels help.
//
// Writes are atomic (a temporary file beside the target, renamed into place) and
// deterministic: the same surfels and options give a byte-identical file. OpenVDB puts a
// random UUID in each header; writeSurfelVdb replaces it with a hash of the rest of the file.
//
// Hostile files. OpenVDB has no checksums and trusts every size it reads: a truncated file
// gets it to allocate from sizes it never read, and one changed byte can make it write past
// its buffers (tests/data/vdb/crashes_openvdb.vdb). So the reader first checks that the file
// still hashes to the UUID in its header, and rejects (DataLoss) any damaged or truncated
// file before OpenVDB parses a byte of it; files that another program saved since (their UUID
// is not a content hash) are refused too. Behind that check, for files a buggy writer could
// make, it rejects with an error naming the problem: another grid type, a missing attribute
// or metadata entry, an attribute of the wrong type, inconsistent point offsets, duplicate or
// out-of-range ids, non-finite or out-of-range fields, and a pbgi_checksum that does not
// match. What OpenVDB allocates while reading such a file is up to OpenVDB. The hash keeps out
// damage, not malice: a file crafted with a matching hash reaches OpenVDB's parser, which a
// fuzzer makes allocate any size, abort on its own assertions or write past its buffers
// (tests/fuzz/surfel_vdb_fuzz_input.h, rehashed mode). Read only files that pbgi wrote.

#include <cstdint>
#include <iosfwd>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/pbgi/surfel.h"

namespace pbgi {

// Where the cloud came from; stored as grid metadata.
struct SurfelVdbMetadata {
  std::string shot;
  int32_t frame = 0;
  uint64_t seed = 0;
  std::string pbgiVersion;  // the version of pbgi that baked the cloud
};

// How "N" is stored: precision against size (bytes per point before compression).
enum class SurfelVdbNormals {
  kUnitVector16,  // "uvec", 2 bytes: the direction to within 0.035 rad (2 degrees)
  kHalf,          // "trnc", 6 bytes: within 1e-3 rad (half floats)
  kFloat,         // "null", 12 bytes: exact
};

struct SurfelVdbOptions {
  // World-space voxel edge. 0 picks one from the point density so that an active voxel holds
  // about `pointsPerVoxel` points (OpenVDB's computeVoxelSize); positions are quantized
  // relative to the voxel, so a smaller voxel stores them more precisely.
  float voxelSize = 0.0f;
  uint32_t pointsPerVoxel = 8;
  // The file is for looking at the bake (Houdini, `pbgi inspect`) as much as for reading it
  // back; the default keeps it small.
  SurfelVdbNormals normals = SurfelVdbNormals::kUnitVector16;
  SurfelVdbMetadata metadata;
};

// Writes `surfels` to `path` as OpenVDB points, Blosc-compressed (ZIP where the OpenVDB
// build lacks Blosc). An empty span writes a valid file with no points. Rejects surfels with
// non-finite or out-of-range fields (a zero normal, a negative radius, an albedo beyond half
// range, an unknown material class), naming the first offender by index.
absl::Status writeSurfelVdb(const std::string& path, std::span<const Surfel> surfels,
                            const SurfelVdbOptions& options = {});

// Reads a file written by writeSurfelVdb: the surfels in the order they were written.
absl::StatusOr<std::vector<Surfel>> readSurfelVdb(const std::string& path);
// The same from a seekable stream that holds the whole file from its first byte (the fuzz
// target reads bytes in memory); `name` stands for the path in messages. Reads `in` to its end.
absl::StatusOr<std::vector<Surfel>> readSurfelVdb(std::istream& in, const std::string& name);

struct SurfelVdbAttributeInfo {
  std::string name;
  std::string valueType;     // OpenVDB's type name: "vec3s", "float", "int32", ...
  std::string codec;         // OpenVDB's codec name: "null", "fxpt16", "uvec", "trnc", ...
  uint64_t memoryBytes = 0;  // in memory once loaded, summed over the leaves
};

// What `pbgi inspect` shows about a surfel file.
struct SurfelVdbInfo {
  std::string path;
  uint64_t fileBytes = 0;
  std::string vdbVersion;   // "<library major>.<minor>/<file format>" of the writer
  std::string compression;  // as OpenVDB recorded it: "blosc", "zip", "none", ...
  uint64_t pointCount = 0;
  uint64_t leafCount = 0;
  uint64_t activeVoxelCount = 0;
  Vec3f voxelSize{0.0f};
  Bounds3f bounds;  // of the decoded positions; empty when there are none or problem is set
  std::vector<SurfelVdbAttributeInfo> attributes;  // as the first leaf declares them
  SurfelVdbMetadata metadata;
  std::vector<std::pair<std::string, std::string>> gridMetadata;  // every entry, as text
  uint64_t memoryBytes = 0;                                       // the grid in memory
  // Why readSurfelVdb rejects this file; empty when it reads it.
  std::string problem;

  double fileBytesPerPoint() const;
  double memoryBytesPerPoint() const;
  std::string toString() const;  // several lines, for `pbgi inspect`
};

// Summarises a surfel file. Fails when the file is damaged (see above) or holds no OpenVDB
// points grid named "surfels"; a grid that readSurfelVdb rejects for its contents (a missing
// attribute, a bad id, ...) is described, with `problem` saying why.
absl::StatusOr<SurfelVdbInfo> inspectSurfelVdb(const std::string& path);
absl::StatusOr<SurfelVdbInfo> inspectSurfelVdb(std::istream& in, const std::string& name);

}  // namespace pbgi
