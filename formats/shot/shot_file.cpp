#include "formats/shot/shot_file.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <toml++/toml.h>

#include "core/math/vec.h"
#include "core/util/source_location.h"

// Every read below can fail with a user-facing error, so the plumbing is spelled once here
// rather than as an if-return after each of the ~100 reads.
#define PBGI_SHOT_CONCAT_INNER(a, b) a##b
#define PBGI_SHOT_CONCAT(a, b) PBGI_SHOT_CONCAT_INNER(a, b)
#define PBGI_RETURN_IF_ERROR(expr)                                               \
  do {                                                                           \
    if (absl::Status pbgi_status_ = (expr); !pbgi_status_.ok()) return pbgi_status_; \
  } while (false)
#define PBGI_ASSIGN_OR_RETURN(lhs, expr) \
  PBGI_ASSIGN_OR_RETURN_IMPL(PBGI_SHOT_CONCAT(pbgi_statusor_, __LINE__), lhs, expr)
#define PBGI_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                               \
  if (!tmp.ok()) return std::move(tmp).status();   \
  lhs = *std::move(tmp)

namespace pbgi {
namespace {

namespace fs = std::filesystem;

constexpr int64_t kSupportedVersion = 1;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kMaxResolution = 16384;
// 8192 x 8192: a frame buffer of a few GB at most, so a typo cannot exhaust a worker.
constexpr int64_t kMaxPixels = int64_t{1} << 26;
// Hand-written and generated shots are kilobytes; anything this big is not a shot file.
constexpr std::uintmax_t kMaxShotFileBytes = std::uintmax_t{16} << 20;
// Degeneracy checks run on every frame of ranges up to this long, on the keys beyond it.
constexpr int64_t kMaxFramesToCheck = 10000;

// An allowed interval for a number, with the words error messages use for it.
struct Range {
  double lo = -kInf, hi = kInf;
  bool loOpen = false, hiOpen = false;

