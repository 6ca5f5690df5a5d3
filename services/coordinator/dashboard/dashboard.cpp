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

#include <fmt/format.h>
#include <httplib.h>

#include "core/util/log.h"
#include "core/util/status.h"
#include "services/coordinator/dashboard/dashboard_assets.h"
#include "services/coordinator/farm_auth.h"
#include "services/coordinator/lease_reaper.h"

namespace pbgi::farm {

std::string jsonString(std::string_view text) {
  std::string out = "\"";
  out.reserve(text.size() + 2);
  for (const char ch : text) {
    switch (ch) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (static_cast<unsigned char>(ch) < 0x20) {
          out += fmt::format("\\u{:04x}", static_cast<int>(ch));
        } else {
          out += ch;
        }
    }
  }
  return out + "\"";
}

namespace {

using std::chrono::milliseconds;

// A JSON number; NaN and infinities (which JSON lacks) are null.
std::string jsonNumber(double v) { return std::isfinite(v) ? fmt::format("{}", v) : "null"; }

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
  replyJson(res, fmt::format("{{\"error\":{}}}", jsonString(std::string_view(s.message().data(), s.message().size()))), status);
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

std::string taskJson(const TaskInfo& t) {
  return fmt::format(
      "{{\"id\":{},\"kind\":\"{}\",\"frame\":{},\"tile\":{},\"state\":\"{}\",\"attempt\":{},"
      "\"failures\":{},\"worker\":{},\"error\":{},\"progress\":{}}}",
      t.id, toString(t.ref.kind), t.ref.frame, t.ref.tile, toString(t.state), t.attempt,
      t.failures, jsonString(t.worker), jsonString(t.lastError), jsonNumber(t.progress));
}

std::string auditJson(const AuditInfo& a) {
  std::string tiles;
  for (const int t : a.spec.tiles) tiles += fmt::format("{}{}", tiles.empty() ? "" : ",", t);
  return fmt::format(
      "{{\"state\":\"{}\",\"tiles\":[{}],\"spp\":{},\"threshold\":{},\"relMse\":{},"
      "\"bias\":{},\"flagged\":{},\"worker\":{},\"error\":{}}}",
      toString(a.state), tiles, a.spec.spp, jsonNumber(a.spec.threshold),
      a.result ? jsonNumber(a.result->relMse) : "null",
      a.result ? jsonNumber(a.result->bias) : "null", a.flagged(), jsonString(a.worker),
      jsonString(a.lastError));
}

// A job as the list shows it: state, counts, progress and the time left at the rate so far,
// and how many of its frames' audits are done and flagged.
std::string jobSummaryJson(const JobInfo& job, const std::vector<AuditInfo>& audits,
                           Seconds now) {
  int audited = 0, flagged = 0;
  for (const AuditInfo& a : audits) {
    audited += a.result.has_value();
    flagged += a.flagged();
  }
  const int total = totalTasks(job);
  const int done = job.tasksByState[static_cast<int>(TaskState::kDone)];
  const double progress = total > 0 ? double(done) / total : 0.0;
  std::optional<double> eta;
  if (job.state == JobState::kActive && done > 0 && now > job.submitted) {
    eta = (now - job.submitted) * (total - done) / done;
  }
  std::string states;
  for (int s = 0; s < kTaskStateCount; ++s) {
    if (s > 0) states += ',';
    states += fmt::format("\"{}\":{}", toString(static_cast<TaskState>(s)), job.tasksByState[s]);
  }
  std::string frames;
  for (size_t i = 0; i < job.spec.frames.size(); ++i) {
    frames += fmt::format("{}{}", i ? "," : "", job.spec.frames[i]);
  }
  // Every dead task of a large job would be megabytes: the first few, and how many.
  std::string dead;
  for (size_t i = 0; i < job.dead.size() && i < 20; ++i) {
    dead += (i ? "," : "") + taskJson(job.dead[i]);
  }
  return fmt::format(
      "{{\"id\":{},\"name\":{},\"state\":\"{}\",\"priority\":{},\"submitted\":{},\"frames\":[{}],"
      "\"tilesPerFrame\":{},\"tasks\":{{{}}},\"total\":{},\"done\":{},\"progress\":{},\"eta\":{},"
      "\"output\":{},\"deadCount\":{},\"dead\":[{}],\"audits\":{},\"audited\":{},"
      "\"flagged\":{}}}",
      job.id, jsonString(job.spec.name), toString(job.state), job.spec.priority,
      jsonNumber(job.submitted), frames, job.spec.tileCount, states, total, done,
      jsonNumber(progress), eta ? jsonNumber(*eta) : "null", jsonString(job.spec.outputPattern),
      job.dead.size(), dead, audits.size(), audited, flagged);
}

// One job's frames: per frame its bake's and assemble's state and its tiles' states as one
// string of digits (TaskState numbers, tile order), with where each tile lies in the view's
// grid of tiles; and the tasks leased now. 4,096 tiles make about 40 kB.
absl::StatusOr<std::string> jobDetailJson(const DashboardParts& p, int64_t id, Seconds now) {
  PBGI_ASSIGN_OR_RETURN(const JobInfo info, p.store.job(id));
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const JobView> view, p.jobs.get(id));
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, p.store.tasks(id));
  PBGI_ASSIGN_OR_RETURN(const std::vector<AuditInfo> audits, p.store.audits(id));
  const int tileSize = p.jobs.tileSize();
  const int cols = (view->shot.width + tileSize - 1) / tileSize;
  const int rows = (view->shot.height + tileSize - 1) / tileSize;
  std::string cells;
  for (size_t t = 0; t < view->tiles.size(); ++t) {
    const TileRect r = view->tiles[t].empty() ? TileRect{} : view->tiles[t].front();
    const int col = (r.x0 % std::max(view->shot.width, 1)) / tileSize;
    const int row = (r.y0 % std::max(view->shot.height, 1)) / tileSize;
    cells += fmt::format("{}{},{}", t ? "," : "", col, row);
  }
  struct Frame {
    char bake = 0, assemble = 0;
    std::string tiles;
    int done = 0;
    std::string audit = "null";
  };
  std::map<int, Frame> frames;
  for (const int f : info.spec.frames) {
    frames[f].tiles.assign(static_cast<size_t>(info.spec.tileCount), '0');
  }
  for (const AuditInfo& a : audits) {
    if (auto it = frames.find(a.spec.frame); it != frames.end()) it->second.audit = auditJson(a);
  }
  std::string leased;
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
    if (t.state == TaskState::kLeased) leased += (leased.empty() ? "" : ",") + taskJson(t);
  }
  std::string framesJson;
  for (const auto& [f, fr] : frames) {
    const auto code = [](char c) { return c ? fmt::format("\"{}\"", c) : std::string("null"); };
    framesJson += fmt::format(
        "{}{{\"frame\":{},\"bake\":{},\"assemble\":{},\"tiles\":\"{}\",\"done\":{},"
        "\"output\":{},\"audit\":{}}}",
        framesJson.empty() ? "" : ",", f, code(fr.bake), code(fr.assemble), fr.tiles, fr.done,
        jsonString(JobViews::frameOutput(*view, f)), fr.audit);
  }
  return fmt::format(
      "{{\"job\":{},\"tileSize\":{},\"width\":{},\"height\":{},\"views\":[{},{}],\"cols\":{},"
      "\"rows\":{},\"cells\":[{}],\"frames\":[{}],\"leased\":[{}]}}",
      jobSummaryJson(info, audits, now), tileSize, view->shot.width, view->shot.height,
      view->shot.camera.views.x, view->shot.camera.views.y, cols, rows, cells, framesJson, leased);
}

