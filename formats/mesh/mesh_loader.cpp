#include "formats/mesh/mesh_loader.h"

#include <algorithm>
#include <cctype>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <assimp/GltfMaterial.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <fmt/format.h>
#include <assimp/Importer.hpp>

#include "formats/image/texture.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

enum class SourceFormat { kObj, kGltf };

std::string lowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

Rgb toRgb(const aiColor3D& c) { return {c.r, c.g, c.b}; }
bool isZero(const aiColor3D& c) { return c.r == 0.0f && c.g == 0.0f && c.b == 0.0f; }

std::string formatRgb(const aiColor3D& c) { return fmt::format("{} {} {}", c.r, c.g, c.b); }

// glTF URIs may percent-encode characters such as spaces.
std::string percentDecode(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(std::string(s.substr(i + 1, 2)), nullptr, 16));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

bool iequals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) ==
                  std::tolower(static_cast<unsigned char>(y));
         });
}

// Files (textures, material libraries) as the geometry file spells them, made into an
// existing path: relative to the geometry file's folder, with Windows separators, and with
// `foldCase`, forgiving the letter case of the file name, which exporters on
// case-insensitive file systems get wrong all the time.
std::optional<fs::path> resolveReferencedFile(const fs::path& folder, std::string raw,
                                              bool foldCase) {
  std::replace(raw.begin(), raw.end(), '\\', '/');
  const auto notSpace = [](unsigned char c) { return !std::isspace(c); };
  raw.erase(raw.begin(), std::find_if(raw.begin(), raw.end(), notSpace));
  raw.erase(std::find_if(raw.rbegin(), raw.rend(), notSpace).base(), raw.end());
  if (raw.empty()) return std::nullopt;
  std::vector<std::string> spellings{raw};
  if (raw.find('%') != std::string::npos) spellings.push_back(percentDecode(raw));
  std::error_code ec;
  for (const std::string& spelling : spellings) {
    fs::path p(spelling);
    if (p.is_relative()) p = folder / p;
    p = p.lexically_normal();
    if (fs::is_regular_file(p, ec)) return p;
    if (!foldCase) continue;
    const fs::path dir = p.parent_path().empty() ? fs::path(".") : p.parent_path();
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      if (it->is_regular_file(ec) &&
          iequals(it->path().filename().string(), p.filename().string())) {
        return it->path();
      }
    }
  }
  return std::nullopt;
}

std::string_view trimmed(std::string_view s) {
  const auto isSpace = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
  while (!s.empty() && isSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && isSpace(s.back())) s.remove_suffix(1);
  return s;
}

// The value of an OBJ/MTL statement `keyword value...`, or nullopt for another statement.
std::optional<std::string> statement(std::string_view line, std::string_view keyword) {
  const std::string_view t = trimmed(line);
  if (t.size() <= keyword.size() || t.substr(0, keyword.size()) != keyword ||
      !std::isspace(static_cast<unsigned char>(t[keyword.size()]))) {
    return std::nullopt;
  }
  return std::string(trimmed(t.substr(keyword.size())));
}

// What the OBJ's material libraries define. Assimp quietly makes a default grey material for
// a `usemtl` no library defines (a missing or misspelt mtllib is the usual cause), so the
// loader looks itself to be able to say so.
struct MaterialLibraries {
  std::set<std::string> defined;     // newmtl names
  std::vector<std::string> missing;  // mtllib entries that name no file
  std::vector<std::string> files;    // the libraries found, and the map_Kd textures they name
};

