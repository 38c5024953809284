#!/usr/bin/env node
// Conformance-gate adapter for jsmodbus (protocol 1, see ../PROTOCOL.md).
//
// Every decision about a frame is jsmodbus's own code, driven without a port:
//
// - decode, request: the RTU server's request path, `ModbusServerRequestHandler` over
//   `ModbusRTURequest.fromBuffer` (what `ModbusRTUServer` runs on received bytes; it
//   drops a request whose CRC is wrong); a request it hands on is accepted.
// - decode, response: the RTU client, `ModbusRTUClient` over an in-memory socket: the
//   adapter issues the request the frame answers (readHoldingRegisters,
//   writeSingleRegister, writeMultipleRegisters), feeds the frame as the socket's data and
//   reports whether the client's promise resolves (accepted, with the response body's
//   values), rejects with a Modbus exception (accepted as an exception) or rejects
//   otherwise / times out (not accepted).
// - encode: `new ModbusRTURequest(address, body).createPayload()` and
//   `new ModbusRTUResponse(address, undefined, body).createPayload()` with jsmodbus's
//   request and response body classes.
// - crc: `crc16modbus` of the `crc` package, the function jsmodbus frames and checks with.
//
// jsmodbus has no ASCII framing and no 08H (loop-back): those are answered "unsupported".
// stdout carries answers only; logs go to stderr.
'use strict';

const EventEmitter = require('events');
const readline = require('readline');

const PROTOCOL = 1;
const RESPONSE_WAIT_MS = 40;

const jsmodbus = require('jsmodbus');
const ServerRequestHandler = require('jsmodbus/dist/modbus-server-request-handler.js').default;
const { crc16modbus } = require(require.resolve('crc', { paths: [require.resolve('jsmodbus')] }));
const version = require('jsmodbus/package.json').version;

const { ModbusRTURequest, ModbusRTUResponse, ModbusRTUClient, requests, responses } = jsmodbus;

class Unsupported extends Error {}
class BadRequest extends Error {}

const hex2 = (n) => n.toString(16).toUpperCase().padStart(2, '0');
const hex4 = (n) => n.toString(16).toUpperCase().padStart(4, '0');
const hexBytes = (buf) => Array.from(buf, hex2).join(' ');

function parseHex(text) {
  if (typeof text !== 'string') throw new BadRequest('expected a hex string');
  const toks = text.split(/\s+/).filter((t) => t.length > 0);
  const out = Buffer.alloc(toks.length);
  toks.forEach((t, i) => {
    if (!/^[0-9a-fA-F]{2}$/.test(t)) throw new BadRequest(`bad hex byte ${JSON.stringify(t)}`);
    out[i] = parseInt(t, 16);
  });
  return out;
}

function hexField(fields, key) {
  const v = fields[key];
  if (typeof v !== 'string' || !/^[0-9a-fA-F]{1,4}[Hh]?$/.test(v)) {
    throw new BadRequest(`field ${key} missing or not hex`);
  }
  return parseInt(v.replace(/[Hh]$/, ''), 16);
}

function numField(fields, key) {
  const v = fields[key];
  if (!Number.isInteger(v)) throw new BadRequest(`field ${key} missing or not a number`);
  return v;
}

function message(address, fc, kind, fields) {
  return { address: hex2(address), function: hex2(fc), kind, fields };
}

function requestMessage(req) {
  const b = req.body;
  const a = req.address;
  if (b instanceof requests.ReadHoldingRegistersRequestBody) {
    return message(a, b.fc, 'read-request', { start: hex4(b.start), count: b.count });
  }
  if (b instanceof requests.WriteSingleRegisterRequestBody) {
    return message(a, b.fc, 'write-single', { register: hex4(b.address), value: hex4(b.value) });
  }
  if (b instanceof requests.WriteMultipleRegistersRequestBody) {
    return message(a, b.fc, 'write-multiple-request', {
      start: hex4(b.address),
      count: b.quantity,
      byte_count: b.numberOfBytes,
      values: Array.from(b.valuesAsArray, hex4),
    });
  }
  if (b.isException) {
    // jsmodbus's server answers this request with the exception below, unread.
    return message(a, b.fc, 'other', { jsmodbus_answers_exception: hex2(b.code) });
  }
  return message(a, b.fc, 'other', {});
}

function decodeRequest(frame) {
  if (frame.length >= 2 && frame[1] === 0x08) {
    throw new Unsupported('jsmodbus has no 08H: its server answers every 08H request with exception 01');
  }
  const handler = new ServerRequestHandler(ModbusRTURequest.fromBuffer);
  handler.handle(frame);
  const got = [];
  for (let r = handler.shift(); r; r = handler.shift()) got.push(r);
  if (got.length === 0) {
    const left = handler._buffer ? handler._buffer.length : 0;
    return {
      accepted: false,
      reason: `jsmodbus's RTU server handed on no request (${left} of ${frame.length} bytes left waiting; a request with a wrong CRC is dropped)`,
    };
  }
  // The handler unshifts, so the first frame on the wire comes out last.
  const first = got[got.length - 1];
  return { accepted: true, message: requestMessage(first) };
}

