#include "services/farm/farm_json.h"

#include <cstdint>

#include <google/protobuf/descriptor.h>
#include <google/protobuf/util/json_util.h>
#include <nlohmann/json.hpp>

namespace pbgi::farm {

namespace {

namespace pb = google::protobuf;
using Json = nlohmann::ordered_json;

bool is64Bit(const pb::FieldDescriptor& field) {
  switch (field.cpp_type()) {
    case pb::FieldDescriptor::CPPTYPE_INT64:
    case pb::FieldDescriptor::CPPTYPE_UINT64:
      return true;
    default:
      return false;
  }
}

Json number(const pb::FieldDescriptor& field, const Json& text) {
  if (!text.is_string()) return text;
  const std::string s = text.get<std::string>();
  try {
    if (field.cpp_type() == pb::FieldDescriptor::CPPTYPE_UINT64) return Json(std::stoull(s));
    return Json(std::stoll(s));
  } catch (const std::exception&) {
    return text;  // not a number after all: left as the mapping wrote it
  }
}

// The 64-bit integers of `json` (the mapping of a `descriptor` message) as numbers, in place.
void numbersFor64BitFields(const pb::Descriptor& descriptor, Json& json) {
  if (!json.is_object()) return;
  for (int i = 0; i < descriptor.field_count(); ++i) {
    const pb::FieldDescriptor& field = *descriptor.field(i);
    const auto it = json.find(field.json_name());
    if (it == json.end()) continue;
    Json& value = *it;
    if (field.is_map()) {
      const pb::FieldDescriptor& mapped = *field.message_type()->map_value();
      for (auto& [key, v] : value.items()) {
        if (is64Bit(mapped)) v = number(mapped, v);
        if (mapped.message_type() != nullptr) numbersFor64BitFields(*mapped.message_type(), v);
      }
    } else if (field.is_repeated()) {
      for (Json& v : value) {
        if (is64Bit(field)) v = number(field, v);
        if (field.message_type() != nullptr) numbersFor64BitFields(*field.message_type(), v);
      }
    } else if (is64Bit(field)) {
      value = number(field, value);
    } else if (field.message_type() != nullptr) {
      numbersFor64BitFields(*field.message_type(), value);
    }
  }
}

}  // namespace

std::string toJson(const pb::Message& message) {
  pb::util::JsonPrintOptions options;
  options.always_print_primitive_fields = true;
  std::string text;
  (void)pb::util::MessageToJsonString(message, &text, options);
  Json json = Json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (json.is_discarded()) return text;
  numbersFor64BitFields(*message.GetDescriptor(), json);
  return json.dump();
}

}  // namespace pbgi::farm