  bool contains(double v) const {
    return (loOpen ? v > lo : v >= lo) && (hiOpen ? v < hi : v <= hi);
  }
  std::string toString() const {
    if (hi == kInf) return fmt::format("{} {}", loOpen ? ">" : ">=", lo);
    if (lo == -kInf) return fmt::format("{} {}", hiOpen ? "<" : "<=", hi);
    return fmt::format("in {}{}, {}{}", loOpen ? '(' : '[', lo, hi, hiOpen ? ')' : ']');
  }
};

constexpr Range kAnyNumber{};
constexpr Range kPositive{0.0, kInf, true, false};
constexpr Range kNonNegative{0.0, kInf, false, false};
constexpr Range kUnitInterval{0.0, 1.0, false, false};
constexpr Range kFovRange{0.0, 180.0, true, true};
constexpr Range kConeRange{0.0, 90.0, true, false};
constexpr Range kIorRange{1.0, kInf, true, false};
constexpr Range kFrameRange{0.0, INT_MAX, false, false};
constexpr Range kResolutionRange{1.0, kMaxResolution, false, false};
constexpr Range kViewsRange{1.0, 1024.0, false, false};
constexpr Range kSppRange{1.0, 1 << 20, false, false};
constexpr Range kDepthRange{1.0, 65536.0, false, false};
constexpr Range kFilterWidthRange{0.0, 32.0, true, false};
constexpr Range kTileSizeRange{4.0, 1024.0, false, false};

// A float as the user would write it: 4.0 stays "4.0", so that "expected an integer, found
// float 4.0" does not read as a contradiction.
std::string formatFloat(double v) {
  std::string s = fmt::format("{}", v);
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

// What a node holds, for "found ..." in messages.
std::string describe(const toml::node& n) {
  switch (n.type()) {
    case toml::node_type::string: {
      std::string s = n.as_string()->get();
      if (s.size() > 60) s = s.substr(0, 57) + "...";
      return fmt::format("string \"{}\"", s);
    }
    case toml::node_type::integer:
      return fmt::format("integer {}", n.as_integer()->get());
    case toml::node_type::floating_point:
      return "float " + formatFloat(n.as_floating_point()->get());
    case toml::node_type::boolean:
      return fmt::format("boolean {}", n.as_boolean()->get());
    case toml::node_type::array:
      return fmt::format("an array of {} element(s)", n.as_array()->size());
    case toml::node_type::table:
      return "a table";
    default:
      return "a date/time";
  }
}

// Where keys and values sit in the file, and where relative paths point.
class Context {
 public:
  explicit Context(std::string file) : file_(std::move(file)) {
    // Absolute, so that resolved paths stay right if the process changes folder and
    // "not found" messages say exactly where pbgi looked.
    std::error_code ec;
    const fs::path dir = fs::path(file_).parent_path();
    const fs::path abs = dir.empty() ? fs::current_path(ec) : fs::absolute(dir, ec);
    dir_ = (ec ? dir : abs).lexically_normal();
  }

  const std::string& file() const { return file_; }
  const fs::path& dir() const { return dir_; }

  SourceLocation at(const toml::source_region& r) const {
    return {file_, static_cast<int>(r.begin.line), static_cast<int>(r.begin.column)};
  }
  absl::Status invalid(const toml::source_region& r, std::string_view msg) const {
    return absl::InvalidArgumentError(fmt::format("{}: {}", at(r).toString(), msg));
  }
  absl::Status notFound(const toml::source_region& r, std::string_view msg) const {
    return absl::NotFoundError(fmt::format("{}: {}", at(r).toString(), msg));
  }
  std::string resolve(const std::string& p) const {
    fs::path q(p);
    if (q.is_relative()) q = dir_ / q;
    return q.lexically_normal().string();
  }

 private:
  std::string file_;
  fs::path dir_;
};

// A TOML table being read: reads typed values and blames errors on the right line.
class Section {
 public:
  Section(const Context& ctx, const toml::table& table, std::string name)
      : ctx_(&ctx), table_(&table), name_(std::move(name)) {}

  const std::string& name() const { return name_; }
  const toml::table& table() const { return *table_; }
  const Context& ctx() const { return *ctx_; }
  SourceLocation where() const { return ctx_->at(table_->source()); }
  const toml::node* find(std::string_view key) const { return table_->get(key); }

  absl::Status error(const toml::node& at, std::string_view msg) const {
    return ctx_->invalid(at.source(), fmt::format("{}: {}", name_, msg));
  }
  absl::Status errorHere(std::string_view msg) const {
    return ctx_->invalid(table_->source(), fmt::format("{}: {}", name_, msg));
  }
  absl::Status missing(std::string_view key) const {
    return errorHere(fmt::format("missing required key '{}'", key));
  }

  // A misspelt key is an error, never silently ignored. The earliest one in the file is
  // reported so that fixing errors top to bottom works; `hint` may add why a key is wrong.
  absl::Status allowOnly(const std::vector<std::string_view>& allowed,
                         const std::function<std::string(std::string_view)>& hint = {}) const {
    const toml::key* first = nullptr;
    const toml::node* firstNode = nullptr;
    for (auto&& [key, node] : *table_) {
      if (std::find(allowed.begin(), allowed.end(), key.str()) != allowed.end()) continue;
      if (first == nullptr || keyRegion(key, node).begin < keyRegion(*first, *firstNode).begin) {
        first = &key;
        firstNode = &node;
      }
    }
    if (first == nullptr) return absl::OkStatus();
    std::string why = hint ? hint(first->str()) : std::string();
    return ctx_->invalid(keyRegion(*first, *firstNode),
                         fmt::format("{}: unknown key '{}'{} (expected one of: {})", name_,
                                     first->str(), why, fmt::join(allowed, ", ")));
  }

  template <typename T>
  absl::StatusOr<std::optional<T>> get(std::string_view key, const Range& range = kAnyNumber) const {
    const toml::node* n = find(key);
    if (n == nullptr) return std::optional<T>();
    PBGI_ASSIGN_OR_RETURN(T value, convert<T>(*n, fmt::format("'{}'", key), range));
    return std::optional<T>(std::move(value));
  }
  template <typename T>
  absl::StatusOr<T> need(std::string_view key, const Range& range = kAnyNumber) const {
    const toml::node* n = find(key);
    if (n == nullptr) return missing(key);
    return convert<T>(*n, fmt::format("'{}'", key), range);
  }
  template <typename T>
  absl::StatusOr<T> getOr(std::string_view key, T fallback, const Range& range = kAnyNumber) const {
    PBGI_ASSIGN_OR_RETURN(std::optional<T> value, get<T>(key, range));
    return value ? *std::move(value) : std::move(fallback);
  }

  // One of a fixed set of names, e.g. a material type.
  template <typename E>
  absl::StatusOr<std::optional<E>> choice(std::string_view key, std::string_view what,
                                          const std::vector<std::pair<std::string_view, E>>& options) const {
    PBGI_ASSIGN_OR_RETURN(std::optional<std::string> name, get<std::string>(key));
    if (!name) return std::optional<E>();
    for (const auto& [option, value] : options) {
      if (*name == option) return std::optional<E>(value);
    }
    std::vector<std::string_view> names;
    for (const auto& option : options) names.push_back(option.first);
    return error(*find(key), fmt::format("'{}': unknown {} \"{}\" (expected one of: {})", key, what,
                                         *name, fmt::join(names, ", ")));
  }

  // A path to a file that must exist, resolved against the shot file's folder.
  absl::StatusOr<std::optional<std::string>> existingFile(std::string_view key) const {
    PBGI_ASSIGN_OR_RETURN(std::optional<std::string> given, get<std::string>(key));
    if (!given) return std::optional<std::string>();
    const toml::node& n = *find(key);
    if (given->empty()) return error(n, fmt::format("'{}': expected a file path, found \"\"", key));
    std::string resolved = ctx_->resolve(*given);
    std::error_code ec;
    const fs::file_status st = fs::status(resolved, ec);
    if (!fs::exists(st)) {
      return ctx_->notFound(n.source(), fmt::format("{}: '{}': file \"{}\" not found (resolved to {})",
                                                    name_, key, *given, resolved));
    }
    if (!fs::is_regular_file(st)) {
      return error(n, fmt::format("'{}': \"{}\" is not a regular file (resolved to {})", key,
                                  *given, resolved));
    }
    return std::optional<std::string>(std::move(resolved));
  }

  template <typename T>
  absl::StatusOr<T> convert(const toml::node& n, const std::string& label, const Range& range) const {
    if constexpr (std::is_same_v<T, std::string>) {
      if (!n.is_string()) return typeError(n, label, "a string");
      return n.as_string()->get();
    } else if constexpr (std::is_same_v<T, float>) {
      return toFloat(n, label, range);
    } else if constexpr (std::is_same_v<T, int>) {
      PBGI_ASSIGN_OR_RETURN(int64_t v, toInteger(n, label, range));
      if (v < INT_MIN || v > INT_MAX) {
        return error(n, fmt::format("{} must fit a 32-bit integer, found {}", label, v));
      }
      return static_cast<int>(v);
    } else if constexpr (std::is_same_v<T, int64_t>) {
      return toInteger(n, label, range);
    } else if constexpr (std::is_same_v<T, Vec3f>) {
      PBGI_ASSIGN_OR_RETURN(const toml::array* a, fixedArray(n, label, 3, "3 numbers"));
      Vec3f v;
      for (int i = 0; i < 3; ++i) {
        PBGI_ASSIGN_OR_RETURN(v[i], toFloat(*a->get(i), fmt::format("{}[{}]", label, i), range));
      }
      return v;
    } else {
      static_assert(std::is_same_v<T, Vec2i>);
      PBGI_ASSIGN_OR_RETURN(const toml::array* a, fixedArray(n, label, 2, "2 integers"));
      Vec2i v;
      for (int i = 0; i < 2; ++i) {
        PBGI_ASSIGN_OR_RETURN(v[i], convert<int>(*a->get(i), fmt::format("{}[{}]", label, i), range));
      }
      return v;
    }
  }

 private:
  // toml++ knows where a key sits for keys written out; keys it made up itself (dotted
  // headers) fall back to their value.
  static toml::source_region keyRegion(const toml::key& key, const toml::node& node) {
    return key.source().begin.line > 0 ? key.source() : node.source();
  }

  absl::Status typeError(const toml::node& n, const std::string& label, std::string_view expected) const {
    return error(n, fmt::format("{}: expected {}, found {}", label, expected, describe(n)));
  }

  absl::StatusOr<const toml::array*> fixedArray(const toml::node& n, const std::string& label,
                                                size_t size, std::string_view of) const {
    const toml::array* a = n.as_array();
    if (a == nullptr || a->size() != size) {
      return typeError(n, label, fmt::format("an array of {}", of));
    }
    return a;
  }

  absl::StatusOr<float> toFloat(const toml::node& n, const std::string& label, const Range& range) const {
    // Integers are accepted where floats are expected: `fov_y_deg = 37` means 37.0.
    double v = 0.0;
    std::string asWritten;
    if (const auto* i = n.as_integer()) {
      v = static_cast<double>(i->get());
      asWritten = fmt::format("{}", i->get());
    } else if (const auto* f = n.as_floating_point()) {
      v = f->get();
      asWritten = formatFloat(v);
    } else {
      return typeError(n, label, "a number");
    }
    if (!std::isfinite(v)) return typeError(n, label, "a finite number");
    if (std::abs(v) > std::numeric_limits<float>::max()) {
      return error(n, fmt::format("{}: {} is out of the 32-bit float range", label, asWritten));
    }
    if (!range.contains(v)) {
      return error(n, fmt::format("{} must be {}, found {}", label, range.toString(), asWritten));
    }
    return static_cast<float>(v);
  }

  absl::StatusOr<int64_t> toInteger(const toml::node& n, const std::string& label, const Range& range) const {
    const auto* i = n.as_integer();
    if (i == nullptr) return typeError(n, label, "an integer");
    const int64_t v = i->get();
    if (!range.contains(static_cast<double>(v))) {
      return error(n, fmt::format("{} must be {}, found {}", label, range.toString(), v));
    }
    return v;
  }

  const Context* ctx_;
  const toml::table* table_;
  std::string name_;
};

// A sub-table such as [shot]; nullopt when absent.
absl::StatusOr<std::optional<Section>> subTable(const Section& parent, std::string_view key,
                                                std::string name) {
  const toml::node* n = parent.find(key);
  if (n == nullptr) return std::optional<Section>();
  if (!n->is_table()) {
    return parent.error(*n, fmt::format("'{}': expected a table {}, found {}", key, name, describe(*n)));
  }
  return std::optional<Section>(Section(parent.ctx(), *n->as_table(), std::move(name)));
}

// An array of tables such as [[geometry]]; each element is named "[[geometry]] #i".
absl::StatusOr<std::vector<Section>> tableArray(const Section& parent, std::string_view key,
                                                std::string_view name) {
  std::vector<Section> out;
  const toml::node* n = parent.find(key);
  if (n == nullptr) return out;
  const toml::array* a = n->as_array();
  if (a == nullptr) {
    return parent.error(*n, fmt::format("'{}': expected an array of tables {}, found {}", key, name,
                                        describe(*n)));
  }
  for (size_t i = 0; i < a->size(); ++i) {
    const toml::node& element = *a->get(i);
    if (!element.is_table()) {
      return parent.error(element, fmt::format("'{}'[{}]: expected a table {}, found {}", key, i,
                                               name, describe(element)));
    }
    out.emplace_back(parent.ctx(), *element.as_table(), fmt::format("{} #{}", name, i + 1));
  }
  return out;
}

// Names the variant a key was found in and, when the key belongs to other variants (a
// light's or a material's type), which: the usual mistake is a key copied from another type.
std::function<std::string(std::string_view)> otherVariantHint(
    const std::vector<std::pair<std::string_view, std::vector<std::string_view>>>& variants,
    std::string_view self, std::string_view kind) {
  return [&variants, self = std::string(self), kind = std::string(kind)](std::string_view key) {
    std::vector<std::string_view> owners;
    for (const auto& [type, keys] : variants) {
      if (std::find(keys.begin(), keys.end(), key) != keys.end()) owners.push_back(type);
    }
    if (owners.empty()) return fmt::format(" for a {} {}", self, kind);
    return fmt::format(" for a {} {}: it belongs to {} {}s", self, kind, fmt::join(owners, " and "),
                       kind);
  };
}

// Rejects two keys at the same frame, which would silently drop one of them.
absl::Status checkUniqueFrame(std::map<int, int>& seen, int frame, const Section& key) {
  auto [it, inserted] = seen.emplace(frame, key.where().line);
  if (!inserted) {
    return key.error(*key.find("frame"), fmt::format("frame {} already has a key at line {}", frame,
                                                     it->second));
  }
  return absl::OkStatus();
}

// --- [shot] ------------------------------------------------------------------------------

absl::Status parseShotTable(const Section& s, ShotDesc& shot) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"name", "frames", "resolution", "output"}));

  PBGI_ASSIGN_OR_RETURN(shot.name, s.need<std::string>("name"));
  const bool nameOk = !shot.name.empty() && std::all_of(shot.name.begin(), shot.name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
  if (!nameOk) {
    return s.error(*s.find("name"), fmt::format("'name' must match [A-Za-z0-9_-]+, found \"{}\"",
                                                shot.name));
  }

  PBGI_ASSIGN_OR_RETURN(const Vec2i frames, s.need<Vec2i>("frames", kFrameRange));
  if (frames.x > frames.y) {
    return s.error(*s.find("frames"),
                   fmt::format("'frames' must be [first, last] with first <= last, found [{}, {}]",
                               frames.x, frames.y));
  }
  shot.firstFrame = frames.x;
  shot.lastFrame = frames.y;

  PBGI_ASSIGN_OR_RETURN(const Vec2i res, s.need<Vec2i>("resolution", kResolutionRange));
  const int64_t pixels = int64_t{res.x} * res.y;
  if (pixels > kMaxPixels) {
    return s.error(*s.find("resolution"),
                   fmt::format("'resolution' {} x {} is {} pixels; at most {} (2^26) are allowed",
                               res.x, res.y, pixels, kMaxPixels));
  }
  shot.width = res.x;
  shot.height = res.y;

  PBGI_ASSIGN_OR_RETURN(const std::string output, s.need<std::string>("output"));
  if (output.empty() || output.back() == '/') {
    return s.error(*s.find("output"),
                   fmt::format("'output': expected a file pattern such as \"{}.####.exr\", found \"{}\"",
                               shot.name, output));
  }
  shot.output = s.ctx().resolve(output);
  return absl::OkStatus();
}