absl::StatusOr<std::string> taskDetailJson(const DashboardParts& p, int64_t job,
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
  std::string eventsJson;
  for (const TaskEvent& e : events) {
    if (e.task != it->id) continue;
    eventsJson += fmt::format(
        "{}{{\"time\":{},\"attempt\":{},\"worker\":{},\"event\":{},\"text\":{}}}",
        eventsJson.empty() ? "" : ",", jsonNumber(e.time), e.attempt, jsonString(e.worker),
        jsonString(e.event), jsonString(e.text));
  }
  return fmt::format("{{\"task\":{},\"events\":[{}]}}", taskJson(*it), eventsJson);
}

absl::StatusOr<std::string> workersJson(const DashboardParts& p, Seconds now) {
  PBGI_ASSIGN_OR_RETURN(const std::vector<WorkerInfo> registered, p.store.workers());
  const std::map<std::string, WorkerActivity> seen = p.activity.workers();
  std::string out;
  for (const WorkerInfo& w : registered) {
    const auto it = seen.find(w.id);
    const WorkerActivity a = it == seen.end() ? WorkerActivity{} : it->second;
    std::string held;
    for (const HeldFrame& h : a.held) {
      held += fmt::format("{}[{},{}]", held.empty() ? "" : ",", h.job, h.frame);
    }
    out += fmt::format(
        "{}{{\"id\":{},\"host\":{},\"cores\":{},\"memoryBytes\":{},\"cacheBytes\":{},"
        "\"registered\":{},\"lastHeard\":{},\"held\":[{}],\"current\":{},\"progress\":{},"
        "\"tasksDone\":{},\"tasksFailed\":{},\"cacheHits\":{},\"cacheMisses\":{},"
        "\"treeBytesStreamed\":{}}}",
        out.empty() ? "" : ",", jsonString(w.id), jsonString(w.host), w.cores, w.memoryBytes,
        w.cacheBytes, jsonNumber(w.lastSeen), jsonNumber(std::max(a.lastHeard, w.lastSeen)),
        held, jsonString(a.current), jsonNumber(a.progress), a.tasksDone, a.tasksFailed, a.cacheHits,
        a.cacheMisses, a.treeBytesStreamed);
  }
  return fmt::format("{{\"now\":{},\"workers\":[{}]}}", jsonNumber(now), out);
}

// The frame's preview: its tiles done so far (or the assembled frame).
absl::StatusOr<std::string> framePreview(const DashboardParts& p, int64_t job, int frame) {
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const JobView> view, p.jobs.get(job));
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

void addDashboard(httplib::Server& http, const DashboardParts& parts) {
  const DashboardParts* p = &parts;
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
    std::string list;
    for (const JobInfo& j : *jobs) {
      auto audits = p->store.audits(j.id);
      if (!audits.ok()) return replyError(res, audits.status());
      list += (list.empty() ? "" : ",") + jobSummaryJson(j, *audits, now);
    }
    replyJson(res, fmt::format("{{\"version\":{},\"now\":{},\"jobs\":[{}]}}",
                               p->activity.version(), jsonNumber(now), list));
  });
  http.Get(R"(/api/jobs/(\d+))", [p](const httplib::Request& req, httplib::Response& res) {
    auto json = jobDetailJson(*p, pathId(req), wallClock());
    if (!json.ok()) return replyError(res, json.status());
    replyJson(res, *std::move(json));
  });
  http.Get(R"(/api/jobs/(\d+)/task)", [p](const httplib::Request& req, httplib::Response& res) {
    auto json = taskDetailJson(*p, pathId(req), req);
    if (!json.ok()) return replyError(res, json.status());
    replyJson(res, *std::move(json));
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
    replyJson(res, *std::move(json));
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
