// The pbgi farm dashboard: reads the coordinator's JSON API (services/coordinator/dashboard/dashboard.h)
// and draws it; refreshes whenever the event stream says something changed. No framework and
// no build step: this file is served as written.
'use strict';

const STATES = ['blocked', 'ready', 'leased', 'done', 'dead', 'cancelled'];
const COLOURS = {};
const view = {
  jobs: [], workers: [], job: null, selectedJob: null, task: null, // {frame, tile, kind}
  refreshing: false, again: false, ready: false,
};

const $ = (id) => document.getElementById(id);
function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(props)) {
    if (k === 'class') e.className = v;
    else if (k === 'dataset') Object.assign(e.dataset, v);
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return e;
}

function duration(seconds) {
  if (seconds == null || !isFinite(seconds)) return '';
  seconds = Math.round(seconds);
  if (seconds < 60) return `${seconds} s`;
  const m = Math.floor(seconds / 60), s = seconds % 60;
  if (m < 60) return `${m} min ${s} s`;
  return `${Math.floor(m / 60)} h ${m % 60} min`;
}
function bytes(n) {
  if (n >= 1 << 30) return `${(n / (1 << 30)).toFixed(1)} GiB`;
  if (n >= 1 << 20) return `${(n / (1 << 20)).toFixed(0)} MiB`;
  return `${(n / 1024).toFixed(0)} KiB`;
}

function say(text, ok = false) {
  const m = $('message');
  m.textContent = text;
  m.className = ok ? 'ok' : '';
  m.hidden = !text;
}

async function getJson(url) {
  const r = await fetch(url, {cache: 'no-store'});
  const body = await r.json().catch(() => ({error: `${url}: HTTP ${r.status}`}));
  if (!r.ok) throw new Error(body.error || `${url}: HTTP ${r.status}`);
  return body;
}

// A change to a job: needs the farm token, which the page keeps for this tab only.
async function act(url, what) {
  const token = $('token').value.trim();
  if (!token) {
    say(`${what}: type the farm token first (top right).`);
    return;
  }
  sessionStorage.setItem('pbgi-token', token);
  const r = await fetch(url, {method: 'POST', headers: {Authorization: `Bearer ${token}`}});
  const body = await r.json().catch(() => ({}));
  if (!r.ok) say(`${what} refused: ${body.error || `HTTP ${r.status}`}`);
  else say(`${what}: done.`, true);
  refresh();
}

// ---- jobs ----
function renderJobs() {
  const body = $('jobs').tBodies[0];
  body.replaceChildren();
  $('no-jobs').hidden = view.jobs.length > 0;
  for (const j of view.jobs) {
    const actions = el('td');
    // Stalled and waiting jobs are active ones that cannot go on (the store keeps them active).
    const running = j.state === 'active' || j.state === 'stalled' || j.state === 'waiting';
    if (running) {
      actions.append(el('button', {type: 'button', class: 'cancel',
        onclick: (e) => { e.stopPropagation(); act(`api/jobs/${j.id}/cancel`, `Cancel job ${j.id}`); }},
      'Cancel'));
    }
    if (j.state === 'failed' || j.state === 'cancelled' || j.state === 'stalled') {
      actions.append(el('button', {type: 'button', class: 'retry',
        onclick: (e) => { e.stopPropagation(); act(`api/jobs/${j.id}/retry`, `Retry job ${j.id}`); }},
      'Retry'));
    }
    const bar = el('span', {class: 'bar'}, el('span', {style: `width:${(j.progress * 100).toFixed(1)}%`}));
    const row = el(
        'tr', {
          dataset: {job: j.id, state: j.state},
          class: j.id === view.selectedJob ? 'selected' : '',
          onclick: () => selectJob(j.id)
        },
        el('td', {}, j.id), el('td', {}, j.name),
        el('td', {}, el('span', {class: `state ${j.state}`}, j.state),
           j.deadCount ? ` ${j.deadCount} dead` : '',
           j.state === 'stalled' ?
               el('span', {class: 'stall'},
                  ` no live worker may take its tasks; blocklisted: ` +
                      `${j.blocklisted.join(', ')}${
                          j.stallError ? `; last error: ${j.stallError}` : ''}`) :
                                         '',
           j.flagged ? el('span', {class: 'flag'}, ` ${j.flagged} frame(s) flagged by the audit`) :
                                                 ''),
                                  el('td', {}, bar, `${j.done} / ${j.total}`), el('td', {}, running ? duration(j.eta) : ''),
        el('td', {}, j.priority), actions);
    body.append(row);
  }
}