// --- [camera] ----------------------------------------------------------------------------

// Why a camera cannot form an image, and which key to blame; nullopt when it can.
struct CameraProblem {
  std::string what;
  std::string_view key;
};

std::optional<CameraProblem> cameraProblem(const CameraParams& c) {
  const Vec3f dir = c.lookAt - c.position;
  const float scale = std::max({1.0f, maxAbsComponent(vmax(c.position, -c.position)),
                                maxAbsComponent(vmax(c.lookAt, -c.lookAt))});
  if (length(dir) <= 1e-6f * scale) {
    return CameraProblem{fmt::format("position and look_at coincide at {}", c.position), "look_at"};
  }
  if (length(c.up) == 0.0f) return CameraProblem{"up is the zero vector", "up"};
  if (length(cross(normalize(dir), normalize(c.up))) < 1e-5f) {
    return CameraProblem{fmt::format("up {} is parallel to the view direction {}", c.up, normalize(dir)),
                         "up"};
  }
  if (c.apertureRadius > 0.0f && !(c.focusDistance > 0.0f)) {
    return CameraProblem{fmt::format("aperture_radius {} > 0 needs focus_distance > 0, found {}",
                                     c.apertureRadius, c.focusDistance),
                         "aperture_radius"};
  }
  return std::nullopt;
}