MaterialLibraries scanMaterialLibraries(const fs::path& obj) {
  MaterialLibraries libs;
  std::ifstream in(obj);
  std::string line;
  while (std::getline(in, line)) {
    const std::optional<std::string> value = statement(line, "mtllib");
    if (!value) continue;
    // One name with spaces, or several names separated by them.
    std::vector<std::string> names{*value};
    // Assimp opens them by their exact names, so no case folding here.
    if (!resolveReferencedFile(obj.parent_path(), *value, /*foldCase=*/false)) {
      names.clear();
      std::istringstream words(*value);
      for (std::string w; words >> w;) names.push_back(w);
    }
    for (const std::string& name : names) {
      const std::optional<fs::path> mtl =
          resolveReferencedFile(obj.parent_path(), name, /*foldCase=*/false);
      if (!mtl) {
        libs.missing.push_back(name);
        continue;
      }
      libs.files.push_back(mtl->string());
      std::ifstream mtlIn(*mtl);
      for (std::string mtlLine; std::getline(mtlIn, mtlLine);) {
        if (auto newmtl = statement(mtlLine, "newmtl")) libs.defined.insert(*newmtl);
        if (auto map = statement(mtlLine, "map_Kd")) {
          // The file name, after any options ("-s 1 1 1 wood.png"): the whole value when it
          // names a file, else its last word.
          std::optional<fs::path> texture =
              resolveReferencedFile(mtl->parent_path(), *map, /*foldCase=*/true);
          if (!texture) {
            const size_t space = map->find_last_of(" \t");
            if (space != std::string::npos) {
              texture = resolveReferencedFile(mtl->parent_path(), map->substr(space + 1),
                                              /*foldCase=*/true);
            }
          }
          if (texture) libs.files.push_back(texture->string());
        }
      }
    }
  }
  return libs;
}

// Textures the mapping has no place for, by the names a user knows from each format.
struct IgnoredTextureType {
  aiTextureType type;
  const char* obj;
  const char* gltf;
};
constexpr IgnoredTextureType kIgnoredTextures[] = {
    {aiTextureType_SPECULAR, "map_Ks", "specular texture"},
    {aiTextureType_AMBIENT, "map_Ka", "ambient texture"},
    {aiTextureType_EMISSIVE, "map_Ke", "emissiveTexture"},
    {aiTextureType_EMISSION_COLOR, "map_Ke", "emissiveTexture"},
    {aiTextureType_HEIGHT, "bump map", "height texture"},
    {aiTextureType_NORMALS, "normal map", "normalTexture"},
    {aiTextureType_NORMAL_CAMERA, "normal map", "normalTexture"},
    {aiTextureType_SHININESS, "map_Ns", "shininess texture"},
    {aiTextureType_OPACITY, "map_d", "opacity texture"},
    {aiTextureType_DISPLACEMENT, "disp", "displacement texture"},
    {aiTextureType_LIGHTMAP, "lightmap", "occlusionTexture"},
    {aiTextureType_AMBIENT_OCCLUSION, "ambient occlusion map", "occlusionTexture"},
    {aiTextureType_REFLECTION, "refl", "reflection texture"},
    {aiTextureType_METALNESS, "map_Pm", "metallicRoughnessTexture"},
    {aiTextureType_DIFFUSE_ROUGHNESS, "map_Pr", "metallicRoughnessTexture"},
    {aiTextureType_UNKNOWN, "unknown texture", "metallicRoughnessTexture"},
    {aiTextureType_SHEEN, "sheen texture", "sheen textures"},
    {aiTextureType_CLEARCOAT, "clearcoat texture", "clearcoat textures"},
    {aiTextureType_TRANSMISSION, "transmission texture", "transmission/volume textures"},
};

class MaterialMapper {
 public:
  MaterialMapper(const aiScene& scene, const std::string& file, SourceFormat format)
      : scene_(scene), file_(file), folder_(fs::path(file).parent_path()), format_(format) {
    if (format_ == SourceFormat::kObj) libraries_ = scanMaterialLibraries(file);
  }

  const std::vector<std::string>& missingLibraries() const { return libraries_.missing; }

  MaterialDesc map(const aiMaterial& mat, unsigned index, std::vector<std::string>* warnings) {
    MaterialDesc desc;
    aiString name;
    desc.name = mat.Get(AI_MATKEY_NAME, name) == AI_SUCCESS && name.length > 0
                    ? std::string(name.C_Str())
                    : fmt::format("material{}", index);
    desc.where.file = file_;
    ignored_.clear();
    notes_.clear();
    if (format_ == SourceFormat::kObj) {
      mapObj(mat, &desc);
    } else {
      mapGltf(mat, &desc);
    }
    listIgnoredTextures(mat);
    if (!ignored_.empty()) {
      const char* as = desc.type == MaterialType::kEmissive    ? "emissive"
                       : desc.type == MaterialType::kConductor ? "a conductor"
                                                               : "diffuse";
      warnings->push_back(fmt::format("{}: material '{}': ignored {}; it renders as {}", file_,
                                      desc.name, fmt::join(ignored_, ", "), as));
    }
    for (const std::string& note : notes_) {
      warnings->push_back(fmt::format("{}: material '{}': {}", file_, desc.name, note));
    }
    return desc;
  }

