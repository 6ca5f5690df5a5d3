#include "services/coordinator/dashboard/dashboard.h"

#include <algorithm>
#include <atomic>
#include <charconv>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <thread>

#include <absl/strings/ascii.h>
#include <absl/strings/str_split.h>
#include <fmt/format.h>
#include <httplib.h>
#include <nlohmann/json.hpp>

#include "core/util/log.h"
#include "core/util/status.h"
#include "services/coordinator/dashboard/dashboard_assets.h"
#include "services/coordinator/farm_auth.h"
#include "services/coordinator/lease_reaper.h"
#include "services/coordinator/status_report.h"

namespace pbgi::farm {

namespace {

// The API's JSON, in the order the fields are set. Text that is not UTF-8 (a worker's log) is
// sent with U+FFFD in place of the bytes that are not.
using Json = nlohmann::ordered_json;
std::string dump(const Json& j) { return j.dump(-1, ' ', false, Json::error_handler_t::replace); }

}  // namespace

namespace {

using std::chrono::milliseconds;

void replyJson(httplib::Response& res, std::string body, int status = 200) {
  res.status = status;
  res.set_header("Cache-Control", "no-store");
  res.set_content(std::move(body), "application/json");
}

void replyError(httplib::Response& res, const absl::Status& s) {
  int status = 500;
  switch (s.code()) {
    case absl::StatusCode::kNotFound: status = 404; break;
    case absl::StatusCode::kInvalidArgument: status = 400; break;
    case absl::StatusCode::kFailedPrecondition: status = 409; break;
    case absl::StatusCode::kUnauthenticated: status = 401; break;
    default: break;
  }
  replyJson(res, dump(Json{{"error", std::string(s.message())}}), status);
}

// An optional integer query parameter; InvalidArgument naming it when it is not one.
absl::StatusOr<std::optional<int>> intParam(const httplib::Request& req, const char* name) {
  if (!req.has_param(name)) return std::optional<int>();
  const std::string text = req.get_param_value(name);
  int value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size()) {
    return absl::InvalidArgumentError(
        fmt::format("query parameter {}={}: expected an integer", name, text));
  }
  return std::optional<int>(value);
}

int64_t pathId(const httplib::Request& req, size_t match = 1) {
  return std::stoll(req.matches[match].str());  // the route's regex admits digits only
}

int totalTasks(const JobInfo& job) {
  int n = 0;
  for (const int c : job.tasksByState) n += c;
  return n;
}

// A number, or null where JSON has none (NaN, infinities).
Json number(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

Json taskJson(const TaskInfo& t) {
  return {{"id", t.id},
          {"kind", toString(t.ref.kind)},
          {"frame", t.ref.frame},
          {"tile", t.ref.tile},
          {"state", toString(t.state)},
          {"attempt", t.attempt},
          {"failures", t.failures},
          {"worker", t.worker},
          {"error", t.lastError},
          {"progress", number(t.progress)}};
}

Json auditJson(const AuditInfo& a) {
  return {{"state", toString(a.state)},
          {"tiles", a.spec.tiles},
          {"spp", a.spec.spp},
          {"threshold", number(a.spec.threshold)},
          {"relMse", a.result ? number(a.result->relMse) : Json(nullptr)},
          {"bias", a.result ? number(a.result->bias) : Json(nullptr)},
          {"flagged", a.flagged()},
          {"worker", a.worker},
          {"error", a.lastError}};
}

// The job's time left from its finished tasks' durations (estimatedSecondsLeft): its tasks
// left (the store's count) shared among the kinds as this coordinator has seen them finish.
std::optional<double> jobEta(const JobInfo& job, const TaskDurations& durations) {
  const int frames = static_cast<int>(job.spec.frames.size());
  const std::array<int, 3> totals = {job.spec.needsBake ? frames : 0, frames * job.spec.tileCount,
                                     frames};
  std::array<int, 3> remaining{};
  int sum = 0;
  for (size_t k = 0; k < 3; ++k) {
    remaining[k] = std::max(0, totals[k] - durations.count[k]);
    sum += remaining[k];
  }
  // Completions before this coordinator started are in the store's count, not in ours.
  const int left = totalTasks(job) - job.tasksByState[static_cast<int>(TaskState::kDone)];
  if (sum > left && sum > 0) {
    int assigned = 0;
    for (size_t k = 0; k < 3; ++k) {
      remaining[k] = k == 2 ? left - assigned : remaining[k] * left / sum;
      assigned += remaining[k];
    }
  }
  return estimatedSecondsLeft(durations, remaining,
                              job.tasksByState[static_cast<int>(TaskState::kLeased)]);
}

// A job as the list shows it: state, counts, progress and the time left (jobEta), and how
// many of its frames' audits are done and flagged.
Json jobSummaryJson(const JobInfo& job, const std::vector<AuditInfo>& audits, const JobStall& stall,
                    const TaskDurations& durations, Seconds now) {
  int audited = 0, flagged = 0;
  for (const AuditInfo& a : audits) {
    audited += a.result.has_value();
    flagged += a.flagged();
  }
  const int total = totalTasks(job);
  const int done = job.tasksByState[static_cast<int>(TaskState::kDone)];
  const double progress = total > 0 ? double(done) / total : 0.0;
  Json eta = nullptr;
  if (job.state == JobState::kActive) {
    if (const std::optional<double> left = jobEta(job, durations)) eta = number(*left);
  }
  Json states = Json::object();
  for (int s = 0; s < kTaskStateCount; ++s) {
    states[toString(static_cast<TaskState>(s))] = job.tasksByState[s];
  }
  // Every dead task of a large job would be megabytes: the first few, and how many.
  Json dead = Json::array();
  for (size_t i = 0; i < job.dead.size() && i < 20; ++i) dead.push_back(taskJson(job.dead[i]));
  return {{"id", job.id},
          {"name", job.spec.name},
          {"state", stall.word.empty() ? toString(job.state) : stall.word},
          {"blocklisted", stall.blocklisted},
          {"stallError", stall.error},
          {"priority", job.spec.priority},
          {"submitted", number(job.submitted)},
          {"frames", job.spec.frames},
          {"tilesPerFrame", job.spec.tileCount},
          {"tasks", std::move(states)},
          {"total", total},
          {"done", done},
          {"progress", number(progress)},
          {"eta", std::move(eta)},
          {"output", job.spec.outputPattern},
          {"deadCount", job.dead.size()},
          {"dead", std::move(dead)},
          {"audits", audits.size()},
          {"audited", audited},
          {"flagged", flagged}};
}

// One job's frames: per frame its bake's and assemble's state and its tiles' states as one
// string of digits (TaskState numbers, tile order), with where each tile lies in the view's
// grid of tiles; and the tasks leased now. 4,096 tiles make about 40 kB.
absl::StatusOr<Json> jobDetailJson(const DashboardParts& p, int64_t id, Seconds now) {
  PBGI_ASSIGN_OR_RETURN(const JobInfo info, p.store.job(id));
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const ParsedJob> view, p.jobs.get(id));
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, p.store.tasks(id));
  PBGI_ASSIGN_OR_RETURN(const std::vector<AuditInfo> audits, p.store.audits(id));
  const int tileSize = p.jobs.tileSize();
  const int cols = (view->shot.width + tileSize - 1) / tileSize;
  const int rows = (view->shot.height + tileSize - 1) / tileSize;
  Json cells = Json::array();
  for (size_t t = 0; t < view->tiles.size(); ++t) {
    const TileRect r = view->tiles[t].empty() ? TileRect{} : view->tiles[t].front();
    cells.push_back((r.x0 % std::max(view->shot.width, 1)) / tileSize);
    cells.push_back((r.y0 % std::max(view->shot.height, 1)) / tileSize);
  }
  struct Frame {
    char bake = 0, assemble = 0;
    std::string tiles;
    int done = 0;
    Json audit = nullptr;
  };
  std::map<int, Frame> frames;
  for (const int f : info.spec.frames) {
    frames[f].tiles.assign(static_cast<size_t>(info.spec.tileCount), '0');
  }
  for (const AuditInfo& a : audits) {
    if (auto it = frames.find(a.spec.frame); it != frames.end()) it->second.audit = auditJson(a);
  }
  Json leased = Json::array();
  for (const TaskInfo& t : tasks) {
    auto it = frames.find(t.ref.frame);
    if (it == frames.end()) continue;
    const char state = static_cast<char>('0' + static_cast<int>(t.state));
    switch (t.ref.kind) {
      case TaskKind::kBake: it->second.bake = state; break;
      case TaskKind::kAssemble: it->second.assemble = state; break;
      case TaskKind::kTile:
        if (t.ref.tile >= 0 && static_cast<size_t>(t.ref.tile) < it->second.tiles.size()) {
          it->second.tiles[static_cast<size_t>(t.ref.tile)] = state;
          if (t.state == TaskState::kDone) ++it->second.done;
        }
        break;
    }
    if (t.state == TaskState::kLeased) leased.push_back(taskJson(t));
  }
  const auto code = [](char c) { return c ? Json(std::string(1, c)) : Json(nullptr); };
  Json framesJson = Json::array();
  for (const auto& [f, fr] : frames) {
    framesJson.push_back({{"frame", f},
                          {"bake", code(fr.bake)},
                          {"assemble", code(fr.assemble)},
                          {"tiles", fr.tiles},
                          {"done", fr.done},
                          {"output", ParsedJobCache::frameOutput(*view, f)},
                          {"audit", fr.audit}});
  }
  PBGI_ASSIGN_OR_RETURN(
      const JobStall stall,
      jobStall(p.store, info, liveWorkers(p.store, p.activity, now, p.leaseSeconds)));
  return Json{{"job", jobSummaryJson(info, audits, stall, p.activity.durations(id), now)},
              {"tileSize", tileSize},
              {"width", view->shot.width},
              {"height", view->shot.height},
              {"views", {view->shot.camera.views.x, view->shot.camera.views.y}},
              {"cols", cols},
              {"rows", rows},
              {"cells", std::move(cells)},
              {"frames", std::move(framesJson)},
              {"leased", std::move(leased)}};
}