function selectJob(id) {
  if (view.selectedJob !== id) view.task = null;
  view.selectedJob = id;
  history.replaceState(null, '', `#job=${id}`);
  refresh();
}

// ---- one job's frames ----
function cellSize(job) {
  return Math.max(2, Math.min(18, Math.floor(256 / Math.max(job.cols, job.rows, 1))));
}

function drawGrid(canvas, job, frame) {
  const size = cellSize(job);
  canvas.width = job.cols * size;
  canvas.height = job.rows * size;
  const g = canvas.getContext('2d');
  g.fillStyle = '#101216';
  g.fillRect(0, 0, canvas.width, canvas.height);
  const gap = size >= 6 ? 1 : 0;
  for (let t = 0; t < frame.tiles.length; ++t) {
    g.fillStyle = COLOURS[STATES[frame.tiles.charCodeAt(t) - 48]];
    g.fillRect(job.cells[2 * t] * size, job.cells[2 * t + 1] * size, size - gap, size - gap);
  }
  canvas.dataset.states = frame.tiles;
}

function tileAt(job, canvas, event) {
  const size = cellSize(job);
  const r = canvas.getBoundingClientRect();
  const col = Math.floor((event.clientX - r.left) * canvas.width / r.width / size);
  const row = Math.floor((event.clientY - r.top) * canvas.height / r.height / size);
  for (let t = 0; t < job.cells.length / 2; ++t) {
    if (job.cells[2 * t] === col && job.cells[2 * t + 1] === row) return t;
  }
  return -1;
}

function renderJob() {
  const job = view.job;
  $('job-section').hidden = !job;
  if (!job) return;
  const s = job.job;
  $('job-title').textContent = `Job ${s.id}: ${s.name}`;
  $('job-summary').textContent =
    `${s.state}; ${s.done} of ${s.total} tasks done` +
    (s.state === 'active' && s.eta != null ? `, about ${duration(s.eta)} left` : '') +
    `; ${job.frames.length} frame(s) of ${s.tilesPerFrame} tiles (${job.width}x${job.height}` +
    `${job.views[0] * job.views[1] > 1 ? `, ${job.views[0]}x${job.views[1]} views` : ''}, ` +
    `tiles of ${job.tileSize} px); output ${s.output}`;
  const frames = $('frames');
  const existing = new Map([...frames.children].map((f) => [f.dataset.frame, f]));
  frames.replaceChildren();
  for (const f of job.frames) {
    let fig = existing.get(String(f.frame));
    if (!fig) {
      const canvas = el('canvas', {class: 'grid', title: 'click a tile for its history'});
      canvas.addEventListener('click', (e) => {
        const t = tileAt(view.job, canvas, e);
        if (t >= 0) selectTask(Number(fig.dataset.frame), t, 'tile');
      });
      const preview = el('img', {class: 'preview', alt: `frame ${f.frame} so far`, hidden: '',
        title: 'click for full size'});
      preview.addEventListener('click', () => openFull(preview,
        `job ${view.job.job.id} frame ${preview.closest('figure').dataset.frame}`));
      fig = el('figure', {class: 'frame', dataset: {frame: f.frame}},
        el('figcaption'), el('div', {class: 'pictures'}, canvas, preview));
    }
    const caption = fig.querySelector('figcaption');
    caption.replaceChildren(`frame ${f.frame}: ${f.done} / ${f.tiles.length} tiles`);
    for (const kind of ['bake', 'assemble']) {
      if (f[kind] == null) continue;
      caption.append(' ', el('button', {type: 'button', class: `task-${kind}`,
        style: `border-color:${COLOURS[STATES[Number(f[kind])]]}`,
        onclick: () => selectTask(f.frame, -1, kind)}, `${kind}: ${STATES[Number(f[kind])]}`));
    }
    const a = f.audit;
    fig.dataset.audit = a ? (a.relMse != null ? (a.flagged ? 'flagged' : 'ok') : a.state) : 'none';
    if (a) {
      const text = a.relMse != null
        ? `audit: relMSE ${a.relMse.toPrecision(3)}, bias ${(100 * a.bias).toFixed(1)} % ` +
          `(path ${a.spp} spp, ${a.tiles.length} tiles)` + (a.flagged ? ` FLAGGED > ${a.threshold}` : '')
        : `audit ${a.state}${a.error ? `: ${a.error}` : ''}`;
      caption.append(el('div', {class: `audit ${fig.dataset.audit}`,
        title: `tiles ${a.tiles.join(', ')} path traced and compared with this frame`}, text));
    }
    fig.dataset.done = f.done;
    fig.dataset.assembled = f.assemble === '3' ? '1' : '0';
    drawGrid(fig.querySelector('canvas'), job, f);
    const img = fig.querySelector('img');
    const version = f.done + (f.assemble === '3' ? 1000000 : 0);
    if (f.done > 0 && img.dataset.version !== String(version)) {
      img.dataset.version = String(version);
      img.hidden = false;
      img.src = `api/jobs/${s.id}/frames/${f.frame}/preview.png?v=${version}`;
    }
    frames.append(fig);
  }
}