const std::vector<std::string_view> kCameraKeyValues = {"position",        "look_at",
                                                        "up",              "fov_y_deg",
                                                        "aperture_radius", "focus_distance"};

absl::StatusOr<CameraKey> parseCameraKey(const Section& s) {
  std::vector<std::string_view> allowed = {"frame"};
  allowed.insert(allowed.end(), kCameraKeyValues.begin(), kCameraKeyValues.end());
  PBGI_RETURN_IF_ERROR(s.allowOnly(allowed));
  CameraKey key;
  key.where = s.where();
  PBGI_ASSIGN_OR_RETURN(key.frame, s.need<int>("frame", kFrameRange));
  PBGI_ASSIGN_OR_RETURN(key.position, s.get<Vec3f>("position"));
  PBGI_ASSIGN_OR_RETURN(key.lookAt, s.get<Vec3f>("look_at"));
  PBGI_ASSIGN_OR_RETURN(key.up, s.get<Vec3f>("up"));
  PBGI_ASSIGN_OR_RETURN(key.fovYDeg, s.get<float>("fov_y_deg", kFovRange));
  PBGI_ASSIGN_OR_RETURN(key.apertureRadius, s.get<float>("aperture_radius", kNonNegative));
  PBGI_ASSIGN_OR_RETURN(key.focusDistance, s.get<float>("focus_distance", kPositive));
  if (s.table().size() == 1) {
    return s.errorHere(fmt::format("key at frame {} sets nothing (expected at least one of: {})",
                                   key.frame, fmt::join(kCameraKeyValues, ", ")));
  }
  return key;
}