absl::StatusOr<Json> taskDetailJson(const DashboardParts& p, int64_t job,
                                    const httplib::Request& req) {
  PBGI_ASSIGN_OR_RETURN(const std::optional<int> frame, intParam(req, "frame"));
  PBGI_ASSIGN_OR_RETURN(const std::optional<int> tileParam, intParam(req, "tile"));
  if (!frame) return absl::InvalidArgumentError("a task needs its frame: ?frame=F");
  const std::string kind = req.has_param("kind") ? req.get_param_value("kind") : "tile";
  const int tile = kind == "tile" ? tileParam.value_or(-1) : -1;
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, p.store.tasks(job));
  const auto it = std::find_if(tasks.begin(), tasks.end(), [&](const TaskInfo& t) {
    return toString(t.ref.kind) == kind && t.ref.frame == *frame && t.ref.tile == tile;
  });
  if (it == tasks.end()) {
    return absl::NotFoundError(
        fmt::format("job {} has no {} task of frame {} tile {}", job, kind, *frame, tile));
  }
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskEvent> events,
                        p.store.events(job, *frame, std::optional<int>(tile)));
  Json eventsJson = Json::array();
  for (const TaskEvent& e : events) {
    if (e.task != it->id) continue;
    eventsJson.push_back({{"time", number(e.time)},
                          {"attempt", e.attempt},
                          {"worker", e.worker},
                          {"event", e.event},
                          {"text", e.text}});
  }
  return Json{{"task", taskJson(*it)}, {"events", std::move(eventsJson)}};
}

