#!/usr/bin/env node
/*
 * Runs one job through a real cncjs server's TinyG controller (the one it has for TinyG and
 * g2core boards) against a board on a serial port, and prints one JSON report line on stdout.
 *
 *   node cncjs_tinyg_driver.js CNCJS_PREFIX PORT JOB.gcode [--baudrate B] [--timeout S]
 *                              [--pause-at N] [--pause-ms MS] [--url URL]
 *
 * The set-up is cncjs_driver.js's: CNCJS_PREFIX is the `npm install --prefix` directory holding
 * node_modules/cncjs; the driver starts `cncjs` (its own server, unchanged, on a free port of
 * 127.0.0.1 with a throwaway HOME and config), signs in as its web page does and speaks its
 * Socket.IO API. With --url it reuses a cncjs server already running there instead (then the
 * serial tap below is not in it, and the report has only what cncjs's socket events show).
 *
 * What it does: `open` the port with controllerType 'TinyG'; wait until cncjs's controller
 * state carries the board's status report (its `stat`) and its settings the firmware build
 * (`fb`, from the banner or {sys:n}), and until cncjs's init has been answered; `gcode:load` and
 * `gcode:start` the job; `gcode:pause` (cncjs writes `!`) once N lines were acknowledged and
 * cncjs holds back no acknowledgement (see main()); wait for the board's `stat` 6 (hold) and
 * watch the position while held; `gcode:resume` (`~`) MS after the pause; wait for the job's end
 * (cncjs's workflow idle, its sender done); `close`.
 *
 * cncjs shows the serial traffic only partly on its socket: `serialport:read` only while its
 * workflow is idle, `serialport:write` for its own controls and console lines but not for job
 * lines. Both are in the report (`socket_read`, `socket_write`). The whole of it comes from a tap:
 * loaded with `node -r` into the cncjs process itself (FAKE_MARLIN_CNCJS_TRACE set), this file
 * wraps serialport's SerialPort.prototype.write (every write cncjs makes, exactly) and its
 * stream's push (every chunk read from the port, exactly), one JSON line each to that file;
 * the report has them as `wire` ({t, dir: 'w' | 'r', data}) and, cut into lines, as `written`
 * and `read`.
 */
'use strict';

const fs = require('fs');
const os = require('os');
const path = require('path');
const { spawn } = require('child_process');

const TRACE_ENV = 'FAKE_MARLIN_CNCJS_TRACE';
const HOLD = 6; // the board's stat while in a feedhold
const IDLE_STATS = [1, 3, 4]; // ready, program stop, program end: cncjs's isIdle()
const started = Date.now();
// What the report says so far: a timeout still shows how far the job got.
const progress = {
  cncjs: null, controller: 'TinyG', port: null, opened: false, ready_ms: null, firmware: null,
  settings: null, phase: 'start', init_errors: [], states: [], workflow: [], positions: [], pause: null, sender: null,
  sender_at_end: null, sender_max: null, errors: [], socket_read: [], socket_write: [],
  server_warnings: [],
};

function cncjsRequire(prefix, name) {
  const server = path.join(prefix, 'node_modules', 'cncjs', 'dist', 'cncjs', 'server');
  return require(require.resolve(name, { paths: [server] }));
}

function installTap() {
  const tracePath = process.env[TRACE_ENV];
  const prefix = process.env.FAKE_MARLIN_CNCJS_PREFIX;
  if (!tracePath || !prefix) {
    return;
  }
  const { SerialPort } = cncjsRequire(prefix, 'serialport');
  const log = (dir, data) => {
    const text = Buffer.isBuffer(data) ? data.toString('latin1') : String(data);
    fs.appendFileSync(tracePath, JSON.stringify({ t: Date.now(), dir, data: text }) + '\n');
  };
  const write = SerialPort.prototype.write;
  SerialPort.prototype.write = function tappedWrite(data, ...rest) {
    log('w', data);
    return write.call(this, data, ...rest);
  };
  const push = SerialPort.prototype.push;
  SerialPort.prototype.push = function tappedPush(chunk, ...rest) {
    if (chunk !== null && chunk !== undefined) {
      log('r', chunk);
    }
    return push.call(this, chunk, ...rest);
  };
}

