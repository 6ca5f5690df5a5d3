#pragma once
// The farm's web page, served by the coordinator's HTTP listener (--http) beside /metrics:
// jobs with their progress and ETA, a job's frames as grids of tiles coloured by task state
// with each frame's accuracy audit (relMSE and bias against the path tracer, flagged beyond
// its threshold),
// a task's history and logs, the workers, previews of frames as their tiles land, and cancel
// and retry. The page (services/coordinator/dashboard/) is compiled into the binary; it reads
// the JSON API below and refreshes when the server-sent event stream says something changed.
//
//   GET  /                               the page (and /dashboard.js, /dashboard.css)
//   GET  /api/jobs                       every job: state, tasks by state, progress, ETA
//   GET  /api/jobs/J                     one job: per frame its tiles' states as one string
//   GET  /api/jobs/J/task?frame=F&tile=T&kind=K   a task and its events (history, logs)
//   GET  /api/jobs/J/frames/F/preview.png   the frame so far (assembled, or its done tiles)
//   GET  /api/jobs/J/frames/F/tiles/T.png   one done tile
//   GET  /api/workers                    workers: cores, memory, frames held, current task
//   GET  /api/events                     text/event-stream: "data: {version}" on each change
//   POST /api/jobs/J/cancel              needs "Authorization: Bearer <farm token>"
//   POST /api/jobs/J/retry?frame=F&tile=T   likewise; dead and cancelled tasks run again
//
// Reading is open to whoever reaches the HTTP port, as /metrics and /status are, unless the
// coordinator runs with --read-access token (DashboardParts::readsNeedToken), the same policy
// as its gRPC reads. Changing a job needs the farm token in the Authorization header, like
// every gRPC call (a cookie never does: refusals are counted with theirs).
#include <string>

#include "services/coordinator/dashboard/frame_previews.h"
#include "services/coordinator/farm_activity.h"
#include "services/coordinator/metrics.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/job_store/job_store.h"

namespace httplib {
class Server;
}

namespace pbgi::farm {

struct DashboardParts {
  JobStore& store;
  ParsedJobCache& jobs;
  FarmActivity& activity;
  FramePreviews& previews;
  metrics::Counter& refused;
  std::string token;
  // The store is shared with other coordinators (PostgreSQL): their changes move no version
  // here, so event streams look again every second.
  bool sharedStore = false;
  // A worker not heard from for longer than a lease is not live (a job whose only live
  // workers are blocklisted is stalled).
  Seconds leaseSeconds = 30;
  // Every request (the page, the API, /status, /metrics) needs the token: the Authorization
  // header, or the cookie the page gets when opened once at /?token=TOKEN.
  bool readsNeedToken = false;
};

// Adds the page, its files and the API to `http`. The parts outlive the server.
void addDashboard(httplib::Server& http, const DashboardParts& parts);

}  // namespace pbgi::farm