absl::StatusOr<Json> workersJson(const DashboardParts& p, Seconds now) {
  PBGI_ASSIGN_OR_RETURN(const std::vector<WorkerInfo> registered, p.store.workers());
  const std::map<std::string, WorkerActivity> seen = p.activity.workers();
  Json workers = Json::array();
  for (const WorkerInfo& w : registered) {
    const auto it = seen.find(w.id);
    const WorkerActivity a = it == seen.end() ? WorkerActivity{} : it->second;
    Json held = Json::array();
    for (const HeldFrame& h : a.held) held.push_back({h.job, h.frame});
    workers.push_back({{"id", w.id},
                       {"host", w.host},
                       {"cores", w.cores},
                       {"memoryBytes", w.memoryBytes},
                       {"cacheBytes", w.cacheBytes},
                       {"registered", number(w.lastSeen)},
                       {"lastHeard", number(std::max(a.lastHeard, w.lastSeen))},
                       {"state", workerState(a, w.lastSeen, now, p.leaseSeconds)},
                       {"held", std::move(held)},
                       {"current", a.current},
                       {"progress", number(a.progress)},
                       {"tasksDone", a.tasksDone},
                       {"tasksFailed", a.tasksFailed},
                       {"cacheHits", a.cacheHits},
                       {"cacheMisses", a.cacheMisses},
                       {"treeBytesStreamed", a.treeBytesStreamed}});
  }
  return Json{{"now", number(now)}, {"workers", std::move(workers)}};
}

// The frame's preview: its tiles done so far (or the assembled frame).
absl::StatusOr<std::string> framePreview(const DashboardParts& p, int64_t job, int frame) {
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const ParsedJob> view, p.jobs.get(job));
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, p.store.tasks(job));
  std::vector<int> done;
  bool assembled = false;
  for (const TaskInfo& t : tasks) {
    if (t.ref.frame != frame || t.state != TaskState::kDone) continue;
    if (t.ref.kind == TaskKind::kTile) done.push_back(t.ref.tile);
    if (t.ref.kind == TaskKind::kAssemble) assembled = true;
  }
  return p.previews.frame(job, *view, p.jobs.workDir(job), frame, assembled, done);
}

