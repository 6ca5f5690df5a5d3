#include "services/farm/farm_wire.h"

#include <utility>

#include <absl/strings/str_split.h>
#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>

#include "core/render/integrators.h"
#include "core/render/renderer.h"
#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

namespace {

// Each set once: the store's value, the wire's. The words are the store's toString.
constexpr std::pair<TaskKind, v1::TaskKind> kKinds[] = {
    {TaskKind::kBake, v1::TASK_KIND_BAKE},
    {TaskKind::kTile, v1::TASK_KIND_TILE},
    {TaskKind::kAssemble, v1::TASK_KIND_ASSEMBLE},
};
constexpr std::pair<TaskState, v1::TaskState> kTaskStates[] = {
    {TaskState::kBlocked, v1::TASK_STATE_BLOCKED},
    {TaskState::kReady, v1::TASK_STATE_READY},
    {TaskState::kLeased, v1::TASK_STATE_LEASED},
    {TaskState::kDone, v1::TASK_STATE_DONE},
    {TaskState::kDead, v1::TASK_STATE_DEAD},
    {TaskState::kCancelled, v1::TASK_STATE_CANCELLED},
};
constexpr std::pair<JobState, v1::JobState> kJobStates[] = {
    {JobState::kActive, v1::JOB_STATE_ACTIVE},
    {JobState::kDone, v1::JOB_STATE_DONE},
    {JobState::kFailed, v1::JOB_STATE_FAILED},
    {JobState::kCancelled, v1::JOB_STATE_CANCELLED},
};
constexpr std::pair<TaskEventKind, v1::TaskEventKind> kEventKinds[] = {
    {TaskEventKind::kLeased, v1::TASK_EVENT_KIND_LEASED},
    {TaskEventKind::kDone, v1::TASK_EVENT_KIND_DONE},
    {TaskEventKind::kFailed, v1::TASK_EVENT_KIND_FAILED},
    {TaskEventKind::kExpired, v1::TASK_EVENT_KIND_EXPIRED},
};

template <typename Store, typename Wire, size_t N>
Wire toWireIn(const std::pair<Store, Wire> (&table)[N], Store value) {
  for (const auto& [store, wire] : table) {
    if (store == value) return wire;
  }
  return Wire{};  // UNSPECIFIED; the store has no value the tables miss
}

template <typename Store, typename Wire, size_t N>
std::optional<Store> fromWireIn(const std::pair<Store, Wire> (&table)[N], Wire value) {
  for (const auto& [store, wire] : table) {
    if (wire == value) return store;
  }
  return std::nullopt;
}

// The word of a message from before the enums.
template <typename Store, typename Wire, size_t N>
Wire named(const std::pair<Store, Wire> (&table)[N], const std::string& word) {
  for (const auto& [store, wire] : table) {
    if (toString(store) == word) return wire;
  }
  return Wire{};
}

template <typename Store, typename Wire, size_t N>
std::string wordIn(const std::pair<Store, Wire> (&table)[N], Wire value) {
  const std::optional<Store> store = fromWireIn(table, value);
  return store ? toString(*store) : "unknown";
}

template <typename Message>
v1::TaskKind kindOf(const Message& m) {
  if (m.task_kind() != v1::TASK_KIND_UNSPECIFIED) return m.task_kind();
  return m.kind() == kAuditWord ? v1::TASK_KIND_AUDIT : named(kKinds, m.kind());
}

}  // namespace

v1::TaskKind toWire(TaskKind kind) { return toWireIn(kKinds, kind); }
v1::TaskState toWire(TaskState state) { return toWireIn(kTaskStates, state); }
v1::JobState toWire(JobState state) { return toWireIn(kJobStates, state); }
v1::TaskEventKind toWire(TaskEventKind kind) { return toWireIn(kEventKinds, kind); }
std::optional<TaskKind> fromWire(v1::TaskKind kind) { return fromWireIn(kKinds, kind); }
std::optional<TaskState> fromWire(v1::TaskState state) { return fromWireIn(kTaskStates, state); }
std::optional<JobState> fromWire(v1::JobState state) { return fromWireIn(kJobStates, state); }
std::optional<TaskEventKind> fromWire(v1::TaskEventKind kind) {
  return fromWireIn(kEventKinds, kind);
}

