// node_subscriber.mjs: a lunad consumer in Node.js, the same as c_subscriber.c. It applies
// docs/messages.md (schema v2) by hand: exact topics, "v":2, duplicates and loss from
// run/seq/frames, cached messages, 64-bit times as BigInt, and its own staleness check.
// Install: npm install   (here, in examples/: the zeromq package pinned in package.json)
// Run:     node node_subscriber.mjs ENDPOINT SENSOR [--count N] [--stale-ms M]   (M: 200)
// Prints "seq range_m status" per reading, then "received N lost L duplicates D".
// Exits 0 after N readings or on SIGINT/SIGTERM, 3 after M ms without a reading ("STALE"),
// 1 or 2 on errors.
import { Subscriber } from "zeromq";

const [endpoint, sensor = "", ...opts] = process.argv.slice(2);
let count = 0, staleMs = 200; // docs/messages.md: 0.2 s is a sensible limit at 250 Hz
let bad = !endpoint || !/^[A-Za-z0-9_.-]{1,64}$/.test(sensor) || opts.length % 2 === 1;
for (let i = 0; i < opts.length; i += 2) {
  if (opts[i] === "--count") count = Number(opts[i + 1]);
  else if (opts[i] === "--stale-ms") staleMs = Number(opts[i + 1]);
  else bad = true;
}
if (bad || !(staleMs > 0) || !Number.isInteger(count) || count < 0) {
  console.error("usage: node node_subscriber.mjs ENDPOINT SENSOR [--count N] [--stale-ms M]");
  process.exit(2);
}

const wantRange = `range/${sensor}/`;
const wantHealth = `health/${sensor}/`;
// A longer message is not lunad's (its own are at most 64 KiB): libzmq does not read it.
const sub = new Subscriber({ linger: 0, maxMessageSize: 1 << 20 });
sub.connect(endpoint);
// The final "/" makes ZeroMQ's prefix match exact: range/front/ never gets range/frontleft/.
sub.subscribe(wantRange, wantHealth);

// JSON.parse turns every number into a double: t_unix_ns (always above 2^53) and t_mono_ns
// (after 104 days of uptime) would lose their last digits. Read them from the text instead.
const bigField = (text, key) => {
  const m = new RegExp(`"${key}"\\s*:\\s*(-?\\d+)`).exec(text);
  return m ? BigInt(m[1]) : undefined;
};

let received = 0, lost = 0, dups = 0, lastRun = null, last = 0;
let deadline = performance.now() + staleMs; // the silence clock starts now (monotonic)
let timer;
const finish = (code, line) => {
  if (line) console.log(line);
  console.log(`received ${received} lost ${lost} duplicates ${dups}`);
  sub.close();
  process.exit(code);
};
const arm = () => {
  clearTimeout(timer);
  const left = Math.max(0, deadline - performance.now());
  timer = setTimeout(() => finish(3, `STALE no reading for ${staleMs} ms`), left);
};
arm();
for (const sig of ["SIGINT", "SIGTERM"]) process.on(sig, () => finish(0));

for await (const parts of sub) {
  if (parts.length !== 2) continue; // lunad's messages: a topic, then JSON
  const topic = parts[0].toString();
  const text = parts[1].toString();
  if (topic !== wantRange && topic !== wantHealth) continue; // exact topics only
  let msg;
  try {
    msg = JSON.parse(text);
  } catch {
    console.error("malformed");
    continue;
  }
  if (msg?.v !== 2) {
    console.error("not schema v2");
    continue;
  }
  if (topic === wantHealth) {
    console.error(`health ${msg.state}`); // about once a second
    continue;
  }
  msg.t_mono_ns = bigField(text, "t_mono_ns"); // exact, as BigInt: use these, not doubles
  msg.t_unix_ns = bigField(text, "t_unix_ns");
  // seq as a Number is exact up to 2^53: 1.1 million years at 250 Hz.
  const ok = Number.isSafeInteger(msg.seq) && msg.seq >= 0 && Number.isSafeInteger(msg.frames)
    && msg.frames >= 1 && typeof msg.run === "string" && typeof msg.status === "string"
    && msg.sensor === sensor && (msg.range_m === null || Number.isFinite(msg.range_m))
    && (msg.sigma_m === null || Number.isFinite(msg.sigma_m))
    && (msg.status === "dropout") === (msg.range_m === null) // null exactly on a dropout
    && (msg.status === "dropout") === (msg.sigma_m === null)
    && typeof msg.cached === "boolean" && Number.isInteger(msg.age_ms) && msg.age_ms >= 0;
  if (!ok) {
    console.error("malformed");
    continue;
  }
  if (msg.run === lastRun) { // same run: seq rules; a new run starts the count again
    if (msg.seq <= last) { dups++; continue; } // e.g. the cache re-sent one we had
    lost += Math.max(0, msg.seq - last - msg.frames); // folded frames are not loss
  }
  lastRun = msg.run;
  last = msg.seq;
  received++;
  // A cached reading (the last-value cache's answer to our arrival) was made age_ms ago,
  // so an old one is no sign of life: the silence clock counts from its making.
  const made = performance.now() - (msg.cached ? msg.age_ms : 0);
  deadline = Math.max(deadline, made + staleMs);
  arm();
  if (msg.cached && msg.age_ms > staleMs) { // older than our own limit: stale, as the
    msg.range_m = null; // daemon marks a cached one older than its own
    msg.status = "dropout";
  }
  const range = msg.range_m === null ? "null" : msg.range_m.toFixed(4); // null: dropout
  console.log(`${msg.seq} ${range} ${msg.status}${msg.cached ? " cached" : ""}`);
  if (count && received >= count) finish(0);
}