// A preview at its full size (one image pixel per screen pixel), in a dialog that scrolls
// when the frame is larger than the window; a click or Escape closes it.
function openFull(img, what) {
  const box = $('lightbox');
  const full = $('lightbox-img');
  full.src = img.src;
  $('lightbox-caption').textContent = `${what} (${img.naturalWidth} x ${img.naturalHeight})`;
  if (!box.open) box.showModal();
}

// ---- one task ----
function selectTask(frame, tile, kind) {
  view.task = {frame, tile, kind};
  refresh();
}

function renderTask(detail) {
  $('task-section').hidden = !detail;
  if (!detail) return;
  const t = detail.task;
  const where = t.kind === 'tile' ? `frame ${t.frame} tile ${t.tile}` : `frame ${t.frame} ${t.kind}`;
  $('task-title').textContent = `Job ${view.selectedJob}, ${where}`;
  const info = $('task-info');
  info.replaceChildren();
  const add = (k, v) => { if (v !== '' && v != null) info.append(el('dt', {}, k), el('dd', {}, v)); };
  add('State', t.state);
  add('Attempt', `${t.attempt} (${t.failures} failed)`);
  add('Worker', t.worker);
  if (t.state === 'leased') add('Progress', `${Math.round(t.progress * 100)} %`);
  add('Last error', t.error);
  $('task-section').dataset.state = t.state;
  const retry = $('task-retry');
  retry.hidden = !(t.state === 'dead' || t.state === 'cancelled');
  retry.onclick = () => act(`api/jobs/${view.selectedJob}/retry?frame=${t.frame}` +
    (t.kind === 'tile' ? `&tile=${t.tile}` : ''), `Retry ${where}`);
  const img = $('task-tile');
  if (t.kind === 'tile' && t.state === 'done') {
    const src = `api/jobs/${view.selectedJob}/frames/${t.frame}/tiles/${t.tile}.png?a=${t.attempt}`;
    if (img.getAttribute('src') !== src) img.src = src;
    img.hidden = false;
  } else {
    img.hidden = true;
  }
  const body = $('task-events').tBodies[0];
  body.replaceChildren();
  for (const e of detail.events) {
    body.append(el('tr', {}, el('td', {}, new Date(e.time * 1000).toLocaleTimeString()),
      el('td', {}, e.attempt), el('td', {}, e.worker), el('td', {}, e.event), el('td', {}, e.text)));
  }
}

