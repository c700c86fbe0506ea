#!/usr/bin/env node
/*
 * Runs one job through a real cncjs server against a printer on a serial port, and prints one
 * JSON report line on stdout.
 *
 *   node cncjs_driver.js CNCJS_PREFIX PORT JOB.gcode [--baudrate B] [--timeout S]
 *                        [--pause-at N] [--pause-ms MS]
 *
 * CNCJS_PREFIX is the `npm install --prefix` directory holding node_modules/cncjs. The driver
 * starts `cncjs` (its own server, unchanged, on a free port of 127.0.0.1 with a throwaway HOME
 * and config), signs in as its web page does (POST /api/signin: with no users configured it
 * hands out a token), and speaks its Socket.IO API: `open` the port as a Marlin controller,
 * wait for the firmware report, `gcode:load` and `gcode:start` the job, `gcode:pause` once N
 * lines were acknowledged and `gcode:resume` MS later, wait for the workflow to end, and
 * send M114 from the console (cncjs's feeder) for the position the job ended at.
 *
 * Loaded with `node -r` into the cncjs process itself (FAKE_MARLIN_CNCJS_TRACE set), this file
 * instead wraps serialport's SerialPort.prototype.write to append every write cncjs makes to
 * that file, one JSON line each: the exact text that went to the port, nothing changed.
 */
'use strict';

const fs = require('fs');
const os = require('os');
const path = require('path');
const { spawn } = require('child_process');

const TRACE_ENV = 'FAKE_MARLIN_CNCJS_TRACE';
// What the report says so far: a timeout still shows how far the job got.
const progress = { read: [], unparsed: [], errors: [], workflow: [], pause: null, sender: null, sender_at_end: null, settings: null, state: null };

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
  const write = SerialPort.prototype.write;
  SerialPort.prototype.write = function tappedWrite(data, ...rest) {
    const text = Buffer.isBuffer(data) ? data.toString('latin1') : String(data);
    fs.appendFileSync(tracePath, JSON.stringify({ t: Date.now(), data: text }) + '\n');
    return write.call(this, data, ...rest);
  };
}

function parseArgs(argv) {
  const options = { baudrate: 250000, timeout: 120, pauseAt: 50, pauseMs: 1500 };
  const positional = [];
  for (let i = 0; i < argv.length; i++) {
    const flag = { '--baudrate': 'baudrate', '--timeout': 'timeout', '--pause-at': 'pauseAt', '--pause-ms': 'pauseMs' }[argv[i]];
    if (flag) {
      options[flag] = Number(argv[++i]);
      if (!Number.isFinite(options[flag])) {
        throw new Error(`${argv[i - 1]} needs a number`);
      }
    } else {
      positional.push(argv[i]);
    }
  }
  if (positional.length !== 3) {
    throw new Error('usage: cncjs_driver.js CNCJS_PREFIX PORT JOB.gcode [--baudrate B] [--timeout S] [--pause-at N] [--pause-ms MS]');
  }
  [options.prefix, options.port, options.job] = positional;
  return options;
}

let server = null; // the cncjs process
let serverLog = '';
let workdir = null;