// The camera must be usable on every frame it renders, including interpolated ones: a key
// can make up parallel to the view direction half-way between two good keys.
absl::Status checkCameraOverTime(const Section& s, const CameraDesc& camera, int firstFrame,
                                 int lastFrame, const std::vector<Section>& keySections) {
  std::vector<int> frames;
  for (const CameraKey& key : camera.keys) frames.push_back(key.frame);
  if (int64_t{lastFrame} - firstFrame < kMaxFramesToCheck) {
    for (int64_t f = firstFrame; f <= lastFrame; ++f) frames.push_back(static_cast<int>(f));
  }
  std::sort(frames.begin(), frames.end());
  frames.erase(std::unique(frames.begin(), frames.end()), frames.end());
  for (int frame : frames) {
    const auto problem = cameraProblem(cameraAt(camera, firstFrame, frame));
    if (!problem) continue;
    // Blame the key that sets this frame, else the next key, whose values pull it there.
    const Section* blame = nullptr;
    int blameFrame = INT_MAX;
    for (size_t i = 0; i < camera.keys.size(); ++i) {
      const int kf = camera.keys[i].frame;
      if (kf >= frame && kf < blameFrame) {
        blame = &keySections[i];
        blameFrame = kf;
      }
    }
    const Section& at = blame != nullptr ? *blame : s;
    return at.errorHere(fmt::format("the camera at frame {} is degenerate: {}", frame, problem->what));
  }
  return absl::OkStatus();
}

absl::Status parseCamera(const Section& s, ShotDesc& shot) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"position", "look_at", "up", "fov_y_deg", "aperture_radius",
                                    "focus_distance", "views", "view_spacing", "key"}));
  CameraDesc& camera = shot.camera;
  CameraParams& base = camera.base;
  camera.where = s.where();
  PBGI_ASSIGN_OR_RETURN(base.position, s.need<Vec3f>("position"));
  PBGI_ASSIGN_OR_RETURN(base.lookAt, s.need<Vec3f>("look_at"));
  PBGI_ASSIGN_OR_RETURN(base.up, s.need<Vec3f>("up"));
  PBGI_ASSIGN_OR_RETURN(base.fovYDeg, s.need<float>("fov_y_deg", kFovRange));
  PBGI_ASSIGN_OR_RETURN(base.apertureRadius, s.getOr<float>("aperture_radius", 0.0f, kNonNegative));
  PBGI_ASSIGN_OR_RETURN(const std::optional<float> focus, s.get<float>("focus_distance", kPositive));
  base.focusDistance = focus.value_or(0.0f);
  PBGI_ASSIGN_OR_RETURN(camera.views, s.getOr<Vec2i>("views", Vec2i(1, 1), kViewsRange));
  PBGI_ASSIGN_OR_RETURN(camera.viewSpacing, s.getOr<float>("view_spacing", 0.0f, kNonNegative));

  if (auto problem = cameraProblem(base)) {
    const toml::node* blame = s.find(problem->key);
    return s.error(*blame, problem->key == "aperture_radius" && !focus
                               ? std::string("'aperture_radius' > 0 turns on depth of field and "
                                             "needs 'focus_distance' (> 0), which is missing")
                               : problem->what);
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> keys, tableArray(s, "key", "[[camera.key]]"));
  std::map<int, int> seen;
  for (const Section& k : keys) {
    PBGI_ASSIGN_OR_RETURN(CameraKey key, parseCameraKey(k));
    PBGI_RETURN_IF_ERROR(checkUniqueFrame(seen, key.frame, k));
    camera.keys.push_back(std::move(key));
  }
  return checkCameraOverTime(s, camera, shot.firstFrame, shot.lastFrame, keys);
}

// --- [[geometry]] ------------------------------------------------------------------------

absl::StatusOr<TransformKey> parseTransformKey(const Section& s) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"frame", "translate", "rotate_deg", "scale"}));
  TransformKey key;
  key.where = s.where();
  PBGI_ASSIGN_OR_RETURN(key.frame, s.need<int>("frame", kFrameRange));
  PBGI_ASSIGN_OR_RETURN(key.translate, s.get<Vec3f>("translate"));
  PBGI_ASSIGN_OR_RETURN(key.rotateDeg, s.get<Vec3f>("rotate_deg"));
  PBGI_ASSIGN_OR_RETURN(key.scale, s.get<float>("scale", kPositive));
  if (s.table().size() == 1) {
    return s.errorHere(fmt::format(
        "key at frame {} sets nothing (expected at least one of: translate, rotate_deg, scale)",
        key.frame));
  }
  return key;
}

absl::StatusOr<GeometryDesc> parseGeometry(const Section& s) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"file", "translate", "rotate_deg", "scale", "key"}));
  GeometryDesc geometry;
  geometry.where = s.where();
  if (s.find("file") == nullptr) return s.missing("file");
  // The format is checked before the file so that a typo in the extension says so.
  const toml::node& fileNode = *s.find("file");
  if (const auto* given = fileNode.as_string()) {
    std::string ext = fs::path(given->get()).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext != ".obj" && ext != ".gltf" && ext != ".glb") {
      return s.error(fileNode, fmt::format("'file': expected a Wavefront OBJ (.obj) or glTF 2.0 "
                                           "(.gltf, .glb) file, found \"{}\"",
                                           given->get()));
    }
  }
  PBGI_ASSIGN_OR_RETURN(const std::optional<std::string> file, s.existingFile("file"));
  geometry.file = *file;
  PBGI_ASSIGN_OR_RETURN(geometry.base.translate, s.getOr<Vec3f>("translate", Vec3f(0.0f)));
  PBGI_ASSIGN_OR_RETURN(geometry.base.rotateDeg, s.getOr<Vec3f>("rotate_deg", Vec3f(0.0f)));
  PBGI_ASSIGN_OR_RETURN(geometry.base.scale, s.getOr<float>("scale", 1.0f, kPositive));

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> keys, tableArray(s, "key", "[[geometry.key]]"));
  std::map<int, int> seen;
  for (const Section& k : keys) {
    PBGI_ASSIGN_OR_RETURN(TransformKey key, parseTransformKey(k));
    PBGI_RETURN_IF_ERROR(checkUniqueFrame(seen, key.frame, k));
    geometry.keys.push_back(std::move(key));
  }
  return geometry;
}

