// Writes the hostile surfel files that tests/formats/vdb/surfel_vdb_test.cpp feeds to
// readSurfelVdb and inspectSurfelVdb. Not part of the build: the files are committed, and this
// program is how they were made. Each starts from valid_small.vdb (64 surfels written by
// writeSurfelVdb; the test regenerates it with PBGI_REGENERATE_VDB_TEST_DATA=1) and spoils one
// thing, so that each is rejected for exactly one reason.
//
// writeSurfelVdb names each file by the hash of its contents (the UUID in the header), and the
// reader checks it before OpenVDB parses anything. Damaged files fail that check:
//
//   garbage.vdb                   plain text
//   magic_then_garbage.vdb        OpenVDB's magic number, then random bytes
//   truncated.vdb                 valid_small.vdb cut in half
//   crashes_openvdb.vdb           valid_small.vdb with byte 9025 (in a node's tile values)
//                                 set to 200: read through io::Stream, OpenVDB 10.0 writes
//                                 past the end of a buffer (valgrind: invalid write in
//                                 bloscFromStream; heap corruption, then abort). A new
//                                 valid_small.vdb needs a new such byte: look with valgrind
//   foreign_writer.vdb            valid_small.vdb's grid saved again by plain OpenVDB (a
//                                 random UUID)
//
// The rest are rehashed after they are spoiled, as a buggy writer would make them, so that
// they reach the checks behind the hash:
//
//   truncated_rehashed.vdb        valid_small.vdb cut in half
//   float_grid_named_surfels.vdb  a FloatGrid called "surfels"
//   no_surfels_grid.vdb           the points grid renamed "points"
//   missing_radiance.vdb          the "radiance" attribute dropped
//   radiance_is_float.vdb         "radiance" replaced by a float attribute
//   duplicate_id.vdb              two points with id 0
//   id_out_of_range.vdb           an id of 64 among 64 points
//   bad_material_class.vdb        a material class of 7
//   nan_radiance.vdb              a NaN radiance
//   checksum_mismatch.vdb         one radiance changed, the checksum kept
//   newer_format_version.vdb      pbgi_format_version 3 (version 2 added radiance_back)
//   no_point_count.vdb            pbgi_point_count removed
//   wrong_point_count.vdb         pbgi_point_count 65
//   point_count_is_string.vdb     pbgi_point_count as a string
//
// Build and run from the repository root (the defines are those of Debian 12's OpenVDB
// package, which its CMake target would add):
//   g++ -std=c++20 -O1 -DOPENVDB_ABI_VERSION_NUMBER=10 -DOPENVDB_USE_DELAYED_LOADING \
//       tests/data/vdb/make_hostile_vdbs.cpp -o /tmp/make_hostile_vdbs \
//       -lopenvdb -ltbb -lImath -lxxhash && /tmp/make_hostile_vdbs tests/data/vdb

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <string>

#include <openvdb/openvdb.h>
#include <openvdb/points/PointAttribute.h>
#include <openvdb/points/PointDataGrid.h>
#include <xxhash.h>

namespace vdbp = openvdb::points;