function finish(report, code) {
  if (server && server.exitCode === null) {
    server.kill('SIGTERM');
  }
  report.server_log_tail = serverLog.replace(/\x1b\[[0-9;]*m/g, '').split('\n').slice(-40);
  if (workdir) {
    fs.rmSync(workdir, { recursive: true, force: true });
  }
  process.stdout.write(JSON.stringify(report) + '\n', () => process.exit(code));
}

function startServer(prefix, trace) {
  const config = path.join(workdir, 'cncrc');
  // A fixed secret, so cncjs writes no generated one into the config; HOME keeps its
  // session directory (~/.cncjs-sessions) out of the user's home.
  fs.writeFileSync(config, JSON.stringify({ secret: 'fake-marlin-test' }));
  const bin = path.join(prefix, 'node_modules', 'cncjs', 'bin', 'cncjs');
  server = spawn(process.execPath, ['-r', __filename, bin, '--port', '0', '--host', '127.0.0.1',
    '--config', config, '--controller', 'Marlin', '-vv'], {
    env: { ...process.env, HOME: workdir, [TRACE_ENV]: trace, FAKE_MARLIN_CNCJS_PREFIX: prefix },
    stdio: ['ignore', 'pipe', 'pipe'],
  });
  return new Promise((resolve, reject) => {
    const onData = (chunk) => {
      serverLog = (serverLog + chunk.toString()).slice(-65536);
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

async function main() {
  const options = parseArgs(process.argv.slice(2));
  const deadline = setTimeout(() => finish({ ok: false, errors: [`no result after ${options.timeout} s`], ...progress }, 1),
    options.timeout * 1000);
  const gcode = fs.readFileSync(options.job, 'utf8');
  workdir = fs.mkdtempSync(path.join(os.tmpdir(), 'fake-marlin-cncjs-')); // gone at finish()
  const trace = path.join(workdir, 'trace.jsonl');
  const version = JSON.parse(fs.readFileSync(path.join(options.prefix, 'node_modules', 'cncjs', 'package.json'))).version;
  const url = await startServer(options.prefix, trace);

  const signin = await fetch(`${url}/api/signin`, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: '{}' });
  if (!signin.ok) {
    throw new Error(`POST /api/signin: HTTP ${signin.status}`);
  }
  const { token } = await signin.json();
  const io = cncjsRequire(options.prefix, 'socket.io-client');
  const { default: MarlinLineParser } = require(path.join(options.prefix, 'node_modules', 'cncjs', 'dist', 'cncjs',
    'server', 'controllers', 'Marlin', 'MarlinLineParser.js'));
  const parser = new MarlinLineParser();
  const socket = io.connect(url, { query: `token=${token}`, transports: ['websocket'], reconnection: false });
  // A request with an answer; cncjs answers a failure with an Error, which reaches us as {}:
  // its log (server_log_tail) says what went wrong.
  const emit = (...args) => new Promise((resolve, reject) => socket.emit(...args, (error, ...rest) => (error
    ? reject(new Error(`cncjs refused ${args.slice(0, 3).map((a) => (typeof a === 'string' ? a : JSON.stringify(a))).join(' ').slice(0, 100)}: ${JSON.stringify(error)}, see server_log_tail`))
    : resolve(rest))));

  Object.assign(progress, { cncjs: version, baudrate: options.baudrate });
  await new Promise((resolve, reject) => {
    socket.on('startup', resolve);
    socket.on('connect_error', (error) => reject(new Error(`Socket.IO: ${error.message || error}`)));
    socket.on('error', (error) => reject(new Error(`Socket.IO: ${error.message || error}`)));
  });
  const positions = []; // resolvers waiting for a position report
  socket.on('serialport:read', (line) => {
    progress.read.push(line);
    const { type, payload } = parser.parse(String(line).replace(/\s+$/, ''));
    if (!type) {
      progress.unparsed.push(line); // cncjs's Marlin parser found no meaning in it
    } else if (type.name === 'MarlinLineParserResultPosition') {
      positions.splice(0).forEach((resolve) => resolve(payload.pos));
    }
  });
  socket.on('serialport:error', (error) => progress.errors.push(`serialport:error ${JSON.stringify(error)}`));
  socket.on('controller:settings', (type, settings) => { progress.settings = settings; });
  socket.on('controller:state', (type, state) => { progress.state = state; });
  const ready = new Promise((resolve) => socket.on('controller:settings', (type, settings) => settings.firmwareName && resolve()));

  await emit('open', options.port, { controllerType: 'Marlin', baudrate: options.baudrate });
  await ready; // the M115 report arrived: cncjs calls the controller ready
  progress.opened = true;

  await emit('command', options.port, 'gcode:load', path.basename(options.job), gcode, {});
  const done = new Promise((resolve) => {
    let pauseAsked = false;
    let started = false;
    socket.on('sender:status', (status) => {
      progress.sender = status;
      if (!pauseAsked && status.received >= options.pauseAt) {
        pauseAsked = true;
        socket.emit('command', options.port, 'gcode:pause');
      }
    });
    socket.on('workflow:state', (state) => {
      progress.workflow.push(state);
      if (state === 'running') {
        started = true;
      } else if (state === 'paused' && !progress.pause) {
        const pause = { paused_at: Date.now(), sender_at_pause: progress.sender };
        progress.pause = pause;
        setTimeout(() => {
          pause.resumed_at = Date.now();
          pause.sender_at_resume = progress.sender;
          socket.emit('command', options.port, 'gcode:resume');
        }, options.pauseMs);
      } else if (state === 'idle' && started) {
        // cncjs stops the workflow once the sender is done and the machine idle, and rewinds
        // the sender: the next status has its counts back at 0.
        progress.sender_at_end = progress.sender;
        resolve();
      }
    });
  });
  socket.emit('command', options.port, 'gcode:start');
  await done;
  // Where the job left the head, asked as a user does from cncjs's console once it is over
  // (its own polls may not have asked again before it called the job done).
  const position = new Promise((resolve) => positions.push(resolve));
  socket.emit('command', options.port, 'gcode', 'M114');
  progress.final_position = await position;
  await emit('close', options.port);
  socket.close();
  progress.done = true;
  progress.trace = fs.existsSync(trace) ? fs.readFileSync(trace, 'utf8').split('\n').filter(Boolean).map(JSON.parse) : [];
  clearTimeout(deadline);
  finish({ ok: true, ...progress }, 0);
}

if (require.main !== module) {
  installTap();
} else {
  main().catch((error) => finish({ ok: false, errors: [`driver: ${error && error.stack || error}`] }, 1));
}