 private:
  void mapObj(const aiMaterial& mat, MaterialDesc* desc) {
    aiColor3D kd(0.6f, 0.6f, 0.6f);
    mat.Get(AI_MATKEY_COLOR_DIFFUSE, kd);
    // Assimp's own "DefaultMaterial" stands in for faces without any usemtl.
    if (desc->name != AI_DEFAULT_MATERIAL_NAME && !libraries_.defined.contains(desc->name)) {
      notes_.push_back(
          fmt::format("not defined in any MTL file{}; using Assimp's default, diffuse albedo {}",
                      libraries_.missing.empty()
                          ? std::string()
                          : fmt::format(" (missing: {})", fmt::join(libraries_.missing, ", ")),
                      formatRgb(kd)));
    }
    aiColor3D ke(0.0f, 0.0f, 0.0f);
    mat.Get(AI_MATKEY_COLOR_EMISSIVE, ke);
    if (!isZero(ke)) {
      desc->type = MaterialType::kEmissive;
      desc->radiance = toRgb(ke);
      if (mat.GetTextureCount(aiTextureType_DIFFUSE) > 0) {
        ignored_.push_back("map_Kd (emissive materials reflect nothing)");
      }
    } else {
      desc->type = MaterialType::kDiffuse;
      desc->albedo = toRgb(kd);
      mapAlbedoTexture(mat, aiTextureType_DIFFUSE, "map_Kd", desc);
    }

    aiColor3D ks(0.0f, 0.0f, 0.0f), ka(0.0f, 0.0f, 0.0f);
    if (mat.Get(AI_MATKEY_COLOR_SPECULAR, ks) == AI_SUCCESS && !isZero(ks)) {
      float ns = 0.0f;
      mat.Get(AI_MATKEY_SHININESS, ns);
      ignored_.push_back(fmt::format("Ks {} (Ns {}, glossy reflection)", formatRgb(ks), ns));
    }
    if (mat.Get(AI_MATKEY_COLOR_AMBIENT, ka) == AI_SUCCESS && !isZero(ka)) {
      ignored_.push_back(fmt::format("Ka {} (ambient)", formatRgb(ka)));
    }
    float opacity = 1.0f;
    if (mat.Get(AI_MATKEY_OPACITY, opacity) == AI_SUCCESS && opacity < 1.0f) {
      ignored_.push_back(fmt::format("d {} (transparency)", opacity));
    }
    int illum = 0;
    // illum 3 and up ask for ray-traced reflection, refraction or glass.
    if (mat.Get("$mat.illum", 0, 0, illum) == AI_SUCCESS && illum >= 3) {
      ignored_.push_back(fmt::format("illum {} (ray-traced reflection/refraction)", illum));
    }
    float pbr = 0.0f;
    if (mat.Get(AI_MATKEY_ROUGHNESS_FACTOR, pbr) == AI_SUCCESS)
      ignored_.push_back("Pr (roughness)");
    if (mat.Get(AI_MATKEY_METALLIC_FACTOR, pbr) == AI_SUCCESS) ignored_.push_back("Pm (metallic)");
  }