namespace {

std::string dir;

vdbp::PointDataGrid::Ptr readValid() {
  openvdb::io::File file(dir + "/valid_small.vdb");
  file.open(false);
  auto grid = openvdb::gridPtrCast<vdbp::PointDataGrid>(file.readGrid("surfels"));
  file.close();
  return grid;
}

std::string readBytes(const std::string& name) {
  std::ifstream in(dir + "/" + name, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void writeBytes(const std::string& name, const std::string& bytes) {
  std::ofstream(dir + "/" + name, std::ios::binary)
      .write(bytes.data(), std::streamsize(bytes.size()));
}

// What writeSurfelVdb does to every file: the UUID at bytes [21, 57) becomes XXH3-128 of all
// the other bytes, as a version 8 UUID (formats/vdb/surfel_vdb.cpp, contentUuid).
std::string rehashed(std::string bytes) {
  XXH3_state_t* state = XXH3_createState();
  XXH3_128bits_reset(state);
  XXH3_128bits_update(state, bytes.data(), 21);
  XXH3_128bits_update(state, bytes.data() + 57, bytes.size() - 57);
  const XXH128_hash_t h = XXH3_128bits_digest(state);
  XXH3_freeState(state);
  const uint64_t hi = (h.high64 & ~uint64_t{0xf000}) | uint64_t{0x8000};
  const uint64_t lo = (h.low64 & ~(uint64_t{3} << 62)) | (uint64_t{2} << 62);
  char uuid[37];
  std::snprintf(uuid, sizeof(uuid), "%08llx-%04llx-%04llx-%04llx-%012llx",
                (unsigned long long)(hi >> 32), (unsigned long long)((hi >> 16) & 0xffff),
                (unsigned long long)(hi & 0xffff), (unsigned long long)(lo >> 48),
                (unsigned long long)(lo & 0xffffffffffffULL));
  bytes.replace(21, 36, uuid);
  return bytes;
}

void write(const std::string& name, const openvdb::GridBase::Ptr& grid, bool rehash = true) {
  {
    openvdb::io::File file(dir + "/" + name);
    file.setCompression(openvdb::io::COMPRESS_BLOSC);
    file.write(openvdb::GridCPtrVec{grid});
    file.close();
  }
  if (rehash) writeBytes(name, rehashed(readBytes(name)));
}

// Calls f(handle, index) on the first point of the first leaf (enough to spoil a file).
template <typename T, typename F>
void spoilFirst(vdbp::PointDataGrid& grid, const std::string& attribute, F f) {
  auto leaf = grid.tree().beginLeaf();
  vdbp::AttributeWriteHandle<T> handle(leaf->attributeArray(attribute));
  handle.expand();
  f(handle);
}

// The index, within its leaf, of the point whose id is `id` (and the leaf).
vdbp::PointDataTree::LeafNodeType* findId(vdbp::PointDataGrid& grid, int64_t id,
                                          openvdb::Index& index) {
  for (auto leaf = grid.tree().beginLeaf(); leaf; ++leaf) {
    vdbp::AttributeHandle<int64_t> ids(leaf->constAttributeArray("id"));
    for (openvdb::Index i = 0; i < ids.size(); ++i) {
      if (ids.get(i) == id) {
        index = i;
        return leaf.getLeaf();
      }
    }
  }
  std::abort();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: make_hostile_vdbs <tests/data/vdb>\n";
    return 2;
  }
  dir = argv[1];
  openvdb::initialize();

  std::ofstream(dir + "/garbage.vdb") << "This is not an OpenVDB file, whatever its name says.\n";
  {
    std::ofstream out(dir + "/magic_then_garbage.vdb", std::ios::binary);
    const int64_t magic = openvdb::OPENVDB_MAGIC;
    out.write(reinterpret_cast<const char*>(&magic), sizeof(magic));
    std::mt19937 rng(1);
    for (int i = 0; i < 120; ++i) out.put(char(rng()));
  }
  const std::string valid = readBytes("valid_small.vdb");
  writeBytes("truncated.vdb", valid.substr(0, valid.size() / 2));
  writeBytes("truncated_rehashed.vdb", rehashed(valid.substr(0, valid.size() / 2)));
  {
    std::string damaged = valid;
    damaged.at(9025) = char(200);
    writeBytes("crashes_openvdb.vdb", damaged);
  }
  write("foreign_writer.vdb", readValid(), /*rehash=*/false);
  {
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("surfels");
    grid->tree().setValue(openvdb::Coord(1, 2, 3), 4.0f);
    write("float_grid_named_surfels.vdb", grid);
  }
  {
    auto grid = readValid();
    grid->setName("points");
    write("no_surfels_grid.vdb", grid);
  }
  {
    auto grid = readValid();
    vdbp::dropAttribute(grid->tree(), "radiance");
    write("missing_radiance.vdb", grid);
  }
  {
    auto grid = readValid();
    vdbp::dropAttribute(grid->tree(), "radiance");
    vdbp::appendAttribute<float>(grid->tree(), "radiance");
    write("radiance_is_float.vdb", grid);
  }
  {
    auto grid = readValid();
    openvdb::Index i = 0;
    auto* leaf = findId(*grid, 1, i);
    vdbp::AttributeWriteHandle<int64_t> ids(leaf->attributeArray("id"));
    ids.set(i, 0);
    write("duplicate_id.vdb", grid);
  }
  {
    auto grid = readValid();
    openvdb::Index i = 0;
    auto* leaf = findId(*grid, 1, i);
    vdbp::AttributeWriteHandle<int64_t> ids(leaf->attributeArray("id"));
    ids.set(i, 64);
    write("id_out_of_range.vdb", grid);
  }
  {
    auto grid = readValid();
    spoilFirst<int32_t>(*grid, "materialClass", [](auto& h) { h.set(0, 7); });
    write("bad_material_class.vdb", grid);
  }
  {
    auto grid = readValid();
    spoilFirst<openvdb::Vec3f>(*grid, "radiance", [](auto& h) {
      h.set(0, openvdb::Vec3f(std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.0f));
    });
    write("nan_radiance.vdb", grid);
  }
  {
    auto grid = readValid();
    spoilFirst<openvdb::Vec3f>(
        *grid, "radiance", [](auto& h) { h.set(0, h.get(0) + openvdb::Vec3f(0.5f, 0.0f, 0.0f)); });
    write("checksum_mismatch.vdb", grid);
  }
  {
    auto grid = readValid();
    grid->insertMeta("pbgi_format_version", openvdb::Int32Metadata(3));
    write("newer_format_version.vdb", grid);
  }
  {
    auto grid = readValid();
    grid->removeMeta("pbgi_point_count");
    write("no_point_count.vdb", grid);
  }
  {
    auto grid = readValid();
    grid->insertMeta("pbgi_point_count", openvdb::Int64Metadata(65));
    write("wrong_point_count.vdb", grid);
  }
  {
    auto grid = readValid();
    grid->removeMeta("pbgi_point_count");
    grid->insertMeta("pbgi_point_count", openvdb::StringMetadata("64"));
    write("point_count_is_string.vdb", grid);
  }
  return 0;
}