// --- [[material]] ------------------------------------------------------------------------

// The keys each type allows, in the order of the type's enum.
using Variants = std::vector<std::pair<std::string_view, std::vector<std::string_view>>>;

const Variants& materialKeys() {
  static const Variants kKeys = {
      {"diffuse", {"name", "type", "albedo", "albedo_texture"}},
      {"conductor", {"name", "type", "roughness", "distribution", "specular", "eta", "k", "tint"}},
      {"dielectric", {"name", "type", "roughness", "distribution", "ior"}},
      {"emissive", {"name", "type", "radiance"}},
  };
  return kKeys;
}

absl::StatusOr<MaterialDesc> parseMaterial(const Section& s) {
  MaterialDesc m;
  m.where = s.where();
  PBGI_ASSIGN_OR_RETURN(const std::optional<MaterialType> type,
                        s.choice<MaterialType>("type", "material type",
                                               {{"diffuse", MaterialType::kDiffuse},
                                                {"conductor", MaterialType::kConductor},
                                                {"dielectric", MaterialType::kDielectric},
                                                {"emissive", MaterialType::kEmissive}}));
  if (!type) return s.missing("type");
  m.type = *type;
  const auto& [typeName, allowed] = materialKeys()[static_cast<size_t>(m.type)];
  PBGI_RETURN_IF_ERROR(s.allowOnly(allowed, otherVariantHint(materialKeys(), typeName, "material")));

  PBGI_ASSIGN_OR_RETURN(m.name, s.need<std::string>("name"));
  if (m.name.empty()) return s.error(*s.find("name"), "'name': expected a material name, found \"\"");

  const std::vector<std::pair<std::string_view, MicrofacetDistribution>> distributions = {
      {"ggx", MicrofacetDistribution::kGgx}, {"beckmann", MicrofacetDistribution::kBeckmann}};
  switch (m.type) {
    case MaterialType::kDiffuse: {
      PBGI_ASSIGN_OR_RETURN(m.albedo, s.get<Vec3f>("albedo", kUnitInterval));
      PBGI_ASSIGN_OR_RETURN(m.albedoTexture, s.existingFile("albedo_texture"));
      if (m.albedo && m.albedoTexture) {
        return s.error(*s.find("albedo_texture"),
                       "a diffuse material takes 'albedo' or 'albedo_texture', not both");
      }
      if (!m.albedo && !m.albedoTexture) {
        return s.errorHere("a diffuse material needs 'albedo' = [r, g, b] or 'albedo_texture' = \"path\"");
      }
      break;
    }
    case MaterialType::kConductor: {
      PBGI_ASSIGN_OR_RETURN(m.roughness, s.getOr<float>("roughness", 0.0f, kNonNegative));
      PBGI_ASSIGN_OR_RETURN(auto d, s.choice<MicrofacetDistribution>("distribution", "distribution",
                                                                      distributions));
      m.distribution = d.value_or(MicrofacetDistribution::kGgx);
      PBGI_ASSIGN_OR_RETURN(m.specular, s.get<Vec3f>("specular", kUnitInterval));
      PBGI_ASSIGN_OR_RETURN(m.eta, s.get<Vec3f>("eta", kPositive));
      PBGI_ASSIGN_OR_RETURN(m.k, s.get<Vec3f>("k", kNonNegative));
      PBGI_ASSIGN_OR_RETURN(m.tint, s.getOr<Vec3f>("tint", Rgb(1.0f), kUnitInterval));
      if (m.specular && (m.eta || m.k)) {
        return s.error(*s.find(m.eta ? "eta" : "k"),
                       "a conductor's Fresnel is either 'specular' or 'eta' and 'k', not both");
      }
      if (m.eta.has_value() != m.k.has_value()) {
        return s.error(*s.find(m.eta ? "eta" : "k"),
                       fmt::format("'{}' needs '{}': a complex index of refraction is eta + i k",
                                   m.eta ? "eta" : "k", m.eta ? "k" : "eta"));
      }
      if (!m.specular && !m.eta) {
        return s.errorHere("a conductor needs 'specular' = [r, g, b] or both 'eta' and 'k'");
      }
      break;
    }
    case MaterialType::kDielectric: {
      PBGI_ASSIGN_OR_RETURN(m.roughness, s.getOr<float>("roughness", 0.0f, kNonNegative));
      PBGI_ASSIGN_OR_RETURN(auto d, s.choice<MicrofacetDistribution>("distribution", "distribution",
                                                                      distributions));
      m.distribution = d.value_or(MicrofacetDistribution::kGgx);
      PBGI_ASSIGN_OR_RETURN(m.ior, s.getOr<float>("ior", 1.5f, kIorRange));
      break;
    }
    case MaterialType::kEmissive: {
      PBGI_ASSIGN_OR_RETURN(m.radiance, s.need<Vec3f>("radiance", kNonNegative));
      break;
    }
  }
  return m;
}

// --- [[light]] ---------------------------------------------------------------------------

// In the order of LightType.
const Variants& lightKeys() {
  static const Variants kKeys = {
      {"quad", {"type", "corner", "edge_u", "edge_v", "radiance"}},
      {"sphere", {"type", "center", "radius", "radiance"}},
      {"point", {"type", "position", "intensity"}},
      {"spot", {"type", "position", "direction", "cone_deg", "intensity"}},
      {"directional", {"type", "direction", "irradiance"}},
      {"environment", {"type", "file", "scale", "rotate_deg"}},
  };
  return kKeys;
}