  void mapGltf(const aiMaterial& mat, MaterialDesc* desc) {
    aiColor4D base(1.0f, 1.0f, 1.0f, 1.0f);
    if (mat.Get(AI_MATKEY_BASE_COLOR, base) != AI_SUCCESS) mat.Get(AI_MATKEY_COLOR_DIFFUSE, base);
    const aiColor3D baseRgb(base.r, base.g, base.b);
    // Assimp's glTF 2.0 importer always sets the factor (the spec's default is 1); without
    // it the file is glTF 1.0, which has no metals.
    float metallic = 0.0f, roughness = 1.0f;
    mat.Get(AI_MATKEY_METALLIC_FACTOR, metallic);
    mat.Get(AI_MATKEY_ROUGHNESS_FACTOR, roughness);
    aiColor3D emissive(0.0f, 0.0f, 0.0f);
    mat.Get(AI_MATKEY_COLOR_EMISSIVE, emissive);
    float strength = 1.0f;
    mat.Get(AI_MATKEY_EMISSIVE_INTENSITY, strength);

    const bool hasBaseTexture = mat.GetTextureCount(aiTextureType_BASE_COLOR) > 0 ||
                                mat.GetTextureCount(aiTextureType_DIFFUSE) > 0;
    const aiTextureType baseTextureType = mat.GetTextureCount(aiTextureType_BASE_COLOR) > 0
                                              ? aiTextureType_BASE_COLOR
                                              : aiTextureType_DIFFUSE;
    if (!isZero(emissive) && strength > 0.0f) {
      desc->type = MaterialType::kEmissive;
      desc->radiance = toRgb(emissive) * strength;
      if (hasBaseTexture)
        ignored_.push_back("baseColorTexture (emissive materials reflect nothing)");
    } else if (metallic >= 0.5f) {
      desc->type = MaterialType::kConductor;
      desc->specular = toRgb(baseRgb);
      desc->roughness = roughness * roughness;  // glTF's perceptual roughness to alpha
      desc->distribution = MicrofacetDistribution::kGgx;
      if (hasBaseTexture) ignored_.push_back("baseColorTexture (conductors use baseColorFactor)");
    } else {
      desc->type = MaterialType::kDiffuse;
      desc->albedo = toRgb(baseRgb);
      if (hasBaseTexture && mapAlbedoTexture(mat, baseTextureType, "baseColorTexture", desc) &&
          (base.r != 1.0f || base.g != 1.0f || base.b != 1.0f)) {
        ignored_.push_back(
            fmt::format("baseColorFactor {} on top of baseColorTexture (the "
                        "texture alone is the albedo)",
                        formatRgb(baseRgb)));
      }
    }
    if (desc->type != MaterialType::kEmissive && metallic > 0.0f && metallic < 1.0f) {
      ignored_.push_back(fmt::format("metallicFactor {} (neither 0 nor 1; taken as {})", metallic,
                                     metallic >= 0.5f ? "1" : "0"));
    }
    aiString alphaMode;
    if (mat.Get(AI_MATKEY_GLTF_ALPHAMODE, alphaMode) == AI_SUCCESS &&
        std::string_view(alphaMode.C_Str()) != "OPAQUE") {
      ignored_.push_back(fmt::format("alphaMode {} (surfaces are opaque)", alphaMode.C_Str()));
    }
    float factor = 0.0f;
    if (mat.Get(AI_MATKEY_TRANSMISSION_FACTOR, factor) == AI_SUCCESS && factor > 0.0f) {
      ignored_.push_back(fmt::format("KHR_materials_transmission (factor {})", factor));
    }
    if (mat.Get(AI_MATKEY_VOLUME_THICKNESS_FACTOR, factor) == AI_SUCCESS && factor > 0.0f) {
      ignored_.push_back("KHR_materials_volume");
    }
    if (mat.Get(AI_MATKEY_CLEARCOAT_FACTOR, factor) == AI_SUCCESS && factor > 0.0f) {
      ignored_.push_back(fmt::format("KHR_materials_clearcoat (factor {})", factor));
    }
    aiColor3D sheen(0.0f, 0.0f, 0.0f);
    if (mat.Get(AI_MATKEY_SHEEN_COLOR_FACTOR, sheen) == AI_SUCCESS && !isZero(sheen)) {
      ignored_.push_back("KHR_materials_sheen");
    }
    if (mat.Get(AI_MATKEY_GLOSSINESS_FACTOR, factor) == AI_SUCCESS) {
      ignored_.push_back("KHR_materials_pbrSpecularGlossiness (read as metallic-roughness)");
    }
    int shading = 0;
    if (mat.Get(AI_MATKEY_SHADING_MODEL, shading) == AI_SUCCESS && shading == aiShadingMode_Unlit) {
      ignored_.push_back("KHR_materials_unlit");
    }
  }