std::string wireWord(v1::TaskKind kind) {
  return kind == v1::TASK_KIND_AUDIT ? kAuditWord : wordIn(kKinds, kind);
}
std::string wireWord(v1::TaskState state) { return wordIn(kTaskStates, state); }
std::string wireWord(v1::JobState state) { return wordIn(kJobStates, state); }
std::string wireWord(v1::TaskEventKind kind) { return wordIn(kEventKinds, kind); }

v1::TaskKind taskKindOf(const v1::LeaseTaskResponse& task) { return kindOf(task); }
v1::TaskKind taskKindOf(const v1::TaskStatus& task) { return kindOf(task); }
v1::TaskKind taskKindOf(const v1::LogEntry& entry) { return kindOf(entry); }

v1::TaskState taskStateOf(const v1::TaskStatus& task) {
  return task.task_state() != v1::TASK_STATE_UNSPECIFIED ? task.task_state()
                                                         : named(kTaskStates, task.state());
}

v1::JobState jobStateOf(const v1::JobStatus& job) {
  return job.job_state() != v1::JOB_STATE_UNSPECIFIED ? job.job_state()
                                                      : named(kJobStates, job.state());
}

v1::TaskEventKind taskEventKindOf(const v1::LogEntry& entry) {
  return entry.event_kind() != v1::TASK_EVENT_KIND_UNSPECIFIED ? entry.event_kind()
                                                               : named(kEventKinds, entry.event());
}

std::array<int, v1::TaskState_ARRAYSIZE> taskCounts(const v1::JobStatus& job) {
  std::array<int, v1::TaskState_ARRAYSIZE> counts{};
  if (job.task_counts_size() > 0) {
    for (const v1::TaskCount& c : job.task_counts()) {
      if (v1::TaskState_IsValid(c.state())) counts[static_cast<size_t>(c.state())] += c.count();
    }
    return counts;
  }
  for (const auto& [word, count] : job.tasks_by_state()) {
    counts[static_cast<size_t>(named(kTaskStates, word))] += count;
  }
  return counts;
}

void setKind(TaskKind kind, v1::LeaseTaskResponse* out) {
  out->set_task_kind(toWire(kind));
  out->set_kind(toString(kind));
}

void setAuditKind(v1::LeaseTaskResponse* out) {
  out->set_task_kind(v1::TASK_KIND_AUDIT);
  out->set_kind(kAuditWord);
}

void setKind(TaskKind kind, v1::LogEntry* out) {
  out->set_task_kind(toWire(kind));
  out->set_kind(toString(kind));
}

void setEvent(TaskEventKind kind, v1::LogEntry* out) {
  out->set_event_kind(toWire(kind));
  out->set_event(toString(kind));
}

void setKindAndState(TaskKind kind, TaskState state, v1::TaskStatus* out) {
  out->set_task_kind(toWire(kind));
  out->set_kind(toString(kind));
  out->set_task_state(toWire(state));
  out->set_state(toString(state));
}

void setState(JobState state, const PerTaskState<int>& tasksByState, v1::JobStatus* out) {
  out->set_job_state(toWire(state));
  out->set_state(toString(state));
  for (const auto& [store, wire] : kTaskStates) {
    const int count = tasksByState[static_cast<size_t>(store)];
    (*out->mutable_tasks_by_state())[toString(store)] = count;
    v1::TaskCount* c = out->add_task_counts();
    c->set_state(wire);
    c->set_count(count);
  }
}