function parseArgs(argv) {
  const options = { baudrate: 115200, timeout: 120, pauseAt: 20, pauseMs: 1500, url: null };
  const positional = [];
  for (let i = 0; i < argv.length; i++) {
    const flag = { '--baudrate': 'baudrate', '--timeout': 'timeout', '--pause-at': 'pauseAt', '--pause-ms': 'pauseMs' }[argv[i]];
    if (flag) {
      options[flag] = Number(argv[++i]);
      if (!Number.isFinite(options[flag])) {
        throw new Error(`${argv[i - 1]} needs a number`);
      }
    } else if (argv[i] === '--url') {
      options.url = argv[++i];
    } else {
      positional.push(argv[i]);
    }
  }
  if (positional.length !== 3) {
    throw new Error('usage: cncjs_tinyg_driver.js CNCJS_PREFIX PORT JOB.gcode [--baudrate B] [--timeout S] [--pause-at N] [--pause-ms MS] [--url URL]');
  }
  [options.prefix, options.port, options.job] = positional;
  return options;
}

let server = null; // the cncjs process, when this driver started it
let serverLog = '';
let workdir = null;
let tracePath = null;
let finished = false;

function lines(entries, dir) {
  // The tap's chunks of one direction, joined and cut at each line end (the last one kept even
  // unterminated); single characters cncjs writes without a line end stay their own entry.
  const out = [];
  let pending = '';
  for (const entry of entries) {
    if (entry.dir !== dir) {
      continue;
    }
    pending += entry.data;
    let at;
    while ((at = pending.search(/\r?\n/)) >= 0) {
      out.push(pending.slice(0, at));
      pending = pending.slice(at + (pending[at] === '\r' ? 2 : 1));
    }
  }
  if (pending) {
    out.push(pending);
  }
  return out;
}

function readTrace() {
  if (!tracePath || !fs.existsSync(tracePath)) {
    return [];
  }
  return fs.readFileSync(tracePath, 'utf8').split('\n').filter(Boolean).map((line) => JSON.parse(line));
}