class MemorySocket extends EventEmitter {
  constructor() {
    super();
    this.isOpen = true;
    this.written = [];
  }

  write(data) {
    this.written.push(Buffer.from(data));
    return true;
  }
}

function responseMessage(address, body) {
  if (body instanceof responses.ReadHoldingRegistersResponseBody) {
    const values = Array.from(body.values, hex4);
    return message(address, body.fc, 'read-response', { byte_count: body._byteCount, values });
  }
  if (body instanceof responses.WriteSingleRegisterResponseBody) {
    return message(address, body.fc, 'write-single', { register: hex4(body.address), value: hex4(body.value) });
  }
  if (body instanceof responses.WriteMultipleRegistersResponseBody) {
    return message(address, body.fc, 'write-multiple-response', { start: hex4(body.start), count: body.quantity });
  }
  return message(address, body.fc, 'other', {});
}

async function decodeResponse(frame) {
  if (frame.length < 2) {
    return { accepted: false, reason: 'frame shorter than address and function: no request to play' };
  }
  const address = frame[0];
  const fc = frame[1] & 0x7f;
  if (fc === 0x08) throw new Unsupported('jsmodbus has no 08H (loop-back)');
  const socket = new MemorySocket();
  const client = new ModbusRTUClient(socket, address, RESPONSE_WAIT_MS);
  // The request this frame answers, issued through the client as an application would.
  let pending;
  if (fc === 0x03) {
    const count = frame[1] & 0x80 ? 1 : Math.max(1, Math.floor((frame[2] || 0) / 2));
    pending = client.readHoldingRegisters(0, count);
  } else if (fc === 0x06) {
    const reg = frame.length >= 4 ? frame.readUInt16BE(2) : 0;
    const value = frame.length >= 6 ? frame.readUInt16BE(4) : 0;
    pending = client.writeSingleRegister(reg, value);
  } else if (fc === 0x10) {
    const start = frame.length >= 4 ? frame.readUInt16BE(2) : 0;
    const count = frame.length >= 6 ? frame.readUInt16BE(4) : 1;
    if (frame[1] & 0x80 || count < 1 || count > 123) {
      pending = client.writeMultipleRegisters(start, [0]);
    } else {
      pending = client.writeMultipleRegisters(start, new Array(count).fill(0));
    }
  } else {
    throw new Unsupported(`jsmodbus's client is not asked for function ${hex2(fc)}H by this protocol's kinds`);
  }
  // Settled either way from here on: a rejection is never left unhandled.
  const settled = pending.then(
    (response) => ({ response }),
    (error) => ({ error }),
  );
  try {
    socket.emit('data', frame);
    const { response, error } = await settled;
    if (error) throw error;
    return { accepted: true, message: responseMessage(response.response.address, response.response.body) };
  } catch (e) {
    const err = e && e.err;
    if (!err) throw e; // thrown by jsmodbus while receiving, not a rejection of the request
    if (err === 'ModbusException' && e.response) {
      const body = e.response.body;
      return {
        accepted: true,
        message: message(e.response.address, body.fc | 0x80, 'exception', {
          exception_function: hex2(body.fc),
          code: hex2(body.code),
        }),
      };
    }
    if (err === 'Timeout') {
      return { accepted: false, reason: `jsmodbus's client found no complete response (it would wait until its timeout)` };
    }
    return { accepted: false, reason: `jsmodbus's client rejected: ${err || ''} ${(e && e.message) || e}` };
  } finally {
    socket.removeAllListeners();
  }
}

function head(msg) {
  if (!msg || typeof msg !== 'object' || typeof msg.fields !== 'object' || msg.fields === null) {
    throw new BadRequest('message must be an object with fields');
  }
  return [hexField(msg, 'address'), hexField(msg, 'function'), msg.kind, msg.fields];
}

