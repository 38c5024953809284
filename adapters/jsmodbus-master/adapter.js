#!/usr/bin/env node
// Master adapter for jsmodbus's RTU client (ModbusRTUClient) and its TCP client, for
// `conformance gate --master` (adapters/PROTOCOL.md, role "master").
//
// One JSON request per line on stdin, one JSON answer per line on stdout; logs on stderr.
// The adapter calls jsmodbus's client API (readHoldingRegisters, writeSingleRegister,
// writeMultipleRegisters) and reports what its promise resolved or rejected with. It never
// builds or parses a frame.
//
// The line: jsmodbus's RTU client takes any socket-like object (write(), 'data' events,
// 'open'). On a pty the adapter hands it the pty opened with Node's own `tty` module
// (tty.ReadStream in raw mode for 'data', fs.write for write()): no native `serialport`
// package is needed, and a pty has no baud rate to set. For `tcp-rtu` it hands it a
// net.Socket (RTU frames over TCP), for `mbap` ModbusTCPClient gets the net.Socket.
// jsmodbus has no ASCII mode and no retries.
//
// jsmodbus is taken from ./node_modules, else from ../jsmodbus/node_modules (the codec
// adapter's `npm ci`), so that one install serves both.
'use strict';

const fs = require('fs');
const net = require('net');
const path = require('path');
const readline = require('readline');
const tty = require('tty');
const EventEmitter = require('events');

function load(name) {
  for (const base of [__dirname, path.join(__dirname, '..', 'jsmodbus')]) {
    try {
      return require(require.resolve(name, { paths: [base] }));
    } catch (e) {
      if (e.code !== 'MODULE_NOT_FOUND') throw e;
    }
  }
  throw new Error(`${name} not found: run npm ci in adapters/jsmodbus (or here)`);
}
const jsmodbus = load('jsmodbus');
const version = load('jsmodbus/package.json').version;

const log = (m) => process.stderr.write(`[jsmodbus-master] ${m}\n`);
const h4 = (v) => (v & 0xffff).toString(16).toUpperCase().padStart(4, '0');

let line = null; // { socket, kind, timeout, close() }
const clients = new Map(); // unit -> client (jsmodbus fixes the unit in the constructor)

function closeLine() {
  for (const c of clients.values()) {
    try { c._requestHandler.manuallylRejectAllRequests(); } catch (_) { /* none pending */ }
  }
  clients.clear();
  if (line) line.close();
  line = null;
}

/** The pty as the socket-like object jsmodbus's RTU client reads and writes. */
function ptySocket(p) {
  const fd = fs.openSync(p, fs.constants.O_RDWR | fs.constants.O_NOCTTY);
  const rs = new tty.ReadStream(fd);
  rs.setRawMode(true);
  const sock = new EventEmitter();
  sock.isOpen = true;
  sock.write = (buf, cb) => {
    fs.write(fd, buf, 0, buf.length, null, (err) => cb && cb(err));
    return true;
  };
  rs.on('data', (d) => sock.emit('data', d));
  rs.on('error', (e) => log(`pty: ${e.message}`));
  return { socket: sock, close: () => { sock.isOpen = false; rs.destroy(); } };
}

function tcpSocket(host, port) {
  return new Promise((resolve, reject) => {
    const s = net.connect({ host, port }, () => {
      s.setNoDelay(true);
      s.isOpen = true;
      resolve({ socket: s, close: () => s.destroy() });
    });
    s.once('error', reject);
  });
}

function client(unit) {
  if (!line) throw new Error('not open');
  let c = clients.get(unit);
  if (!c) {
    c = line.kind === 'mbap'
      ? new jsmodbus.client.TCP(line.socket, unit, line.timeout)
      : new jsmodbus.client.RTU(line.socket, unit, line.timeout);
    if (line.kind === 'mbap') c._requestHandler._onConnect(); // the socket is connected already
    else line.socket.emit('open');
    clients.set(unit, c);
  }
  return c;
}

async function open(req) {
  closeLine();
  if ((req.mode || 'rtu') !== 'rtu') return { ok: false, error: 'unsupported', detail: 'jsmodbus has no ASCII' };
  const l = req.line || {};
  const timeout = req.timeout_ms || 5000;
  let opened;
  if (l.kind === 'pty') opened = ptySocket(l.path);
  else if (l.kind === 'tcp-rtu' || l.kind === 'mbap') opened = await tcpSocket(l.host, l.port);
  else return { ok: false, error: 'unsupported', detail: `line ${l.kind}` };
  line = { ...opened, kind: l.kind, timeout };
  // jsmodbus has no retries: it runs with 0, whatever was asked.
  return { ok: true, timeout_ms: timeout, retries: 0 };
}

