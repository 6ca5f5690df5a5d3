#pragma once
// The farm's messages as JSON for scripts (pbgi status/workers/logs --json, the coordinator's
// /status): protobuf's JSON mapping, with two changes that make a stable schema: every field
// is present, defaults included (tile 0, an empty error), and 64-bit integers (job and task
// ids, byte counts) are numbers, not the strings the mapping writes for them. Field names are
// the mapping's lowerCamelCase.
#include <string>

#include <google/protobuf/message.h>

namespace pbgi::farm {

std::string toJson(const google::protobuf::Message& message);

}  // namespace pbgi::farm