function encode(direction, msg) {
  const [address, fc, kind, f] = head(msg);
  const need = (want) => {
    if (fc !== want) throw new Unsupported(`jsmodbus's ${kind} is function ${hex2(want)}H`);
  };
  if (direction === 'request') {
    let body;
    if (kind === 'read-request') {
      need(0x03);
      body = new requests.ReadHoldingRegistersRequestBody(hexField(f, 'start'), numField(f, 'count'));
    } else if (kind === 'write-single') {
      need(0x06);
      body = new requests.WriteSingleRegisterRequestBody(hexField(f, 'register'), hexField(f, 'value'));
    } else if (kind === 'write-multiple-request') {
      need(0x10);
      const values = (f.values || []).map((v) => parseInt(v, 16));
      if (numField(f, 'count') !== values.length || numField(f, 'byte_count') !== 2 * values.length) {
        throw new Unsupported('jsmodbus derives count and byte count from the values');
      }
      body = new requests.WriteMultipleRegistersRequestBody(hexField(f, 'start'), values);
    } else {
      throw new Unsupported(`jsmodbus has no request of kind ${kind}`);
    }
    return new ModbusRTURequest(address, body).createPayload();
  }
  let body;
  if (kind === 'read-response') {
    need(0x03);
    const values = (f.values || []).map((v) => parseInt(v, 16));
    body = new responses.ReadHoldingRegistersResponseBody(numField(f, 'byte_count'), values);
  } else if (kind === 'write-single') {
    need(0x06);
    body = new responses.WriteSingleRegisterResponseBody(hexField(f, 'register'), hexField(f, 'value'));
  } else if (kind === 'write-multiple-response') {
    need(0x10);
    body = new responses.WriteMultipleRegistersResponseBody(hexField(f, 'start'), numField(f, 'count'));
  } else if (kind === 'exception') {
    const ef = hexField(f, 'exception_function');
    if (fc !== (ef | 0x80)) throw new Unsupported('jsmodbus sends exception_function | 80H');
    if (ef === 0x08) throw new Unsupported('jsmodbus has no 08H (loop-back)');
    body = new responses.ExceptionResponseBody(ef, hexField(f, 'code'));
  } else {
    throw new Unsupported(`jsmodbus has no response of kind ${kind}`);
  }
  return new ModbusRTUResponse(address, undefined, body).createPayload();
}

async function answer(req) {
  switch (req.op) {
    case 'hello':
      if (req.protocol !== PROTOCOL) {
        return { ok: false, error: `protocol ${JSON.stringify(req.protocol)} not spoken; this adapter speaks 1` };
      }
      return {
        ok: true,
        protocol: PROTOCOL,
        adapter: 'jsmodbus-adapter',
        implementation: 'jsmodbus',
        version,
        supports: ['decode:rtu', 'encode:rtu', 'crc'],
      };
    case 'decode': {
      if (req.mode !== 'rtu') throw new Unsupported('jsmodbus has no ASCII framing (RTU and TCP only)');
      const frame = parseHex(req.frame);
      let result;
      try {
        result = req.direction === 'request' ? decodeRequest(frame) : await decodeResponse(frame);
      } catch (e) {
        if (e instanceof Unsupported || e instanceof BadRequest) throw e;
        // The first frame of the stack, with the machine's path to node_modules left out.
        const where = e && e.stack ? e.stack.split('\n')[1].trim().replace(/\/\S*\/node_modules\//, '') : '';
        return {
          ok: true,
          accepted: false,
          raised: true,
          reason: `jsmodbus threw ${e && e.name} ${JSON.stringify(e && e.message)} ${where} (inside the socket's data handler: uncaught in an application)`,
        };
      }
      return { ok: true, ...result };
    }
    case 'encode': {
      if (req.mode !== 'rtu') throw new Unsupported('jsmodbus has no ASCII framing (RTU and TCP only)');
      if (req.direction !== 'request' && req.direction !== 'response') throw new BadRequest('bad direction');
      return { ok: true, frame: hexBytes(encode(req.direction, req.message)) };
    }
    case 'crc':
      return { ok: true, crc: hex4(crc16modbus(parseHex(req.data))) };
    default:
      throw new Unsupported(`op ${req.op}`);
  }
}

async function handle(line) {
  let req;
  try {
    req = JSON.parse(line);
  } catch (e) {
    return { id: null, ok: false, error: `bad request: not JSON (${e.message})` };
  }
  if (!req || typeof req !== 'object') return { id: null, ok: false, error: 'bad request: not a JSON object' };
  try {
    return { id: req.id, ...(await answer(req)) };
  } catch (e) {
    if (e instanceof Unsupported) return { id: req.id, ok: false, error: 'unsupported', detail: e.message };
    if (e instanceof BadRequest) return { id: req.id, ok: false, error: `bad request: ${e.message}` };
    process.stderr.write(`[jsmodbus-adapter] id=${req.id} ${req.op}: ${e && e.stack}\n`);
    return { id: req.id, ok: false, error: `jsmodbus threw ${e && e.name}: ${e && e.message}` };
  }
}

async function main() {
  const rl = readline.createInterface({ input: process.stdin, crlfDelay: Infinity });
  for await (const raw of rl) {
    const line = raw.trim();
    if (line.length === 0) continue;
    process.stdout.write(`${JSON.stringify(await handle(line))}\n`);
  }
}

process.on('unhandledRejection', (e) => {
  process.stderr.write(`[jsmodbus-adapter] unhandled rejection: ${e && (e.stack || e.message || e)}\n`);
});

main().catch((e) => {
  process.stderr.write(`[jsmodbus-adapter] ${e && e.stack}\n`);
  process.exit(1);
});