function finish(report, code) {
  if (finished) {
    return;
  }
  finished = true;
  if (server && server.exitCode === null) {
    server.kill('SIGTERM');
  }
  const wire = readTrace().map((entry) => ({ ...entry, t: entry.t - started }));
  const written = lines(wire, 'w');
  const read = lines(wire, 'r');
  Object.assign(report, {
    wire, written, read,
    // Job lines as the board saw them: written `N<k>...`, and answers carrying an `n`.
    job_lines: {
      sent: written.filter((line) => /^N\d+/.test(line)).length,
      acknowledged: read.filter((line) => /^\{"r":\{"n":\d+/.test(line)).length,
    },
    elapsed_ms: Date.now() - started,
    server_log_tail: serverLog.replace(/\x1b\[[0-9;]*m/g, '').split('\n').slice(-40),
  });
  if (workdir) {
    fs.rmSync(workdir, { recursive: true, force: true });
  }
  process.stdout.write(JSON.stringify(report) + '\n', () => process.exit(code));
}

function startServer(prefix) {
  const config = path.join(workdir, 'cncrc');
  // A fixed secret, so cncjs writes no generated one into the config; HOME keeps its
  // session directory (~/.cncjs-sessions) out of the user's home.
  fs.writeFileSync(config, JSON.stringify({ secret: 'fake-marlin-test' }));
  const bin = path.join(prefix, 'node_modules', 'cncjs', 'bin', 'cncjs');
  server = spawn(process.execPath, ['-r', __filename, bin, '--port', '0', '--host', '127.0.0.1',
    '--config', config, '--controller', 'TinyG', '-vv'], {
    env: { ...process.env, HOME: workdir, [TRACE_ENV]: tracePath, FAKE_MARLIN_CNCJS_PREFIX: prefix },
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  return new Promise((resolve, reject) => {
    const onData = (chunk) => {
      const text = chunk.toString();
      serverLog = (serverLog + text).slice(-65536);
      for (const line of text.replace(/\x1b\[[0-9;]*m/g, '').split('\n')) {
        // cncjs's own warnings and errors about the board or its sender
        if (/\b(warn|error)\b/i.test(line) && progress.server_warnings.length < 200) {
          progress.server_warnings.push(line.trim());
        }
      }
      const match = serverLog.match(/Starting the server at (http:\/\/[\d.]+:\d+)/);
      if (match) {
        resolve(match[1]);
      }
    };
    server.stdout.on('data', onData);
    server.stderr.on('data', onData);
    server.on('exit', (code, signal) => reject(new Error(`cncjs exited (${code === null ? signal : code}) before it listened`)));
  });
}

const ms = () => Date.now() - started;
const xyz = (pos) => (pos ? { x: Number(pos.x), y: Number(pos.y), z: Number(pos.z) } : null);
const same = (a, b) => a && b && a.x === b.x && a.y === b.y && a.z === b.z;

async function main() {
  const options = parseArgs(process.argv.slice(2));
  const deadline = setTimeout(() => finish({ ok: false, ...progress, errors: [...progress.errors, `no result after ${options.timeout} s`] }, 1),
    options.timeout * 1000);
  const gcode = fs.readFileSync(options.job, 'utf8');
  workdir = fs.mkdtempSync(path.join(os.tmpdir(), 'fake-marlin-cncjs-')); // gone at finish()
  tracePath = path.join(workdir, 'trace.jsonl');
  progress.cncjs = JSON.parse(fs.readFileSync(path.join(options.prefix, 'node_modules', 'cncjs', 'package.json'))).version;
  progress.port = options.port;
  let url = options.url;
  if (url) {
    tracePath = null; // not our process: no tap in it
  } else {
    url = await startServer(options.prefix);
  }

  const signin = await fetch(`${url}/api/signin`, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: '{}' });
  if (!signin.ok) {
    throw new Error(`POST /api/signin: HTTP ${signin.status}`);
  }
  const { token } = await signin.json();
  const io = cncjsRequire(options.prefix, 'socket.io-client');
  const socket = io.connect(url, { query: `token=${token}`, transports: ['websocket'], reconnection: false });
  // A request with an answer; cncjs answers a failure with an Error, which reaches us as {}:
  // its log (server_log_tail) says what went wrong.
  const emit = (...args) => new Promise((resolve, reject) => socket.emit(...args, (error, ...rest) => (error
    ? reject(new Error(`cncjs refused ${args.slice(0, 3).map((a) => (typeof a === 'string' ? a : JSON.stringify(a))).join(' ').slice(0, 100)}: ${JSON.stringify(error)}, see server_log_tail`))
    : resolve(rest))));
  await new Promise((resolve, reject) => {
    socket.on('startup', resolve);
    socket.on('connect_error', (error) => reject(new Error(`Socket.IO: ${error.message || error}`)));
    socket.on('error', (error) => reject(new Error(`Socket.IO: ${error.message || error}`)));
  });

  // Everything cncjs tells its page, kept as it comes.
  const waiters = []; // [predicate, resolve]: woken on each state or settings change
  const wake = () => {
    for (let i = waiters.length - 1; i >= 0; i--) {
      if (waiters[i][0]()) {
        waiters.splice(i, 1)[0][1]();
      }
    }
  };
  const until = (predicate) => new Promise((resolve) => {
    if (predicate()) {
      resolve();
    } else {
      waiters.push([predicate, resolve]);
    }
  });
  let state = null; // cncjs's controller state: sr.machineState, sr.wpos, sr.mpos, qr...
  let settings = null;
  socket.on('serialport:read', (line) => {
    progress.socket_read.push({ t: ms(), line: String(line) });
    if (/^error:/.test(String(line))) {
      // cncjs's words for a footer status other than 0; in its init, {spe:n} and {spd:n} draw
      // 100 from a 101.x board (it has spc instead), which is how cncjs learns it.
      (progress.phase === 'init' ? progress.init_errors : progress.errors).push(String(line));
    }
  });
  socket.on('serialport:write', (data) => progress.socket_write.push({ t: ms(), data: String(data) }));
  socket.on('serialport:error', (error) => progress.errors.push(`serialport:error ${JSON.stringify(error)}`));
  socket.on('controller:settings', (type, value) => {
    settings = value;
    progress.settings = value;
    wake();
  });
  socket.on('controller:state', (type, value) => {
    state = value;
    const sr = value.sr || {};
    const stat = sr.machineState;
    const last = progress.states[progress.states.length - 1];
    if (stat !== undefined && (!last || last.stat !== stat)) {
      progress.states.push({ t: ms(), stat });
    }
    const pos = xyz(sr.wpos);
    const lastPos = progress.positions[progress.positions.length - 1];
    if (pos && (!lastPos || !same(lastPos.pos, pos) || lastPos.stat !== stat)) {
      progress.positions.push({ t: ms(), stat, pos });
    }
    wake();
  });
  socket.on('sender:status', (status) => {
    progress.sender = status;
    if (!progress.sender_max || status.received > progress.sender_max.received) {
      progress.sender_max = status;
    }
    wake();
  });
  const stat = () => state && state.sr && state.sr.machineState;

  await emit('open', options.port, { controllerType: 'TinyG', baudrate: options.baudrate });
  progress.opened = true;
  progress.phase = 'init';
  // Ready: the board's status report reached cncjs's state, and its build its settings.
  progress.waiting_for = 'ready: a stat in cncjs\'s state and fb in its settings';
  await until(() => stat() !== undefined && stat() !== null && settings && Number(settings.fb) > 0);
  progress.ready_ms = ms();
  progress.firmware = {
    fb: settings.fb, fv: settings.fv, fbs: settings.fbs, fbc: settings.fbc, hp: settings.hp,
    hv: settings.hv, id: settings.id, stat_at_ready: stat(),
  };
  // cncjs calls the port ready at once and writes its init over about 0.8 s, without waiting
  // for answers: {ej:1} ... {spe:n} ... {cof:n}, its status report fields, then {sys:n} {mt:n}
  // {pwr:n} {qr:n} {sr:n}. A job started before that ends has the init's answers taken as job
  // lines' acknowledgements (cncjs counts any `r` while running), so the job waits for the
  // answer to the last of them, {sr:n}, and for the board to be idle.
  progress.waiting_for = 'the end of cncjs\'s init: the answer to {sr:n}, and stat 1, 3 or 4';
  await until(() => {
    const asked = progress.socket_write.find((entry) => entry.data === '{sr:n}\n');
    return asked && progress.socket_read.some((entry) => entry.t >= asked.t && entry.line.startsWith('{"r":{"sr":'))
      && IDLE_STATS.includes(stat());
  });
  // A board with Marlin compatibility says its banner 2 s after the port opens; while running,
  // cncjs would count that `r` as a job line's acknowledgement. Wait for it (where the serial
  // tap sees the board's lines).
  if (progress.socket_read.length || !options.url) {
    progress.waiting_for = 'the board\'s banner';
    await until(() => progress.socket_read.some((entry) => entry.line.includes('"msg":"SYSTEM READY"')));
  }
  progress.init_done_ms = ms();
  progress.firmware.sys = settings.jv !== undefined; // {sys:n} answered: its values are in the settings

  await emit('command', options.port, 'gcode:load', path.basename(options.job), gcode, {});
  let startedJob = false;
  const done = new Promise((resolve) => {
    socket.on('workflow:state', (value) => {
      progress.workflow.push(value);
      if (value === 'running') {
        startedJob = true;
      } else if (value === 'idle' && startedJob) {
        // cncjs stops the workflow once the sender is done and the machine idle, and rewinds
        // the sender: the next status has its counts back at 0.
        progress.sender_at_end = progress.sender;
        resolve();
      }
      wake();
    });
  });
  progress.job_started_ms = ms();
  socket.emit('command', options.port, 'gcode:start');

  progress.phase = 'job';
  // The feedhold, once N lines were acknowledged and cncjs holds back no acknowledgement.
  // cncjs 1.11.5 withholds a job line's acknowledgement while the board's last queue report
  // said 5 free planner buffers or fewer, and lets it go at the next report of 6 or more; a
  // pause that comes while one is withheld loses it for good when no report of 6 comes during
  // the hold (the board frees no buffer while held): `gcode:resume` sends the next line without
  // counting it, the sender stays one behind, and the job never ends. So the pause waits until
  // cncjs's state has the board's `qr` at 7 or more (cncjs unblocked: an acknowledgement is
  // counted as it comes) while the machine runs: a job that fills the planner gets there at a
  // `%wait` (cncjs stops sending until the planner is empty) or at its tail.
  progress.waiting_for = `the pause: ${options.pauseAt} lines acknowledged, qr >= 7, stat 5`;
  await until(() => progress.sender && progress.sender.received >= options.pauseAt
    && state.qr >= 7 && stat() === 5);
  progress.waiting_for = null;
  const pause = { asked_at: ms(), sender_at_pause: progress.sender, stat_at_ask: stat(), qr_at_ask: state.qr };
  progress.pause = pause;
  socket.emit('command', options.port, 'gcode:pause');
  const holdSeen = await Promise.race([
    until(() => stat() === HOLD).then(() => true),
    new Promise((resolve) => setTimeout(() => resolve(false), 5000)),
  ]);
  pause.hold_seen = holdSeen;
  if (holdSeen) {
    pause.held_at = ms();
    pause.position_at_hold = xyz(state.sr.wpos);
  } else {
    progress.errors.push(`no stat ${HOLD} (hold) within 5 s of gcode:pause: stat ${stat()}`);
  }
  await new Promise((resolve) => setTimeout(resolve, options.pauseMs));
  pause.resumed_at = ms();
  pause.stat_at_resume = stat();
  pause.position_at_resume = xyz(state.sr.wpos);
  pause.sender_at_resume = progress.sender;
  // Every position cncjs's state had with the board held, up to the resume (the first one
  // came with the stat 6 itself).
  pause.positions_held = progress.positions
    .filter((entry) => entry.stat === HOLD && entry.t >= pause.asked_at && entry.t <= pause.resumed_at)
    .map((entry) => entry.pos);
  socket.emit('command', options.port, 'gcode:resume');
  // The position moves on after the resume (the job has lines left to run).
  const movedOn = await Promise.race([
    until(() => state && !same(xyz(state.sr.wpos), pause.position_at_resume)).then(() => true),
    done.then(() => state && !same(xyz(state.sr.wpos), pause.position_at_resume)),
  ]);
  pause.moved_after_resume = movedOn;
  pause.moved_at = ms();

  progress.waiting_for = 'the job\'s end: cncjs\'s workflow idle';
  await done;
  progress.waiting_for = null;
  progress.job_ended_ms = ms();
  progress.final_state = state;
  progress.final_position = xyz(state.sr.wpos);
  await emit('close', options.port);
  socket.close();
  progress.done = true;
  clearTimeout(deadline);
  finish({ ok: true, ...progress }, 0);
}

if (require.main !== module) {
  installTap();
} else {
  main().catch((error) => finish({ ok: false, ...progress, errors: [...progress.errors, `driver: ${error && error.stack || error}`] }, 1));
}
