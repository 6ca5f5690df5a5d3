// The wire API is a contract with workers and scripts of other versions: field numbers never
// change (ARCHITECTURE: "versioned package, never renumber a field"). These bytes are what a
// v1 worker sends and expects; a renumbered or retyped field changes them.

#include <gtest/gtest.h>

#include <string>

#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "pbgi/farm/v1/farm.pb.h"

namespace pbgi {
namespace {

std::string hex(const std::string& bytes) {
  static const char* digits = "0123456789abcdef";
  std::string out;
  for (unsigned char c : bytes) {
    out += digits[c >> 4];
    out += digits[c & 15];
  }
  return out;
}

TEST(FarmApi, LeaseResponseFieldNumbersAreStable) {
  farm::v1::LeaseTaskResponse r;
  r.set_has_task(true);  // 1
  r.set_task(5);         // 2
  r.set_attempt(2);      // 3
  r.set_kind("tile");    // 4
  r.set_frame(3);        // 6
  r.set_tile(7);         // 7
  EXPECT_EQ(hex(r.SerializeAsString()), "08011005180222047469" "6c6530033807");
  farm::v1::LeaseTaskResponse back;
  ASSERT_TRUE(back.ParseFromString(r.SerializeAsString()));
  EXPECT_EQ(back.tile(), 7);
}

TEST(FarmApi, CompletionCarriesTheAttempt) {
  farm::v1::CompleteTaskRequest c;
  c.set_worker("w");  // 1
  c.set_task(9);      // 2
  c.set_attempt(4);   // 3
  EXPECT_EQ(hex(c.SerializeAsString()), "0a01771009" "1804");
}

TEST(FarmApi, ServiceIsVersionedAndHasItsMethods) {
  const auto* service = farm::v1::Coordinator::service_full_name();
  EXPECT_STREQ(service, "pbgi.farm.v1.Coordinator");
  const google::protobuf::ServiceDescriptor* d =
      farm::v1::LeaseTaskRequest::descriptor()->file()->FindServiceByName("Coordinator");
  ASSERT_NE(d, nullptr);
  for (const char* m : {"SubmitJob", "GetStatus", "CancelJob", "RetryJob", "RegisterWorker",
                        "ListWorkers", "LeaseTask", "Heartbeat", "CompleteTask", "FailTask",
                        "OpenTree", "FetchPages"}) {
    EXPECT_NE(d->FindMethodByName(m), nullptr) << m;
  }
  EXPECT_TRUE(d->FindMethodByName("FetchPages")->server_streaming());
}

}  // namespace
}  // namespace pbgi
