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

// A completion may carry the worker's next lease request, and its answer the next lease.
TEST(FarmApi, CompletionMayAskForTheNextTask) {
  farm::v1::CompleteTaskRequest c;
  c.mutable_next()->set_worker("w");  // 12, its worker 1
  EXPECT_EQ(hex(c.SerializeAsString()), "6203" "0a0177");
  farm::v1::CompleteTaskResponse r;
  r.mutable_next()->set_has_task(true);  // 1, its has_task 1
  EXPECT_EQ(hex(r.SerializeAsString()), "0a02" "0801");
}

// Kinds, states and log events became enums in new fields beside the strings v1 readers from
// before them read; both numbers and the enums' values are pinned.
TEST(FarmApi, EnumFieldsHaveNewNumbersBesideTheStrings) {
  farm::v1::LeaseTaskResponse lease;
  lease.set_kind("tile");                         // 4, still there
  lease.set_task_kind(farm::v1::TASK_KIND_TILE);  // 17
  EXPECT_EQ(hex(lease.SerializeAsString()),
            "220474696c65"
            "880102");

  farm::v1::TaskStatus task;
  task.set_task_kind(farm::v1::TASK_KIND_BAKE);      // 11
  task.set_task_state(farm::v1::TASK_STATE_LEASED);  // 12
  EXPECT_EQ(hex(task.SerializeAsString()),
            "5801"
            "6003");

  farm::v1::JobStatus job;
  job.set_job_state(farm::v1::JOB_STATE_FAILED);      // 11
  farm::v1::TaskCount* done = job.add_task_counts();  // 12: {state 1, count 2}
  done->set_state(farm::v1::TASK_STATE_DONE);
  done->set_count(5);
  EXPECT_EQ(hex(job.SerializeAsString()),
            "5803"
            "6204"
            "08041005");

  farm::v1::LogEntry entry;
  entry.set_task_kind(farm::v1::TASK_KIND_ASSEMBLE);  // 10
  EXPECT_EQ(hex(entry.SerializeAsString()), "5003");

  farm::v1::LogEntry event;
  event.set_event("done");                                  // 8, still there
  event.set_event_kind(farm::v1::TASK_EVENT_KIND_EXPIRED);  // 11
  EXPECT_EQ(hex(event.SerializeAsString()),
            "4204646f6e65"
            "5804");
}

TEST(FarmApi, EnumValuesAreStable) {
  EXPECT_EQ(farm::v1::TASK_KIND_UNSPECIFIED, 0);
  EXPECT_EQ(farm::v1::TASK_KIND_BAKE, 1);
  EXPECT_EQ(farm::v1::TASK_KIND_TILE, 2);
  EXPECT_EQ(farm::v1::TASK_KIND_ASSEMBLE, 3);
  EXPECT_EQ(farm::v1::TASK_STATE_UNSPECIFIED, 0);
  EXPECT_EQ(farm::v1::TASK_STATE_BLOCKED, 1);
  EXPECT_EQ(farm::v1::TASK_STATE_READY, 2);
  EXPECT_EQ(farm::v1::TASK_STATE_LEASED, 3);
  EXPECT_EQ(farm::v1::TASK_STATE_DONE, 4);
  EXPECT_EQ(farm::v1::TASK_STATE_DEAD, 5);
  EXPECT_EQ(farm::v1::TASK_STATE_CANCELLED, 6);
  EXPECT_EQ(farm::v1::JOB_STATE_UNSPECIFIED, 0);
  EXPECT_EQ(farm::v1::JOB_STATE_ACTIVE, 1);
  EXPECT_EQ(farm::v1::JOB_STATE_DONE, 2);
  EXPECT_EQ(farm::v1::JOB_STATE_FAILED, 3);
  EXPECT_EQ(farm::v1::JOB_STATE_CANCELLED, 4);
  EXPECT_EQ(farm::v1::TASK_EVENT_KIND_UNSPECIFIED, 0);
  EXPECT_EQ(farm::v1::TASK_EVENT_KIND_LEASED, 1);
  EXPECT_EQ(farm::v1::TASK_EVENT_KIND_DONE, 2);
  EXPECT_EQ(farm::v1::TASK_EVENT_KIND_FAILED, 3);
  EXPECT_EQ(farm::v1::TASK_EVENT_KIND_EXPIRED, 4);
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