v1::RenderOverrides toWire(const RenderOverrides& overrides) {
  v1::RenderOverrides out;
  out.set_integrator(overrides.integrator);
  out.set_spp(overrides.spp);
  for (const auto& [key, param] : overrides.params.values()) {
    v1::ParamValue& value = (*out.mutable_params())[key];
    if (const auto* i = std::get_if<int64_t>(&param.value)) {
      value.set_int_value(*i);
    } else if (const auto* d = std::get_if<double>(&param.value)) {
      value.set_float_value(*d);
    } else {
      value.set_choice(std::get<std::string>(param.value));
    }
  }
  out.set_width(overrides.width);
  out.set_height(overrides.height);
  if (overrides.seed) out.set_seed(*overrides.seed);
  if (overrides.output) {
    v1::OutputOptions* o = out.mutable_output();
    o->set_all_aovs(!overrides.output->aovs);
    if (overrides.output->aovs) {
      for (const std::string& a : *overrides.output->aovs) o->add_aovs(a);
    }
    o->set_exr_compression(overrides.output->exrCompression);
  }
  return out;
}

absl::StatusOr<RenderOverrides> fromWire(const v1::RenderOverrides& overrides) {
  RenderOverrides out;
  out.integrator = overrides.integrator();
  out.integratorWhere = {"job override integrator"};
  if (overrides.spp() < 0 || overrides.spp() > kMaxOverrideSpp) {
    return absl::InvalidArgumentError(
        fmt::format("job override spp {}: expected a whole number in [1, {}] (or 0: the shot's)",
                    overrides.spp(), kMaxOverrideSpp));
  }
  out.spp = overrides.spp();
  for (const auto& [key, value] : overrides.params()) {
    ParamValue param{.where = {fmt::format("job override {}", key)}};
    switch (value.value_case()) {
      case v1::ParamValue::kIntValue:
        param.value = value.int_value();
        break;
      case v1::ParamValue::kFloatValue:
        param.value = value.float_value();
        break;
      case v1::ParamValue::kChoice:
        param.value = value.choice();
        break;
      default:
        return absl::InvalidArgumentError(fmt::format(
            "job override {}: no value (expected an integer, a number or a name)", key));
    }
    PBGI_RETURN_IF_ERROR(setParamValue(out.params, key, std::move(param)));
  }
  if (overrides.width() != 0 || overrides.height() != 0) {
    PBGI_RETURN_IF_ERROR(
        checkImageSize(overrides.width(), overrides.height(), {1, 1}, "job override resolution"));
  }
  out.width = overrides.width();
  out.height = overrides.height();
  if (overrides.has_seed()) out.seed = overrides.seed();
  if (overrides.has_output()) {
    OutputOptions& o = out.output.emplace();
    if (!overrides.output().all_aovs()) {
      o.aovs.emplace(overrides.output().aovs().begin(), overrides.output().aovs().end());
      PBGI_RETURN_IF_ERROR(checkAovs(*o.aovs));
    }
    if (!overrides.output().exr_compression().empty()) {
      o.exrCompression = overrides.output().exr_compression();
    }
    PBGI_RETURN_IF_ERROR(checkExrCompression(o.exrCompression, "job override EXR compression"));
  }
  return out;
}

absl::StatusOr<RenderOverrides> submittedOverrides(const v1::SubmitJobRequest& request) {
  if (request.has_render()) return fromWire(request.render());
  return parseOverrideLines(
      std::vector<std::string>(request.overrides().begin(), request.overrides().end()));
}

std::string toStoreText(const RenderOverrides& overrides) {
  std::string json;
  (void)google::protobuf::util::MessageToJsonString(toWire(overrides), &json);
  return json;
}

absl::StatusOr<RenderOverrides> fromStoreText(std::string_view text) {
  if (text.starts_with('{')) {
    v1::RenderOverrides wire;
    const auto parsed = google::protobuf::util::JsonStringToMessage(
        google::protobuf::StringPiece(text.data(), text.size()), &wire);
    if (!parsed.ok()) {
      return absl::DataLossError(
          fmt::format("stored overrides {}: {}", text, std::string(parsed.message())));
    }
    return fromWire(wire);
  }
  return parseOverrideLines(
      absl::StrSplit(absl::string_view(text.data(), text.size()), '\n', absl::SkipEmpty()));
}

}  // namespace pbgi::farm