absl::StatusOr<Vec3f> needDirection(const Section& s, std::string_view key) {
  PBGI_ASSIGN_OR_RETURN(const Vec3f d, s.need<Vec3f>(key));
  if (length(d) == 0.0f) {
    return s.error(*s.find(key), fmt::format("'{}' must be a non-zero vector, found {}", key, d));
  }
  return normalize(d);
}

absl::StatusOr<LightDesc> parseLight(const Section& s) {
  LightDesc l;
  l.where = s.where();
  PBGI_ASSIGN_OR_RETURN(const std::optional<LightType> type,
                        s.choice<LightType>("type", "light type",
                                            {{"quad", LightType::kQuad},
                                             {"sphere", LightType::kSphere},
                                             {"point", LightType::kPoint},
                                             {"spot", LightType::kSpot},
                                             {"directional", LightType::kDirectional},
                                             {"environment", LightType::kEnvironment}}));
  if (!type) return s.missing("type");
  l.type = *type;
  const auto& [typeName, allowed] = lightKeys()[static_cast<size_t>(l.type)];
  PBGI_RETURN_IF_ERROR(s.allowOnly(allowed, otherVariantHint(lightKeys(), typeName, "light")));

  switch (l.type) {
    case LightType::kQuad: {
      PBGI_ASSIGN_OR_RETURN(l.corner, s.need<Vec3f>("corner"));
      PBGI_ASSIGN_OR_RETURN(l.edgeU, s.need<Vec3f>("edge_u"));
      PBGI_ASSIGN_OR_RETURN(l.edgeV, s.need<Vec3f>("edge_v"));
      const float area = length(cross(l.edgeU, l.edgeV));
      if (!(area > 1e-6f * length(l.edgeU) * length(l.edgeV)) || area == 0.0f) {
        return s.error(*s.find("edge_v"),
                       fmt::format("edge_u {} and edge_v {} are parallel or zero: the quad has no area",
                                   l.edgeU, l.edgeV));
      }
      PBGI_ASSIGN_OR_RETURN(l.radiance, s.need<Vec3f>("radiance", kNonNegative));
      break;
    }
    case LightType::kSphere: {
      PBGI_ASSIGN_OR_RETURN(l.center, s.need<Vec3f>("center"));
      PBGI_ASSIGN_OR_RETURN(l.radius, s.need<float>("radius", kPositive));
      PBGI_ASSIGN_OR_RETURN(l.radiance, s.need<Vec3f>("radiance", kNonNegative));
      break;
    }
    case LightType::kPoint: {
      PBGI_ASSIGN_OR_RETURN(l.position, s.need<Vec3f>("position"));
      PBGI_ASSIGN_OR_RETURN(l.intensity, s.need<Vec3f>("intensity", kNonNegative));
      break;
    }
    case LightType::kSpot: {
      PBGI_ASSIGN_OR_RETURN(l.position, s.need<Vec3f>("position"));
      PBGI_ASSIGN_OR_RETURN(l.direction, needDirection(s, "direction"));
      PBGI_ASSIGN_OR_RETURN(l.coneDeg, s.need<float>("cone_deg", kConeRange));
      PBGI_ASSIGN_OR_RETURN(l.intensity, s.need<Vec3f>("intensity", kNonNegative));
      break;
    }
    case LightType::kDirectional: {
      PBGI_ASSIGN_OR_RETURN(l.direction, needDirection(s, "direction"));
      PBGI_ASSIGN_OR_RETURN(l.irradiance, s.need<Vec3f>("irradiance", kNonNegative));
      break;
    }
    case LightType::kEnvironment: {
      if (s.find("file") == nullptr) return s.missing("file");
      PBGI_ASSIGN_OR_RETURN(const std::optional<std::string> file, s.existingFile("file"));
      l.file = *file;
      PBGI_ASSIGN_OR_RETURN(l.scale, s.getOr<float>("scale", 1.0f, kNonNegative));
      PBGI_ASSIGN_OR_RETURN(l.rotateDeg, s.getOr<float>("rotate_deg", 0.0f));
      break;
    }
  }
  return l;
}

// --- [render] ----------------------------------------------------------------------------

absl::Status parseRender(const Section& s, RenderSettings& r) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"integrator", "spp", "seed", "max_depth", "filter",
                                    "filter_width", "tile_size", "roulette_depth"}));
  PBGI_ASSIGN_OR_RETURN(r.integrator, s.getOr<std::string>("integrator", r.integrator));
  if (r.integrator.empty()) {
    return s.error(*s.find("integrator"), "'integrator': expected a name such as \"path\", found \"\"");
  }
  PBGI_ASSIGN_OR_RETURN(r.spp, s.getOr<int>("spp", r.spp, kSppRange));
  PBGI_ASSIGN_OR_RETURN(const int64_t seed,
                        s.getOr<int64_t>("seed", static_cast<int64_t>(r.seed), kNonNegative));
  r.seed = static_cast<uint64_t>(seed);
  PBGI_ASSIGN_OR_RETURN(r.maxDepth, s.getOr<int>("max_depth", r.maxDepth, kDepthRange));
  PBGI_ASSIGN_OR_RETURN(const std::optional<FilterType> filter,
                        s.choice<FilterType>("filter", "pixel filter",
                                             {{"box", FilterType::kBox},
                                              {"gaussian", FilterType::kGaussian},
                                              {"blackman-harris", FilterType::kBlackmanHarris}}));
  r.filter = filter.value_or(r.filter);
  PBGI_ASSIGN_OR_RETURN(r.filterWidth, s.getOr<float>("filter_width", r.filterWidth, kFilterWidthRange));
  PBGI_ASSIGN_OR_RETURN(r.tileSize, s.getOr<int>("tile_size", r.tileSize, kTileSizeRange));
  PBGI_ASSIGN_OR_RETURN(r.rouletteDepth, s.getOr<int>("roulette_depth", r.rouletteDepth, kDepthRange));
  return absl::OkStatus();
}

