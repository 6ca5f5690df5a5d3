#pragma once
// Strict, located reads from a toml++ document: every read checks the type and range and
// every failure is an absl::Status whose message starts with "file:line:column: section: ".
// Private to formats/shot; the shot parser is its only user.

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <toml++/toml.h>

#include <climits>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "core/math/vec.h"
#include "core/util/source_location.h"
#include "core/util/status.h"

namespace pbgi::strict_toml {

inline constexpr double kInf = std::numeric_limits<double>::infinity();

// An allowed interval for a number, with the words error messages use for it.
struct Range {
  double lo = -kInf, hi = kInf;
  bool loOpen = false, hiOpen = false;

  bool contains(double v) const {
    return (loOpen ? v > lo : v >= lo) && (hiOpen ? v < hi : v <= hi);
  }
  std::string toString() const;
};

inline constexpr Range kAnyNumber{};
inline constexpr Range kPositive{0.0, kInf, true, false};
inline constexpr Range kNonNegative{0.0, kInf, false, false};
inline constexpr Range kUnitInterval{0.0, 1.0, false, false};

// A float as the user would write it: 4.0 stays "4.0", so that "expected an integer, found
// float 4.0" does not read as a contradiction.
std::string formatFloat(double v);
// What a node holds, for "found ..." in messages: `string "wide"`, `an array of 2 element(s)`.
std::string describe(const toml::node& n);

// The file being read: where its keys and values sit, and where its relative paths point.
class Source {
 public:
  explicit Source(std::string file);

  const std::string& file() const { return file_; }
  // The file's folder, absolute, so that resolved paths survive a change of working folder
  // and "not found" messages say exactly where pbgi looked.
  const std::filesystem::path& dir() const { return dir_; }

  SourceLocation at(const toml::source_region& r) const {
    return {file_, static_cast<int>(r.begin.line), static_cast<int>(r.begin.column)};
  }
  absl::Status invalid(const toml::source_region& r, std::string_view msg) const;
  absl::Status notFound(const toml::source_region& r, std::string_view msg) const;
  // `p` made absolute against dir() (when relative) and lexically normalised.
  std::string resolve(const std::string& p) const;

 private:
  std::string file_;
  std::filesystem::path dir_;
};

// One TOML table being read, named for messages ("[camera]", "[[light]] #2").
class Section {
 public:
  // For a key found where it does not belong: text to add after "unknown key 'k'".
  using Hint = std::function<std::string(std::string_view key)>;

  Section(const Source& source, const toml::table& table, std::string name)
      : source_(&source), table_(&table), name_(std::move(name)) {}

  const std::string& name() const { return name_; }
  const toml::table& table() const { return *table_; }
  const Source& source() const { return *source_; }
  SourceLocation where() const { return source_->at(table_->source()); }
  const toml::node* find(std::string_view key) const { return table_->get(key); }

  absl::Status error(const toml::node& at, std::string_view msg) const {
    return source_->invalid(at.source(), fmt::format("{}: {}", name_, msg));
  }
  absl::Status errorHere(std::string_view msg) const {
    return source_->invalid(table_->source(), fmt::format("{}: {}", name_, msg));
  }
  absl::Status missing(std::string_view key) const {
    return errorHere(fmt::format("missing required key '{}'", key));
  }

  // A misspelt key is an error, never silently ignored. The earliest one in the file is
  // reported, so that fixing errors from the top down works.
  absl::Status allowOnly(const std::vector<std::string_view>& allowed, const Hint& hint = {}) const;

  // Typed reads: T is std::string, float, int, int64_t, Vec3f or Vec2i; numbers (and each
  // component of a vector) must lie in `range`.
  template <typename T>
  absl::StatusOr<std::optional<T>> get(std::string_view key,
                                       const Range& range = kAnyNumber) const {
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

  // One of a fixed set of names, such as a material type; `what` names the set in messages.
  template <typename E>
  absl::StatusOr<std::optional<E>> choice(
      std::string_view key, std::string_view what,
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

  // A path to a file that must exist (NotFound otherwise), resolved against the file's folder.
  absl::StatusOr<std::optional<std::string>> existingFile(std::string_view key) const;

  template <typename T>
  absl::StatusOr<T> convert(const toml::node& n, const std::string& label,
                            const Range& range) const {
    if constexpr (std::is_same_v<T, std::string>) {
      if (!n.is_string()) return typeError(n, label, "a string");
      return n.as_string()->get();
    } else if constexpr (std::is_same_v<T, float>) {
      return toFloat(n, label, range);
    } else if constexpr (std::is_same_v<T, int>) {
      PBGI_ASSIGN_OR_RETURN(const int64_t v, toInteger(n, label, range));
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
        PBGI_ASSIGN_OR_RETURN(v[i],
                                   toFloat(*a->get(i), fmt::format("{}[{}]", label, i), range));
      }
      return v;
    } else {
      static_assert(std::is_same_v<T, Vec2i>, "no strict TOML read for this type");
      PBGI_ASSIGN_OR_RETURN(const toml::array* a, fixedArray(n, label, 2, "2 integers"));
      Vec2i v;
      for (int i = 0; i < 2; ++i) {
        PBGI_ASSIGN_OR_RETURN(
            v[i], convert<int>(*a->get(i), fmt::format("{}[{}]", label, i), range));
      }
      return v;
    }
  }

 private:
  absl::Status typeError(const toml::node& n, const std::string& label,
                         std::string_view expected) const;
  absl::StatusOr<const toml::array*> fixedArray(const toml::node& n, const std::string& label,
                                                size_t size, std::string_view of) const;
  absl::StatusOr<float> toFloat(const toml::node& n, const std::string& label,
                                const Range& range) const;
  absl::StatusOr<int64_t> toInteger(const toml::node& n, const std::string& label,
                                    const Range& range) const;

  const Source* source_;
  const toml::table* table_;
  std::string name_;
};

// A sub-table such as [shot]; nullopt when absent, an error when `key` holds something else.
absl::StatusOr<std::optional<Section>> subTable(const Section& parent, std::string_view key,
                                                std::string name);
// An array of tables such as [[geometry]]; element i is named "<name> #<i+1>".
absl::StatusOr<std::vector<Section>> tableArray(const Section& parent, std::string_view key,
                                                std::string_view name);

// The keys each variant of a table allows (a light's type, a material's type).
using Variants = std::vector<std::pair<std::string_view, std::vector<std::string_view>>>;
// A Hint naming the variant a stray key was found in and the variants it belongs to: the
// usual mistake is a key copied from another type. `variants` must outlive the hint.
Section::Hint otherVariantHint(const Variants& variants, std::string_view self,
                               std::string_view kind);

}  // namespace pbgi::strict_toml