/** What jsmodbus's promise rejected with, as an answer. */
function rejected(e) {
  if (e && typeof e === 'object' && typeof e.err === 'string') {
    switch (e.err) {
      case 'ModbusException': {
        const code = e.response && e.response.body ? e.response.body.code : undefined;
        return { ok: true, result: 'exception', code: (code ?? 0).toString(16).toUpperCase().padStart(2, '0'), message: e.message };
      }
      case 'Timeout': return { ok: true, result: 'error', kind: 'timeout', message: e.message };
      case 'crcMismatch': return { ok: true, result: 'error', kind: 'checksum', message: e.message };
      case 'OutOfSync': return { ok: true, result: 'error', kind: 'invalid-frame', message: e.message };
      default: return { ok: true, result: 'error', kind: 'other', message: `${e.err}: ${e.message}` };
    }
  }
  return { ok: true, result: 'raised', type: e && e.constructor ? e.constructor.name : typeof e, message: String(e && e.message || e) };
}

// jsmodbus parses replies inside the socket's 'data' handler: what it throws there is
// thrown out of an event handler (an uncaught exception that would end an application).
// The adapter catches it (process 'uncaughtException') and answers `raised` for the
// operation in progress.
let onThrow = null;
process.on('uncaughtException', (e) => {
  if (onThrow) onThrow(e);
  else log(`uncaught exception outside an operation: ${e && e.stack || e}`);
});

async function call(fn, onOk) {
  let r;
  const thrown = new Promise((_, reject) => { onThrow = (e) => reject({ thrownInHandler: e }); });
  try {
    r = await Promise.race([fn(), thrown]);
  } catch (e) {
    if (e && e.thrownInHandler !== undefined) {
      const t = e.thrownInHandler;
      return { ok: true, result: 'raised', type: t && t.constructor ? t.constructor.name : typeof t,
        message: `thrown in jsmodbus's data handler: ${t && t.name || 'Error'}(${JSON.stringify(t && t.message !== undefined ? t.message : String(t))}) ${(String(t && t.stack || '').split('\n')[1] || '').trim()}`.trim() };
    }
    return rejected(e);
  } finally {
    onThrow = null;
  }
  return onOk(r.response.body);
}

const ops = {
  hello: async (req) => (req.protocol === 1 && req.role === 'master'
    ? { ok: true, protocol: 1, role: 'master', adapter: 'jsmodbus-master', implementation: 'jsmodbus', version,
        supports: ['read', 'write-single', 'write-multiple', 'broadcast'], lines: ['pty', 'tcp-rtu', 'mbap'], modes: ['rtu'] }
    : { ok: false, error: 'this adapter speaks protocol 1, role master' }),
  open,
  close: async () => { closeLine(); return { ok: true }; },
  read: async (req) => {
    const c = client(req.unit);
    return call(() => c.readHoldingRegisters(parseInt(req.start, 16), req.count),
      (b) => ({ ok: true, result: 'values', values: Array.from(b.values, h4) }));
  },
  'write-single': async (req) => {
    const c = client(req.unit);
    return call(() => c.writeSingleRegister(parseInt(req.register, 16), parseInt(req.value, 16)),
      (b) => ({ ok: true, result: 'done', echo: { register: h4(b.address), value: h4(b.value) } }));
  },
  'write-multiple': async (req) => {
    const c = client(req.unit);
    return call(() => c.writeMultipleRegisters(parseInt(req.start, 16), req.values.map((v) => parseInt(v, 16))),
      (b) => ({ ok: true, result: 'done', echo: { start: h4(b.start), count: b.quantity } }));
  },
  'loop-back': async () => ({ ok: false, error: 'unsupported', detail: "jsmodbus's client has no 08H request" }),
};

const rl = readline.createInterface({ input: process.stdin, terminal: false });
let chain = Promise.resolve();
rl.on('line', (text) => {
  chain = chain.then(async () => {
    const t = text.trim();
    if (!t) return;
    let req;
    let answer;
    try {
      req = JSON.parse(t);
      if (typeof req !== 'object' || req === null || Array.isArray(req)) throw new Error('not a JSON object');
    } catch (e) {
      process.stdout.write(`${JSON.stringify({ id: null, ok: false, error: `bad request: ${e.message}` })}\n`);
      return;
    }
    const fn = ops[req.op];
    try {
      answer = fn ? await fn(req) : { ok: false, error: 'unsupported', detail: `op ${req.op}` };
    } catch (e) {
      log(`id=${req.id}: ${e.stack || e}`);
      answer = { ok: false, error: String(e && e.message || e) };
    }
    process.stdout.write(`${JSON.stringify({ id: req.id, ...answer })}\n`);
  });
});
rl.on('close', () => { chain.then(() => { closeLine(); process.exit(0); }); });
process.on('unhandledRejection', (e) => log(`unhandled rejection: ${e && e.stack || e}`));