  // Sets desc->albedoTexture from the material's first texture of `type` when it names a
  // file that exists and reads as an image; anything else is a note and the colour stays.
  bool mapAlbedoTexture(const aiMaterial& mat, aiTextureType type, const char* what,
                        MaterialDesc* desc) {
    if (mat.GetTextureCount(type) == 0) return false;
    aiString raw;
    unsigned uvIndex = 0;
    if (mat.GetTexture(type, 0, &raw, nullptr, &uvIndex) != AI_SUCCESS) return false;
    const std::string spelled = raw.C_Str();
    const std::string fallback =
        fmt::format("using the colour {} instead",
                    formatRgb(aiColor3D(desc->albedo->x, desc->albedo->y, desc->albedo->z)));
    if (uvIndex != 0) {
      ignored_.push_back(
          fmt::format("{} on texture coordinate set {} (only set 0 is read)", what, uvIndex));
      return false;
    }
    if ((!spelled.empty() && spelled[0] == '*') || scene_.GetEmbeddedTexture(raw.C_Str())) {
      notes_.push_back(fmt::format("{} is embedded in the file, which is not supported yet; {}",
                                   what, fallback));
      return false;
    }
    const std::optional<fs::path> resolved =
        resolveReferencedFile(folder_, spelled, /*foldCase=*/true);
    if (!resolved) {
      notes_.push_back(fmt::format("{} '{}' not found (looked in '{}'); {}", what, spelled,
                                   folder_.string(), fallback));
      return false;
    }
    const auto texture = loadImageTexture(resolved->string());
    if (!texture.ok()) {
      notes_.push_back(fmt::format("{} '{}' unusable: {}; {}", what, spelled,
                                   std::string(texture.status().message()), fallback));
      return false;
    }
    desc->albedoTexture = resolved->string();
    return true;
  }

  void listIgnoredTextures(const aiMaterial& mat) {
    std::set<std::string> seen;
    for (const IgnoredTextureType& t : kIgnoredTextures) {
      if (mat.GetTextureCount(t.type) == 0) continue;
      const std::string name = format_ == SourceFormat::kObj ? t.obj : t.gltf;
      if (seen.insert(name).second) ignored_.push_back(name);
    }
  }

  const aiScene& scene_;
  std::string file_;
  fs::path folder_;
  SourceFormat format_;
  MaterialLibraries libraries_;
  std::vector<std::string> ignored_;  // of the material being mapped
  std::vector<std::string> notes_;
};

std::string meshName(const aiMesh& mesh, unsigned index) {
  return mesh.mName.length > 0 ? std::string(mesh.mName.C_Str()) : fmt::format("mesh{}", index);
}

