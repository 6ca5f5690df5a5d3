// The farm's JSON for scripts: every field present, 64-bit integers as numbers.

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "services/farm/farm_json.h"
#include "services/farm/farm_wire.h"

namespace pbgi::farm {
namespace {

TEST(FarmJson, EveryFieldIsPresentAndIdsAndCountsAreNumbers) {
  v1::GetStatusResponse status;
  v1::JobStatus* job = status.add_jobs();
  job->set_job(5);
  job->set_name("shot");
  v1::TaskStatus* dead = job->add_dead();
  dead->set_task(12345678901234);
  dead->set_tile(0);  // a default: the mapping alone leaves it out
  const nlohmann::json read = nlohmann::json::parse(toJson(status));
  const nlohmann::json& j = read["jobs"][0];
  ASSERT_TRUE(j["job"].is_number_integer()) << j;
  EXPECT_EQ(j["job"].get<int64_t>(), 5);
  EXPECT_TRUE(j.contains("stall") && j["stall"] == "") << j;
  EXPECT_TRUE(j["blocklistedWorkers"].is_array()) << j;
  const nlohmann::json& d = j["dead"][0];
  EXPECT_EQ(d["task"].get<int64_t>(), 12345678901234);
  EXPECT_TRUE(d.contains("tile") && d["tile"] == 0) << d;
  EXPECT_TRUE(d.contains("lastError") && d["lastError"] == "") << d;

  v1::ListWorkersResponse workers;
  v1::WorkerStatus* w = workers.add_workers();
  w->set_worker("w1");
  w->set_memory_bytes(uint64_t{17} << 32);
  const nlohmann::json wj = nlohmann::json::parse(toJson(workers))["workers"][0];
  ASSERT_TRUE(wj["memoryBytes"].is_number_unsigned()) << wj;
  EXPECT_EQ(wj["memoryBytes"].get<uint64_t>(), uint64_t{17} << 32);
  EXPECT_TRUE(wj.contains("cores") && wj["cores"] == 0) << wj;
  EXPECT_TRUE(wj.contains("state")) << wj;
}

}  // namespace
}  // namespace pbgi::farm
