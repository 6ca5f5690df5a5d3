#include "formats/shot/strict_toml.h"

#include <algorithm>
#include <cmath>
#include <system_error>

namespace pbgi::strict_toml {

namespace fs = std::filesystem;

namespace {

// toml++ knows where a key sits for keys written out; keys it made up itself (the parents
// of dotted headers) fall back to their value.
toml::source_region keyRegion(const toml::key& key, const toml::node& node) {
  return key.source().begin.line > 0 ? key.source() : node.source();
}

}  // namespace

std::string Range::toString() const {
  if (hi == kInf) return fmt::format("{} {}", loOpen ? ">" : ">=", lo);
  if (lo == -kInf) return fmt::format("{} {}", hiOpen ? "<" : "<=", hi);
  return fmt::format("in {}{}, {}{}", loOpen ? '(' : '[', lo, hi, hiOpen ? ')' : ']');
}

std::string formatFloat(double v) {
  std::string s = fmt::format("{}", v);
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

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

Source::Source(std::string file) : file_(std::move(file)) {
  std::error_code ec;
  const fs::path dir = fs::path(file_).parent_path();
  const fs::path abs = dir.empty() ? fs::current_path(ec) : fs::absolute(dir, ec);
  dir_ = (ec ? dir : abs).lexically_normal();
}

absl::Status Source::invalid(const toml::source_region& r, std::string_view msg) const {
  return absl::InvalidArgumentError(fmt::format("{}: {}", at(r).toString(), msg));
}

absl::Status Source::notFound(const toml::source_region& r, std::string_view msg) const {
  return absl::NotFoundError(fmt::format("{}: {}", at(r).toString(), msg));
}

std::string Source::resolve(const std::string& p) const {
  fs::path q(p);
  if (q.is_relative()) q = dir_ / q;
  return q.lexically_normal().string();
}

absl::Status Section::allowOnly(const std::vector<std::string_view>& allowed,
                                const Hint& hint) const {
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
  const std::string why = hint ? hint(first->str()) : std::string();
  return source_->invalid(keyRegion(*first, *firstNode),
                          fmt::format("{}: unknown key '{}'{} (expected one of: {})", name_,
                                      first->str(), why, fmt::join(allowed, ", ")));
}

absl::StatusOr<std::optional<std::string>> Section::existingFile(std::string_view key) const {
  PBGI_ASSIGN_OR_RETURN(std::optional<std::string> given, get<std::string>(key));
  if (!given) return std::optional<std::string>();
  const toml::node& n = *find(key);
  if (given->empty()) return error(n, fmt::format("'{}': expected a file path, found \"\"", key));
  std::string resolved = source_->resolve(*given);
  std::error_code ec;
  const fs::file_status st = fs::status(resolved, ec);
  if (!fs::exists(st)) {
    return source_->notFound(
        n.source(), fmt::format("{}: '{}': file \"{}\" not found (resolved to {})", name_, key,
                                *given, resolved));
  }
  if (!fs::is_regular_file(st)) {
    return error(n, fmt::format("'{}': \"{}\" is not a regular file (resolved to {})", key, *given,
                                resolved));
  }
  return std::optional<std::string>(std::move(resolved));
}

absl::Status Section::typeError(const toml::node& n, const std::string& label,
                                std::string_view expected) const {
  return error(n, fmt::format("{}: expected {}, found {}", label, expected, describe(n)));
}

absl::StatusOr<const toml::array*> Section::fixedArray(const toml::node& n,
                                                       const std::string& label, size_t size,
                                                       std::string_view of) const {
  const toml::array* a = n.as_array();
  if (a == nullptr || a->size() != size) {
    return typeError(n, label, fmt::format("an array of {}", of));
  }
  return a;
}

absl::StatusOr<float> Section::toFloat(const toml::node& n, const std::string& label,
                                       const Range& range) const {
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

absl::StatusOr<int64_t> Section::toInteger(const toml::node& n, const std::string& label,
                                           const Range& range) const {
  const auto* i = n.as_integer();
  if (i == nullptr) return typeError(n, label, "an integer");
  const int64_t v = i->get();
  if (!range.contains(static_cast<double>(v))) {
    return error(n, fmt::format("{} must be {}, found {}", label, range.toString(), v));
  }
  return v;
}

absl::StatusOr<std::optional<Section>> subTable(const Section& parent, std::string_view key,
                                                std::string name) {
  const toml::node* n = parent.find(key);
  if (n == nullptr) return std::optional<Section>();
  if (!n->is_table()) {
    return parent.error(
        *n, fmt::format("'{}': expected a table {}, found {}", key, name, describe(*n)));
  }
  return std::optional<Section>(Section(parent.source(), *n->as_table(), std::move(name)));
}

absl::StatusOr<std::vector<Section>> tableArray(const Section& parent, std::string_view key,
                                                std::string_view name) {
  std::vector<Section> out;
  const toml::node* n = parent.find(key);
  if (n == nullptr) return out;
  const toml::array* a = n->as_array();
  if (a == nullptr) {
    return parent.error(
        *n, fmt::format("'{}': expected an array of tables {}, found {}", key, name, describe(*n)));
  }
  for (size_t i = 0; i < a->size(); ++i) {
    const toml::node& element = *a->get(i);
    if (!element.is_table()) {
      return parent.error(element, fmt::format("'{}'[{}]: expected a table {}, found {}", key, i,
                                               name, describe(element)));
    }
    out.emplace_back(parent.source(), *element.as_table(), fmt::format("{} #{}", name, i + 1));
  }
  return out;
}

Section::Hint otherVariantHint(const Variants& variants, std::string_view self,
                               std::string_view kind) {
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

}  // namespace pbgi::strict_toml