void replyPng(httplib::Response& res, const absl::StatusOr<std::string>& png) {
  if (!png.ok()) return replyError(res, png.status());
  // The page asks with the frame's done-tile count in the address: a new count, a new URL.
  res.set_header("Cache-Control", "max-age=60");
  res.set_content(*png, "image/png");
}

// The farm token on a request that changes something; otherwise 401, counted.
bool authorized(const DashboardParts& p, const httplib::Request& req, httplib::Response& res) {
  if (bearsToken(req.get_header_value("Authorization"), p.token)) return true;
  p.refused.add();
  log::warn("dashboard: refused {} {} from {}: no farm token", req.method, req.path,
            req.remote_addr);
  replyError(res, absl::UnauthenticatedError(
                      "changing a job needs the farm token (Authorization: Bearer <token>)"));
  return false;
}

// One text/event-stream: a "data: <version>" event at once and after each change (bursts
// of changes coalesce: at most four events a second, each a page's reads of the store), a
// comment every 15 s otherwise so that proxies keep the connection.
void streamEvents(const DashboardParts& p, std::shared_ptr<std::atomic<int>> streams,
                  httplib::Response& res) {
  constexpr int kMaxStreams = 48;
  if (streams->fetch_add(1) >= kMaxStreams) {
    streams->fetch_sub(1);
    return replyError(res, absl::ResourceExhaustedError(fmt::format(
                               "{} pages already follow this coordinator", kMaxStreams)));
  }
  res.set_header("Cache-Control", "no-store");
  FarmActivity* activity = &p.activity;
  const milliseconds wait = p.sharedStore ? milliseconds(1000) : milliseconds(15000);
  const bool shared = p.sharedStore;
  auto seen = std::make_shared<uint64_t>(0);
  res.set_chunked_content_provider(
      "text/event-stream",
      [activity, wait, shared, seen](size_t, httplib::DataSink& sink) {
        std::string message;
        if (*seen == 0) {
          *seen = activity->version();
          message = fmt::format("retry: 1000\n\ndata: {}\n\n", *seen);
        } else {
          const uint64_t v = activity->waitForChange(*seen, wait);
          if (activity->stopped()) {
            sink.done();
            return true;
          }
          message = v != *seen || shared ? fmt::format("data: {}\n\n", v) : ": still here\n\n";
          *seen = v;
        }
        if (!sink.write(message.data(), message.size())) return false;
        std::this_thread::sleep_for(milliseconds(250));
        return true;
      },
      [streams](bool) { streams->fetch_sub(1); });
}

}  // namespace

// With --read-access token: every request bears the token (header or cookie), or brings it
// once in the query (?token=...), which sets the cookie and sends the browser on without it.
void requireTokenForReads(httplib::Server& http, const DashboardParts* p) {
  constexpr std::string_view kCookie = "pbgi_token=";
  http.set_pre_routing_handler([p, kCookie](const httplib::Request& req, httplib::Response& res) {
    using Handled = httplib::Server::HandlerResponse;
    if (bearsToken(req.get_header_value("Authorization"), p->token)) return Handled::Unhandled;
    const std::string cookies = req.get_header_value("Cookie");
    for (const absl::string_view c : absl::StrSplit(cookies, ';', absl::SkipWhitespace())) {
      const absl::string_view trimmed = absl::StripLeadingAsciiWhitespace(c);
      const std::string_view cookie(trimmed.data(), trimmed.size());
      if (cookie.starts_with(kCookie) && sameToken(cookie.substr(kCookie.size()), p->token)) {
        return Handled::Unhandled;
      }
    }
    if (req.has_param("token") && sameToken(req.get_param_value("token"), p->token)) {
      res.set_header("Set-Cookie",
                     fmt::format("{}{}; Path=/; HttpOnly; SameSite=Strict", kCookie, p->token));
      res.set_redirect(req.path);
      return Handled::Handled;
    }
    p->refused.add();
    log::warn("dashboard: refused {} {} from {}: no farm token (--read-access token)", req.method,
              req.path, req.remote_addr);
    replyError(res, absl::UnauthenticatedError(
                        "this coordinator's pages need the farm token: open /?token=TOKEN once, "
                        "or send Authorization: Bearer TOKEN"));
    return Handled::Handled;
  });
}

