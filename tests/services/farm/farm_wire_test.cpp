// The wire's enums against the store's, and messages from a coordinator older than the enums
// (only the words set) read the same. A job's overrides travel typed, and older text reads
// the same.

#include <gtest/gtest.h>

#include "core/render/integrators.h"
#include "services/farm/farm_wire.h"

namespace pbgi::farm {
namespace {

TEST(FarmWire, EveryStoreValueHasAnEnumAndItsWord) {
  for (const TaskKind k : {TaskKind::kBake, TaskKind::kTile, TaskKind::kAssemble}) {
    EXPECT_NE(toWire(k), v1::TASK_KIND_UNSPECIFIED) << toString(k);
    EXPECT_EQ(fromWire(toWire(k)), k);
    EXPECT_EQ(wireWord(toWire(k)), toString(k));
  }
  for (int s = 0; s < 6; ++s) {
    const TaskState state = static_cast<TaskState>(s);
    EXPECT_NE(toWire(state), v1::TASK_STATE_UNSPECIFIED) << toString(state);
    EXPECT_EQ(fromWire(toWire(state)), state);
    EXPECT_EQ(wireWord(toWire(state)), toString(state));
  }
  for (int s = 0; s < 4; ++s) {
    const JobState state = static_cast<JobState>(s);
    EXPECT_NE(toWire(state), v1::JOB_STATE_UNSPECIFIED) << toString(state);
    EXPECT_EQ(fromWire(toWire(state)), state);
  }
  for (const TaskEventKind k : {TaskEventKind::kLeased, TaskEventKind::kDone,
                                TaskEventKind::kFailed, TaskEventKind::kExpired}) {
    EXPECT_NE(toWire(k), v1::TASK_EVENT_KIND_UNSPECIFIED) << toString(k);
    EXPECT_EQ(fromWire(toWire(k)), k);
    EXPECT_EQ(wireWord(toWire(k)), toString(k));
    // Through a message and back, as GetLogs sends it and `pbgi logs` reads it.
    v1::LogEntry sent;
    setEvent(k, &sent);
    v1::LogEntry received;
    ASSERT_TRUE(received.ParseFromString(sent.SerializeAsString()));
    EXPECT_EQ(received.event(), toString(k));  // what a v1 reader from before the enum reads
    EXPECT_EQ(taskEventKindOf(received), toWire(k));
    EXPECT_EQ(fromWire(taskEventKindOf(received)), k);
  }
  EXPECT_EQ(fromWire(v1::TASK_EVENT_KIND_UNSPECIFIED), std::nullopt);
  EXPECT_EQ(fromWire(static_cast<v1::TaskEventKind>(99)), std::nullopt);
  EXPECT_EQ(wireWord(v1::TASK_EVENT_KIND_UNSPECIFIED), "unknown");
  EXPECT_EQ(fromWire(v1::TASK_KIND_UNSPECIFIED), std::nullopt);
  EXPECT_EQ(fromWire(static_cast<v1::TaskKind>(99)), std::nullopt);  // a newer sender's
  EXPECT_EQ(wireWord(v1::TASK_KIND_UNSPECIFIED), "unknown");
}

TEST(FarmWire, BothFormsAreWrittenAndTheEnumIsRead) {
  v1::TaskStatus task;
  setKindAndState(TaskKind::kTile, TaskState::kLeased, &task);
  EXPECT_EQ(task.kind(), "tile");  // what a v1 reader from before the enums reads
  EXPECT_EQ(task.state(), "leased");
  EXPECT_EQ(taskKindOf(task), v1::TASK_KIND_TILE);
  EXPECT_EQ(taskStateOf(task), v1::TASK_STATE_LEASED);
  // The enum wins over the word.
  task.set_kind("bake");
  EXPECT_EQ(taskKindOf(task), v1::TASK_KIND_TILE);

  v1::LogEntry entry;
  setEvent(TaskEventKind::kExpired, &entry);
  EXPECT_EQ(entry.event(), "expired");
  EXPECT_EQ(entry.event_kind(), v1::TASK_EVENT_KIND_EXPIRED);
  entry.set_event("done");
  EXPECT_EQ(taskEventKindOf(entry), v1::TASK_EVENT_KIND_EXPIRED);

  v1::JobStatus job;
  setState(JobState::kActive, {1, 2, 3, 4, 0, 0}, &job);
  EXPECT_EQ(job.state(), "active");
  EXPECT_EQ(job.tasks_by_state().at("done"), 4);
  EXPECT_EQ(jobStateOf(job), v1::JOB_STATE_ACTIVE);
  const auto counts = taskCounts(job);
  EXPECT_EQ(counts[v1::TASK_STATE_BLOCKED], 1);
  EXPECT_EQ(counts[v1::TASK_STATE_DONE], 4);
  EXPECT_EQ(counts[v1::TASK_STATE_CANCELLED], 0);
}

TEST(FarmWire, AnOlderCoordinatorsWordsAreRead) {
  v1::LeaseTaskResponse lease;
  lease.set_kind("assemble");
  EXPECT_EQ(taskKindOf(lease), v1::TASK_KIND_ASSEMBLE);
  lease.set_kind("photon");
  EXPECT_EQ(taskKindOf(lease), v1::TASK_KIND_UNSPECIFIED);

  v1::JobStatus job;
  job.set_state("failed");
  (*job.mutable_tasks_by_state())["done"] = 3;
  (*job.mutable_tasks_by_state())["dead"] = 2;
  EXPECT_EQ(jobStateOf(job), v1::JOB_STATE_FAILED);
  const auto counts = taskCounts(job);
  EXPECT_EQ(counts[v1::TASK_STATE_DONE], 3);
  EXPECT_EQ(counts[v1::TASK_STATE_DEAD], 2);

  v1::LogEntry entry;
  entry.set_kind("bake");
  EXPECT_EQ(taskKindOf(entry), v1::TASK_KIND_BAKE);
  for (const auto& [word, kind] : {std::pair{"leased", v1::TASK_EVENT_KIND_LEASED},
                                   std::pair{"done", v1::TASK_EVENT_KIND_DONE},
                                   std::pair{"failed", v1::TASK_EVENT_KIND_FAILED},
                                   std::pair{"expired", v1::TASK_EVENT_KIND_EXPIRED}}) {
    entry.set_event(word);
    EXPECT_EQ(taskEventKindOf(entry), kind) << word;
  }
  entry.set_event("paused");
  EXPECT_EQ(taskEventKindOf(entry), v1::TASK_EVENT_KIND_UNSPECIFIED);
}

RenderOverrides sampleOverrides() {
  RenderOverrides o;
  o.integrator = "pbgi";
  o.spp = 16;
  EXPECT_TRUE(setParamText(o.params, "gather", "per-pixel", {"test"}).ok());
  EXPECT_TRUE(setParamText(o.params, "cache_mb", "64", {"test"}).ok());
  EXPECT_TRUE(setParamText(o.params, "max_solid_angle", "0.125", {"test"}).ok());
  return o;
}

TEST(FarmWire, OverridesKeepTheirTypesOnTheWireAndInTheStore) {
  const RenderOverrides o = sampleOverrides();
  const v1::RenderOverrides wire = toWire(o);
  EXPECT_EQ(wire.params().at("gather").value_case(), v1::ParamValue::kChoice);
  EXPECT_EQ(wire.params().at("cache_mb").int_value(), 64);
  EXPECT_EQ(wire.params().at("max_solid_angle").float_value(), 0.125);
  auto back = fromWire(wire);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(*back, o);
  EXPECT_EQ(std::get<int64_t>(back->params.find("cache_mb")->value), 64);

  const std::string stored = toStoreText(o);
  EXPECT_TRUE(stored.starts_with('{')) << stored;
  auto read = fromStoreText(stored);
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(*read, o);
  auto none = fromStoreText(toStoreText({}));
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_TRUE(none->empty());

  // The image's size, seed and output options, on the wire and in the store.
  RenderOverrides image = o;
  image.width = 640;
  image.height = 360;
  image.seed = 0;  // set, and zero: not the shot's
  image.output = OutputOptions{.aovs = std::vector<std::string>{"depth"}, .exrCompression = "piz"};
  auto imageBack = fromStoreText(toStoreText(image));
  ASSERT_TRUE(imageBack.ok()) << imageBack.status();
  EXPECT_EQ(*imageBack, image);
  image.output->aovs.reset();  // every layer
  imageBack = fromWire(toWire(image));
  ASSERT_TRUE(imageBack.ok()) << imageBack.status();
  EXPECT_EQ(*imageBack, image);
}

TEST(FarmWire, AStoreOrClientFromBeforeTypedOverridesIsReadTheSame) {
  auto read = fromStoreText(
      "integrator=pbgi\nspp=16\ncache_mb=64\ngather=per-pixel\n"
      "max_solid_angle=0.125\n");
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(*read, sampleOverrides());
  auto empty = fromStoreText("");
  ASSERT_TRUE(empty.ok()) << empty.status();
  EXPECT_TRUE(empty->empty());

  v1::SubmitJobRequest old;
  old.add_overrides("integrator=pbgi");
  old.add_overrides("spp=16");
  auto submitted = submittedOverrides(old);
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  EXPECT_EQ(submitted->integrator, "pbgi");
  EXPECT_EQ(submitted->spp, 16);
  // `render`, when set, is what counts.
  *old.mutable_render() = toWire(sampleOverrides());
  submitted = submittedOverrides(old);
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  EXPECT_EQ(*submitted, sampleOverrides());
}

TEST(FarmWire, ATypedValueIsCheckedAgainstItsDeclaration) {
  const auto refused = [](const v1::RenderOverrides& wire, std::string_view says) {
    const auto read = fromWire(wire);
    EXPECT_EQ(read.status().code(), absl::StatusCode::kInvalidArgument) << read.status();
    EXPECT_NE(std::string(read.status().message()).find(says), std::string::npos) << read.status();
  };
  v1::RenderOverrides unknown;
  (*unknown.mutable_params())["light_solid_angel"].set_float_value(0.1);
  refused(unknown, "unknown parameter 'light_solid_angel'");
  v1::RenderOverrides wrongType;
  (*wrongType.mutable_params())["gather"].set_int_value(2);
  refused(wrongType, "one of:");
  v1::RenderOverrides outOfRange;
  (*outOfRange.mutable_params())["cache_mb"].set_int_value(-5);
  refused(outOfRange, "cache_mb");
  v1::RenderOverrides unset;
  (*unset.mutable_params())["quality"];
  refused(unset, "no value");
  v1::RenderOverrides negativeSpp;
  negativeSpp.set_spp(-1);
  refused(negativeSpp, "spp");
  v1::RenderOverrides hugeImage;
  hugeImage.set_width(100000);
  hugeImage.set_height(10);
  refused(hugeImage, "resolution");
  v1::RenderOverrides badAov;
  badAov.mutable_output()->add_aovs("specular");
  refused(badAov, "AOV 'specular'");
  v1::RenderOverrides badCompression;
  badCompression.mutable_output()->set_all_aovs(true);
  badCompression.mutable_output()->set_exr_compression("lzma");
  refused(badCompression, "lzma");
  const auto damaged = fromStoreText("{\"params\": 3}");
  EXPECT_EQ(damaged.status().code(), absl::StatusCode::kDataLoss) << damaged.status();
}

}  // namespace
}  // namespace pbgi::farm
