// End to end in headless Chromium: a real coordinator (--http) and a real worker render a job
// while the dashboard shows it. The page loads; the frames' tile grids fill as tiles finish;
// a tile that cannot be written goes dead and shows its error, and its one worker, now
// blocklisted for the job, leaves the job stalled, which the page says with the error and the
// worker; a Retry click (with the farm token) revives it and the job completes; a preview
// opens at full size; a worker killed mid-tile shows as lost, and its task goes back; a cancel
// from the command line reaches the page.
// Prints what a user waits for: the page's load time for a job of 4,096 tiles, and how long a
// change takes to show. Times are reported, never asserted (these machines are noisy).
import {spawn, execFileSync} from 'node:child_process';
import {createRequire} from 'node:module';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';

const require = createRequire(`${process.env.PBGI_BROWSER_MODULES}/`);
const {chromium} = require('playwright-core');

const bin = (name) => path.join(process.env.PBGI_BIN_DIR, name);
const source = process.env.PBGI_SOURCE_DIR;
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'pbgi-dashboard-'));
const token = 'dashboard-test-token';
const children = [];
let browser = null;

function check(condition, message) {
  if (!condition) throw new Error(message);
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function waitFor(what, probe, seconds = 60) {
  const end = Date.now() + seconds * 1000;
  for (;;) {
    const value = await probe();
    if (value) return value;
    if (Date.now() > end) throw new Error(`timed out after ${seconds} s waiting for ${what}`);
    await sleep(50);
  }
}
function logs() {
  return fs.readdirSync(dir).filter((f) => f.endsWith('.log'))
    .map((f) => `--- ${f}\n${fs.readFileSync(path.join(dir, f), 'utf8').slice(-3000)}`).join('\n');
}
function start(name, argv) {
  const out = fs.openSync(path.join(dir, `${name}.log`), 'a');
  const child = spawn(argv[0], argv.slice(1), {stdio: ['ignore', out, out],
    env: {...process.env, PBGI_TOKEN: token}});
  children.push(child);
  return child;
}
function pbgi(...args) {
  return execFileSync(bin('pbgi'), args, {env: {...process.env, PBGI_TOKEN: token}}).toString().trim();
}
async function freePort() {
  return new Promise((resolve) => {
    const s = net.createServer();
    s.listen(0, '127.0.0.1', () => {
      const {port} = s.address();
      s.close(() => resolve(port));
    });
  });
}
// The sample Cornell box, small, path traced: `spp` sets how long its tiles take.
function writeShot(name, {width, height, frames, spp}) {
  let text = fs.readFileSync(path.join(source, 'config/scenes/cornell/cornell.shot.toml'), 'utf8');
  const set = (pattern, value) => {
    check(pattern.test(text), `the sample shot has no ${pattern}`);
    text = text.replace(pattern, value);
  };
  set(/frames = \[1, 3\]/, `frames = [${frames[0]}, ${frames[1]}]`);
  set(/resolution = \[256, 256\]/, `resolution = [${width}, ${height}]`);
  set(/output = "[^"]*"/, `output = "${path.join(dir, 'out', name)}.####.exr"`);
  set(/file = "cornell_box.obj"/,
    `file = "${path.join(source, 'config/scenes/cornell/cornell_box.obj')}"`);
  set(/integrator = "[a-z]+"[^\n]*/, 'integrator = "path"');
  for (const key of ['gather', 'quality', 'bake_points']) text = text.replace(new RegExp(`\n${key} = [^\n]*`), '');
  set(/spp = 16/, `spp = ${spp}`);
  const file = path.join(dir, `${name}.shot.toml`);
  fs.writeFileSync(file, text);
  return file;
}

// What the page shows: per frame its tiles' states, and the jobs' states.
async function pageState(page) {
  return page.evaluate(() => ({
    frames: [...document.querySelectorAll('#frames figure')].map((f) => ({
      frame: Number(f.dataset.frame), states: f.querySelector('canvas').dataset.states || '',
      previewLoaded: (() => { const i = f.querySelector('img.preview');
        return !i.hidden && i.complete && i.naturalWidth > 0; })()})),
    jobs: Object.fromEntries([...document.querySelectorAll('#jobs tbody tr')]
      .map((r) => [r.dataset.job, r.dataset.state])),
  }));
}
const count = (states, digit) => [...states].filter((c) => c === digit).length;

async function main() {
  const httpPort = await freePort();
  const state = path.join(dir, 'state');
  fs.writeFileSync(path.join(dir, 'token'), `${token}\n`);
  start('coordinator', [bin('pbgi-coordinator'), '--state', state, '--listen', '127.0.0.1:0',
    '--http', `127.0.0.1:${httpPort}`, '--token-file', path.join(dir, 'token'),
    '--output-root', dir, '--tile-size', '16', '--max-attempts', '1', '--backoff-base', '0',
    '--blocklist-after', '1',
    '--lease-seconds', '5', '--expiry-interval', '0.2']);
  const addressFile = path.join(state, 'coordinator.addr');
  const address = await waitFor('the coordinator', () =>
    fs.existsSync(addressFile) && fs.readFileSync(addressFile, 'utf8').trim(), 30);
  const url = `http://127.0.0.1:${httpPort}/`;

  // Job 1: 2 frames of 8x8 tiles. Frame 1's tile 2 cannot be written (a folder stands where its
  // file goes), so it dies at its first failure.
  const shot = writeShot('small', {width: 128, height: 128, frames: [1, 2], spp: 64});
  const job = Number(pbgi('submit', shot, '--coordinator', address));
  check(job === 1, `the first job is job 1, not ${job}`);
  const blocked = path.join(state, 'jobs', '1', 'frame.0001', 'tile.0002.exr');
  fs.mkdirSync(path.join(blocked, 'keep'), {recursive: true});

  browser = await chromium.launch({executablePath: process.env.PBGI_CHROMIUM || '/usr/bin/chromium',
    args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync']});
  const page = await browser.newPage({viewport: {width: 1400, height: 1000}});
  const consoleErrors = [];
  // The wrong token below is refused on purpose (401); any other error is the page's fault.
  page.on('console', (m) => {
    if (m.type() === 'error' && !m.text().includes('401')) consoleErrors.push(m.text());
  });
  page.on('pageerror', (e) => consoleErrors.push(String(e)));
  await page.goto(`${url}#job=1`);
  await page.waitForSelector('body[data-ready="1"]');
  let s = await pageState(page);
  // Active in the store, but no worker has called yet: it waits for one.
  check(s.jobs['1'] === 'waiting', `job 1 shows as ${s.jobs['1']}`);
  check(s.frames.length === 2 && s.frames.every((f) => f.states === '1'.repeat(64)),
    `before any worker, both frames show 64 ready tiles: ${JSON.stringify(s.frames)}`);
  await page.waitForSelector('#live.on');

  // The grid fills while the worker renders: seen part done, then settled.
  start('worker', [bin('pbgi-worker'), '--coordinator', address, '--id', 'w1', '--threads', '1',
    '--poll-seconds', '0.05', '--cache-dir', path.join(dir, 'cache')]);
  const seenDone = new Set();
  const watch = async () => {
    s = await pageState(page);
    for (const f of s.frames) seenDone.add(count(f.states, '3'));
    return s;
  };
  // Frame 1's tile 2 dies at its first failure, which blocklists w1, the only worker, for the
  // job: its other tiles are ready and nobody may take them. The page says stalled, and why.
  // The jobs table and the grid refresh from their own requests: wait until both have shown it.
  const frameOne = (st) => st.frames.find((f) => f.frame === 1).states;
  await waitFor('job 1 to stall on the page, its tile 2 dead in the grid', async () => {
    const st = await watch();
    return st.jobs['1'] === 'stalled' && frameOne(st)[2] === '4';
  }, 180);
  const f1 = frameOne(s);
  check(f1[2] === '4', `frame 1: tile 2 dead: ${f1}`);
  const stalledRow = await page.textContent('#jobs tbody tr[data-job="1"]');
  check(stalledRow.includes('blocklisted: w1') && stalledRow.includes('tile.0002.exr'),
    `the stalled job names the blocklisted worker and the last error: ${stalledRow}`);

  // The dead tile: click it, read why, then retry it once its folder is gone.
  const detail = await page.evaluate(() => fetch('api/jobs/1').then((r) => r.json()));
  const canvas = page.locator('#frames figure[data-frame="1"] canvas');
  const box = await canvas.boundingBox();
  const cell = box.width / detail.cols;
  await canvas.click({position: {x: (detail.cells[4] + 0.5) * cell, y: (detail.cells[5] + 0.5) * cell}});
  await page.waitForSelector('#task-section[data-state="dead"]');
  const info = await page.textContent('#task-info');
  check(info.includes('tile.0002.exr'), `the dead tile's panel names its file: ${info}`);
  check(await page.isVisible('#task-retry'), 'a dead tile offers Retry');
  fs.rmSync(blocked, {recursive: true});
  await page.fill('#token', '');
  await page.click('#task-retry');
  await page.waitForSelector('#message:not([hidden])');
  check((await page.textContent('#message')).includes('token'), 'Retry without the token asks for it');
  await page.fill('#token', 'not-the-token');
  await page.click('#task-retry');
  await waitFor('the refusal', async () => (await page.textContent('#message')).includes('refused'), 10);
  check(await page.evaluate(() => fetch('api/jobs/1').then((r) => r.json()).then((j) => j.job.state))
    === 'stalled', 'a wrong token changed nothing');
  await page.fill('#token', token);
  await page.click('#task-retry');
  // The retry lifts the blocklist: w1 takes the job's tiles again, and the grids fill live.
  await waitFor('job 1 done after the retry', async () => (await watch()).jobs['1'] === 'done', 180);
  const partial = [...seenDone].filter((n) => n > 0 && n < 63);
  check(partial.length > 0, `the grid never showed a partly done frame: done counts ${[...seenDone]}`);
  console.log(`grid filled live: ${partial.length} part-done views of a frame seen`);
  check(s.frames.every((f) => f.states === '3'.repeat(64)), `every tile done: ${JSON.stringify(s.frames)}`);
  check(fs.existsSync(path.join(dir, 'out', 'small.0001.exr')), 'frame 1 was assembled');
  await waitFor('frame 1\'s preview', async () =>
    (await pageState(page)).frames.find((f) => f.frame === 1).previewLoaded, 30);
  const workers = await page.textContent('#workers tbody');
  check(workers.includes('w1'), `the worker is listed: ${workers}`);

  // A preview opens at full size: the frame's own pixels, one to one.
  await page.click('#frames figure[data-frame="1"] img.preview');
  await page.waitForSelector('#lightbox[open]');
  const full = await waitFor('the full-size preview', () => page.evaluate(() => {
    const i = document.querySelector('#lightbox-img');
    return i.complete && i.naturalWidth > 0 &&
      {natural: i.naturalWidth, shown: i.getBoundingClientRect().width,
       small: document.querySelector('#frames figure[data-frame="1"] img.preview').getBoundingClientRect().width};
  }), 10);
  check(full.natural === 128 && Math.abs(full.shown - 128) < 1,
    `the preview opens at its full 128 px: ${JSON.stringify(full)}`);
  await page.keyboard.press('Escape');
  await page.waitForSelector('#lightbox:not([open])', {state: 'attached'});

  // A worker killed in the middle of a tile: lost on the page, and once its lease expires
  // (5 s) its task is no longer shown as its own.
  const slow = writeShot('slow', {width: 64, height: 64, frames: [1, 1], spp: 65536});
  const slowJob = pbgi('submit', slow, '--coordinator', address);
  const rowState = () => page.evaluate(() => {
    const r = document.querySelector('#workers tbody tr[data-worker="w1"]');
    return r && {state: r.dataset.state, text: r.textContent};
  });
  await waitFor('w1 busy on the slow job', async () => (await rowState())?.state === 'busy', 60);
  children.find((c) => c.spawnargs.includes('w1')).kill('SIGKILL');
  const lost = await waitFor('w1 lost on the page', async () => {
    const r = await rowState();
    return r && r.state === 'lost' && r.text.includes('went back to the queue') && r;
  }, 30);
  console.log(`the killed worker shows as lost: ${lost.text}`);
  pbgi('cancel', slowJob, '--coordinator', address);

  // A job of 4,096 tiles (1024x1024 in tiles of 16), never rendered: how fast the page loads it,
  // and how soon a cancel from the command line shows.
  const big = writeShot('big', {width: 1024, height: 1024, frames: [1, 1], spp: 1});
  const bigJob = pbgi('submit', big, '--coordinator', address);
  const loads = [];
  for (let i = 0; i < 5; ++i) {
    await page.goto(`${url}?load=${i}#job=${bigJob}`);  // a new document each time
    await page.waitForSelector('body[data-ready="1"]');
    loads.push(await page.evaluate(() => window.pbgiLoadMs));
  }
  s = await pageState(page);
  check(s.frames.length === 1 && s.frames[0].states.length === 4096,
    `the big job shows 4,096 tiles: ${s.frames.map((f) => f.states.length)}`);
  await page.waitForSelector('#live.on');
  const t0 = Date.now();
  pbgi('cancel', bigJob, '--coordinator', address);
  const cancelled = Date.now();
  await waitFor('the cancel on the page', async () => (await pageState(page)).jobs[bigJob] === 'cancelled', 10);
  const shown = Date.now();
  loads.sort((a, b) => a - b);
  console.log(`page load, job of 4,096 tiles: median ${loads[2].toFixed(0)} ms ` +
    `(of ${loads.map((l) => l.toFixed(0)).join(', ')} ms; navigation start to the grid drawn)`);
  console.log(`a cancel shows on the page ${shown - cancelled} ms after the command returned ` +
    `(${shown - t0} ms after it started)`);
  check(consoleErrors.length === 0, `the page logged errors: ${consoleErrors.join('\n')}`);
}

let failed = false;
try {
  await main();
  console.log('PASS dashboard end to end');
} catch (e) {
  failed = true;
  console.error(`FAIL: ${e.stack || e}\n${logs()}`);
} finally {
  if (browser) await browser.close().catch(() => {});
  for (const c of children) c.kill('SIGKILL');
  if (!failed) fs.rmSync(dir, {recursive: true, force: true});
  else console.error(`(files kept in ${dir})`);
}
process.exit(failed ? 1 : 0);