void addDashboard(httplib::Server& http, const DashboardParts& parts) {
  const DashboardParts* p = &parts;
  if (p->readsNeedToken) requireTokenForReads(http, p);
  // Each page holds one connection open for its event stream.
  http.new_task_queue = [] { return new httplib::ThreadPool(64); };
  // Small responses go out at once: with Nagle's algorithm each waited on the browser's
  // delayed ACK (about 40 ms a request, measured, on loopback).
  http.set_tcp_nodelay(true);
  for (const DashboardAsset& asset : dashboardAssets()) {
    const std::string route = asset.name == "index.html" ? "/" : "/" + std::string(asset.name);
    http.Get(route, [asset](const httplib::Request&, httplib::Response& res) {
      res.set_header("Cache-Control", "no-cache");
      res.set_content(std::string(asset.content), std::string(asset.contentType));
    });
  }
  http.Get("/api/jobs", [p](const httplib::Request&, httplib::Response& res) {
    auto jobs = p->store.jobs();
    if (!jobs.ok()) return replyError(res, jobs.status());
    const Seconds now = wallClock();
    Json list = Json::array();
    const std::vector<std::string> live = liveWorkers(p->store, p->activity, now, p->leaseSeconds);
    for (const JobInfo& j : *jobs) {
      auto audits = p->store.audits(j.id);
      if (!audits.ok()) return replyError(res, audits.status());
      auto stall = jobStall(p->store, j, live);
      if (!stall.ok()) return replyError(res, stall.status());
      list.push_back(jobSummaryJson(j, *audits, *stall, p->activity.durations(j.id), now));
    }
    replyJson(res, dump(Json{{"version", p->activity.version()},
                             {"now", number(now)},
                             {"jobs", std::move(list)}}));
  });
  http.Get(R"(/api/jobs/(\d+))", [p](const httplib::Request& req, httplib::Response& res) {
    auto json = jobDetailJson(*p, pathId(req), wallClock());
    if (!json.ok()) return replyError(res, json.status());
    replyJson(res, dump(*json));
  });
  http.Get(R"(/api/jobs/(\d+)/task)", [p](const httplib::Request& req, httplib::Response& res) {
    auto json = taskDetailJson(*p, pathId(req), req);
    if (!json.ok()) return replyError(res, json.status());
    replyJson(res, dump(*json));
  });
  http.Get(R"(/api/jobs/(\d+)/frames/(-?\d+)/preview\.png)",
           [p](const httplib::Request& req, httplib::Response& res) {
             replyPng(res, framePreview(*p, pathId(req), std::stoi(req.matches[2].str())));
           });
  http.Get(R"(/api/jobs/(\d+)/frames/(-?\d+)/tiles/(\d+)\.png)",
           [p](const httplib::Request& req, httplib::Response& res) {
             replyPng(res, p->previews.tile(p->jobs.workDir(pathId(req)),
                                            std::stoi(req.matches[2].str()),
                                            std::stoi(req.matches[3].str())));
           });
  http.Get("/api/workers", [p](const httplib::Request&, httplib::Response& res) {
    auto json = workersJson(*p, wallClock());
    if (!json.ok()) return replyError(res, json.status());
    replyJson(res, dump(*json));
  });
  auto streams = std::make_shared<std::atomic<int>>(0);
  http.Get("/api/events", [p, streams](const httplib::Request&, httplib::Response& res) {
    streamEvents(*p, streams, res);
  });
  http.Post(R"(/api/jobs/(\d+)/cancel)", [p](const httplib::Request& req, httplib::Response& res) {
    if (!authorized(*p, req, res)) return;
    const int64_t job = pathId(req);
    if (absl::Status s = p->store.cancel(job); !s.ok()) return replyError(res, s);
    p->activity.changed();
    log::info("dashboard: job {} cancelled by {}", job, req.remote_addr);
    replyJson(res, "{\"ok\":true}");
  });
  http.Post(R"(/api/jobs/(\d+)/retry)", [p](const httplib::Request& req, httplib::Response& res) {
    if (!authorized(*p, req, res)) return;
    const int64_t job = pathId(req);
    auto frame = intParam(req, "frame");
    auto tile = intParam(req, "tile");
    if (!frame.ok()) return replyError(res, frame.status());
    if (!tile.ok()) return replyError(res, tile.status());
    if (*tile && !*frame) {
      return replyError(res, absl::InvalidArgumentError("a tile to retry needs its frame"));
    }
    if (absl::Status s = p->store.retry(job, *frame, *tile, wallClock()); !s.ok()) {
      return replyError(res, s);
    }
    p->activity.changed();
    log::info("dashboard: job {}{}{} retried by {}", job,
              *frame ? fmt::format(" frame {}", **frame) : "",
              *tile ? fmt::format(" tile {}", **tile) : "", req.remote_addr);
    replyJson(res, "{\"ok\":true}");
  });
}

}  // namespace pbgi::farm