// ---- workers ----
function renderWorkers(now) {
  const body = $('workers').tBodies[0];
  body.replaceChildren();
  $('no-workers').hidden = view.workers.length > 0;
  for (const w of view.workers) {
    // A lost worker (silent past a lease while it held a task) is no longer working on it.
    const doing = w.state === 'lost' ? (w.current ? `nothing: lost while on ${w.current}`
                                                  : 'nothing: lost; its task went back to the queue') :
        w.state === 'offline' ? 'nothing: offline' :
        w.current             ? `${w.current} (${Math.round(w.progress * 100)} %)` :
                                'idle';
    const held = w.held.map(([j, f]) => `job ${j} frame ${f}`).join(', ');
    const lookups = w.cacheHits + w.cacheMisses;
    body.append(
        el('tr', {dataset: {worker: w.id, state: w.state}},
           el('td', {}, w.id, ' ', el('span', {class: `state ${w.state}`}, w.state)),
           el('td', {}, w.host), el('td', {}, w.cores), el('td', {}, bytes(w.memoryBytes)),
           // 0: the worker was given no budget, so each job's cache_mb sets it.
           el('td', {}, w.cacheBytes ? bytes(w.cacheBytes) : 'each job\'s cache_mb'),
           el('td', {}, `${duration(Math.max(0, now - w.lastHeard))} ago`), el('td', {}, doing),
           el('td', {}, held), el('td', {}, `${w.tasksDone} / ${w.tasksFailed}`),
           el('td', {}, lookups ? `${(100 * w.cacheHits / lookups).toFixed(1)} %` : '')));
  }
}

// ---- refresh ----
async function refresh() {
  if (view.refreshing) {
    view.again = true;
    return;
  }
  view.refreshing = true;
  try {
    // The selected job's frames and task come in the same round trip as the lists.
    const selected = () => Promise.all([
      view.selectedJob != null ? getJson(`api/jobs/${view.selectedJob}`) : null,
      view.selectedJob != null && view.task
        ? getJson(`api/jobs/${view.selectedJob}/task?frame=${view.task.frame}` +
                  `&tile=${view.task.tile}&kind=${view.task.kind}`) : null]);
    const chosen = view.selectedJob;
    let [jobs, workers, [job, task]] =
      await Promise.all([getJson('api/jobs'), getJson('api/workers'), selected()]);
    view.jobs = jobs.jobs;
    view.workers = workers.workers;
    if (view.selectedJob == null && view.jobs.length) {
      const active = view.jobs.find(
          (j) => j.state !== 'done' && j.state !== 'failed' && j.state !== 'cancelled');
      view.selectedJob = (active || view.jobs[view.jobs.length - 1]).id;
    }
    if (view.selectedJob !== chosen) [job, task] = await selected();
    view.job = job;
    renderJobs();
    renderJob();
    renderTask(task);
    renderWorkers(workers.now);
    if (!view.ready) {
      view.ready = true;
      window.pbgiLoadMs = performance.now();
      document.body.dataset.ready = '1';
    }
    document.body.dataset.version = String(jobs.version);
  } catch (e) {
    say(String(e.message || e));
  } finally {
    view.refreshing = false;
    if (view.again) {
      view.again = false;
      setTimeout(refresh, 50);
    }
  }
}

function follow() {
  const live = $('live');
  const events = new EventSource('api/events');
  let poll = null;
  events.onopen = () => {
    live.textContent = 'live';
    live.className = 'live on';
    clearInterval(poll);
    poll = null;
  };
  events.onmessage = () => refresh();
  events.onerror = () => {
    live.textContent = 'reconnecting';
    live.className = 'live off';
    if (!poll) poll = setInterval(refresh, 2000);
  };
}

function start() {
  const styles = getComputedStyle(document.documentElement);
  for (const s of STATES) COLOURS[s] = styles.getPropertyValue(`--${s}`).trim();
  $('legend').replaceChildren(...STATES.map((s) => el('li', {style: `--c:${COLOURS[s]}`}, s)));
  $('token').value = sessionStorage.getItem('pbgi-token') || '';
  const fromHash = () => {
    const m = /job=(\d+)/.exec(location.hash);
    return m ? Number(m[1]) : null;
  };
  view.selectedJob = fromHash();
  window.addEventListener('hashchange', () => { if (fromHash() != null) selectJob(fromHash()); });
  $('lightbox').addEventListener('click', () => $('lightbox').close());
  refresh();
  follow();
  // Time alone moves some things (a worker silent past its lease is lost): look again now and
  // then, even when nothing has changed in the store.
  setInterval(refresh, 5000);
}

document.addEventListener('DOMContentLoaded', start);