// --- the whole file ----------------------------------------------------------------------

absl::StatusOr<ShotDesc> parseDocument(const Context& ctx, const toml::table& root) {
  ShotDesc shot;
  shot.path = ctx.file();
  shot.dir = ctx.dir().string();
  const Section top(ctx, root, "top level");

  // The version decides what every other key means, so it is checked before any of them: a
  // newer file fails with "update pbgi", not with a list of keys this build does not know.
  if (top.find("version") == nullptr) {
    return top.errorHere(fmt::format("missing required key 'version' (this build reads version {})",
                                     kSupportedVersion));
  }
  PBGI_ASSIGN_OR_RETURN(const int64_t version, top.need<int64_t>("version"));
  if (version > kSupportedVersion) {
    return top.error(*top.find("version"),
                     fmt::format("'version' {} is newer than this build of pbgi reads ({}); update pbgi",
                                 version, kSupportedVersion));
  }
  if (version != kSupportedVersion) {
    return top.error(*top.find("version"),
                     fmt::format("'version' must be {}, found {}", kSupportedVersion, version));
  }
  shot.version = static_cast<int>(version);
  PBGI_RETURN_IF_ERROR(
      top.allowOnly({"version", "shot", "camera", "geometry", "material", "light", "render"}));

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> shotTable, subTable(top, "shot", "[shot]"));
  if (!shotTable) return top.errorHere("missing required table [shot]");
  PBGI_RETURN_IF_ERROR(parseShotTable(*shotTable, shot));

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> camera, subTable(top, "camera", "[camera]"));
  if (!camera) return top.errorHere("missing required table [camera]");
  PBGI_RETURN_IF_ERROR(parseCamera(*camera, shot));

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> geometry, tableArray(top, "geometry", "[[geometry]]"));
  if (geometry.empty()) {
    return top.errorHere("missing required [[geometry]]: a shot needs at least one geometry file");
  }
  for (const Section& g : geometry) {
    PBGI_ASSIGN_OR_RETURN(GeometryDesc desc, parseGeometry(g));
    shot.geometry.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> materials, tableArray(top, "material", "[[material]]"));
  std::map<std::string, int> materialLines;
  for (const Section& m : materials) {
    PBGI_ASSIGN_OR_RETURN(MaterialDesc desc, parseMaterial(m));
    auto [it, inserted] = materialLines.emplace(desc.name, desc.where.line);
    if (!inserted) {
      return m.error(*m.find("name"), fmt::format("material \"{}\" is already defined at line {}",
                                                  desc.name, it->second));
    }
    shot.materials.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> lights, tableArray(top, "light", "[[light]]"));
  int environmentLine = 0;
  for (const Section& l : lights) {
    PBGI_ASSIGN_OR_RETURN(LightDesc desc, parseLight(l));
    // Two environment maps would both claim every escaping ray; nothing sums them.
    if (desc.type == LightType::kEnvironment) {
      if (environmentLine > 0) {
        return l.errorHere(fmt::format("a shot has at most one environment light; another is at line {}",
                                       environmentLine));
      }
      environmentLine = desc.where.line;
    }
    shot.lights.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> render, subTable(top, "render", "[render]"));
  if (render) PBGI_RETURN_IF_ERROR(parseRender(*render, shot.render));
  return shot;
}

absl::Status syntaxError(const std::string& path, const toml::parse_error& e) {
  const SourceLocation loc{path, static_cast<int>(e.source().begin.line),
                           static_cast<int>(e.source().begin.column)};
  return absl::InvalidArgumentError(
      fmt::format("{}: TOML syntax error: {}", loc.toString(), e.description()));
}

}  // namespace

absl::StatusOr<ShotDesc> parseShot(std::string_view text, const std::string& path) {
  toml::table root;
#if TOML_EXCEPTIONS
  try {
    root = toml::parse(text, std::string_view(path));
  } catch (const toml::parse_error& e) {
    return syntaxError(path, e);
  }
#else
  toml::parse_result result = toml::parse(text, std::string_view(path));
  if (!result) return syntaxError(path, result.error());
  root = std::move(result).table();
#endif
  const Context ctx(path);
  return parseDocument(ctx, root);
}

absl::StatusOr<ShotDesc> loadShotFile(const std::string& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) return absl::NotFoundError(fmt::format("{}: shot file not found", path));
  if (!fs::is_regular_file(st)) {
    return absl::InvalidArgumentError(fmt::format("{}: not a regular file", path));
  }
  const std::uintmax_t size = fs::file_size(path, ec);
  if (!ec && size > kMaxShotFileBytes) {
    return absl::InvalidArgumentError(fmt::format(
        "{}: shot file is {} bytes; a shot file is at most {} bytes", path, size, kMaxShotFileBytes));
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::PermissionDeniedError(
        fmt::format("{}: cannot open shot file: {}", path, std::strerror(errno)));
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) {
    return absl::DataLossError(fmt::format("{}: cannot read shot file: {}", path, std::strerror(errno)));
  }
  return parseShot(text.str(), path);
}

}  // namespace pbgi