absl::StatusOr<LoadedGeometry> load(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    return absl::NotFoundError(fmt::format("geometry file '{}' not found", path));
  }
  if (!fs::is_regular_file(path, ec)) {
    return absl::InvalidArgumentError(
        fmt::format("geometry file '{}' is not a regular file", path));
  }
  const std::string ext = lowerExtension(path);
  SourceFormat format;
  if (ext == ".obj") {
    format = SourceFormat::kObj;
  } else if (ext == ".gltf" || ext == ".glb") {
    format = SourceFormat::kGltf;
  } else {
    return absl::InvalidArgumentError(fmt::format(
        "geometry file '{}': expected a .obj, .gltf or .glb file, found '{}'", path, ext));
  }

  Assimp::Importer importer;
  // No normal generation: files without normals shade with face normals (spec). No UV flip:
  // Assimp already hands out v = 0 at the bottom for both formats, as Texture expects.
  // Points and lines are sorted into their own meshes and dropped below with a warning.
  // Not aiProcess_JoinIdenticalVertices: it merges vertices within an absolute 1e-5, which
  // collapses a model built in micrometres; joinIdenticalVertices (exact) does it below.
  const unsigned flags = aiProcess_Triangulate | aiProcess_PreTransformVertices |
                         aiProcess_SortByPType | aiProcess_ValidateDataStructure;
  const aiScene* scene = importer.ReadFile(path, flags);
  if (scene == nullptr) {
    return absl::InvalidArgumentError(fmt::format("geometry file '{}': Assimp cannot read it: {}",
                                                  path, importer.GetErrorString()));
  }

  LoadedGeometry out;
  MaterialMapper mapper(*scene, path, format);
  std::vector<int> remap(scene->mNumMaterials, -1);
  size_t droppedPoints = 0, droppedLines = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh& src = *scene->mMeshes[m];
    MeshData mesh;
    mesh.name = meshName(src, m);
    for (unsigned f = 0; f < src.mNumFaces; ++f) {
      const aiFace& face = src.mFaces[f];
      if (face.mNumIndices == 3) {
        mesh.indices.insert(mesh.indices.end(), face.mIndices, face.mIndices + 3);
      } else if (face.mNumIndices == 1) {
        ++droppedPoints;
      } else if (face.mNumIndices == 2) {
        ++droppedLines;
      }
    }
    if (mesh.indices.empty()) continue;
    mesh.positions.reserve(src.mNumVertices);
    for (unsigned v = 0; v < src.mNumVertices; ++v) {
      mesh.positions.emplace_back(src.mVertices[v].x, src.mVertices[v].y, src.mVertices[v].z);
    }
    if (src.HasNormals()) {
      mesh.normals.reserve(src.mNumVertices);
      for (unsigned v = 0; v < src.mNumVertices; ++v) {
        mesh.normals.emplace_back(src.mNormals[v].x, src.mNormals[v].y, src.mNormals[v].z);
      }
    }
    if (src.HasTextureCoords(0)) {
      mesh.uvs.reserve(src.mNumVertices);
      for (unsigned v = 0; v < src.mNumVertices; ++v) {
        mesh.uvs.emplace_back(src.mTextureCoords[0][v].x, src.mTextureCoords[0][v].y);
      }
    }
    // Only materials that some triangle uses are mapped, so that a library's unused entries
    // (and Assimp's own default material) neither show up nor warn.
    int& material = remap.at(src.mMaterialIndex);
    if (material < 0) {
      material = static_cast<int>(out.materials.size());
      out.materialWarnings.emplace_back();
      out.materials.push_back(mapper.map(*scene->mMaterials[src.mMaterialIndex],
                                         src.mMaterialIndex, &out.materialWarnings.back()));
    }
    mesh.materials.assign(mesh.triangleCount(), static_cast<uint32_t>(material));

    joinIdenticalVertices(mesh);
    const MeshCleanReport report = cleanMesh(mesh);
    if (report.total() > 0) {
      out.warnings.push_back(fmt::format("{}: mesh '{}': {}", path, mesh.name, report.toString()));
    }
    if (mesh.triangleCount() > 0) out.meshes.push_back(std::move(mesh));
  }
  for (const std::string& lib : mapper.missingLibraries()) {
    out.libraryWarnings.push_back(fmt::format("{}: material library '{}' not found", path, lib));
  }
  if (droppedPoints + droppedLines > 0) {
    out.warnings.push_back(
        fmt::format("{}: dropped {} point{} and {} line segment{}: only "
                    "triangles render",
                    path, droppedPoints, droppedPoints == 1 ? "" : "s", droppedLines,
                    droppedLines == 1 ? "" : "s"));
  }
  if (out.meshes.empty()) {
    return absl::InvalidArgumentError(
        fmt::format("geometry file '{}': no usable triangles{}", path,
                    out.warnings.empty() ? std::string()
                                         : fmt::format(" ({})", fmt::join(out.warnings, "; "))));
  }
  return out;
}

}  // namespace

std::vector<std::string> referencedFiles(const std::string& path) {
  if (lowerExtension(path) != ".obj") return {};
  return scanMaterialLibraries(path).files;
}

absl::StatusOr<LoadedGeometry> loadGeometry(const std::string& path) {
  // Assimp reports failures through ReadFile's result, but its parsers and post-processing
  // can still throw (std::bad_alloc on hostile sizes, among others).
  try {
    return load(path);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(
        fmt::format("geometry file '{}': Assimp failed: {}", path, e.what()));
  }
}

}  // namespace pbgi
