// usb2rc's status page: renders each record of the live stream (/api/events, server-sent
// events). Text from devices (names) only ever goes in as textContent, never as HTML.
// The header badge is the daemon's state (its nodes and outputs), not the page's own link.
"use strict";

const AXIS_MIN = -32768, AXIS_SPAN = 65535;
// The C2-16B status byte a node sends, in words (docs/ICD.md, "Status priority").
const STATUS_WORDS = { ">": "live", "!": "failsafe", "&": "handover", "%": "low battery" };
const heartbeats = new Map(); // output name -> [count, time it last changed]

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (key === "class") node.className = value; else node.setAttribute(key, value);
  }
  for (const child of children) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : String(child));
  }
  return node;
}

// The children with a space between each (a row's items: flex lays them out, and its copied
// text still reads as words)
function spaced(...children) {
  return children.filter((c) => c !== null && c !== undefined).flatMap((c, i) => (i ? [" ", c] : [c]));
}

function count(n, noun) {
  return n + " " + noun + (n === 1 ? "" : "s");
}

function axisRow(nodeId, name, value) {
  const frac = (value - AXIS_MIN) / AXIS_SPAN;           // 0..1
  const left = Math.min(frac, 0.5), width = Math.abs(frac - 0.5);
  const fill = el("div", { class: "fill" });
  fill.style.left = (left * 100).toFixed(1) + "%";
  fill.style.width = (width * 100).toFixed(1) + "%";
  return el("div", { class: "axis", "data-node": nodeId, "data-axis": name, "data-value": value },
    el("span", {}, name), el("div", { class: "track" }, fill), el("span", { class: "num" }, value));
}

function buttonsRow(node) {
  const row = el("div", { class: "buttons" });
  if (!node.buttons.length) {
    row.append(el("span", { class: "dim" }, "no button pressed"));
  } else {
    row.append(el("span", { class: "dim" }, "pressed "));
    for (const b of node.buttons) row.append(el("span", { class: "chip", "data-button": b }, "button " + b));
  }
  row.append(el("span", { class: "dim" }, " · hat "), node.hat);
  return row;
}

function nodeCard(node) {
  const card = el("article", {
    class: "node" + (node.failsafe ? " failsafe" : ""),
    "data-node": node.node_id, "data-status": node.status, "data-failsafe": node.failsafe,
  });
  const words = node.failsafe ? "failsafe" : (STATUS_WORDS[node.status] || "");
  card.append(el("h3", {}, "Node " + node.node_id, el("span", { class: "status" }, node.status + " " + words)));
  for (const why of node.waiting_for) card.append(el("div", { class: "waits" }, "waits for " + why));
  for (const dev of node.devices) {
    card.append(el("div", { class: "dim" }, dev.name + " " + dev.vid_pid + (dev.present ? "" : " (unplugged)")));
  }
  for (const [name, value] of Object.entries(node.axes)) {
    if (value !== 0 || ["x", "y", "z", "rz", "slider"].includes(name)) card.append(axisRow(node.node_id, name, value));
  }
  card.append(buttonsRow(node));
  return card;
}

function linkText(out, now) {
  const parts = [];
  if (out.module) parts.push(out.module);
  if (out.link_quality_up !== undefined && out.link_quality_up !== null) parts.push("LQ " + out.link_quality_up + "%");
  if (out.far_end_heartbeats !== undefined) {
    const last = heartbeats.get(out.name);
    if (!last || last[0] !== out.far_end_heartbeats) heartbeats.set(out.name, [out.far_end_heartbeats, now]);
    const seen = out.far_end_heartbeats ? ((now - heartbeats.get(out.name)[1]) / 1000).toFixed(1) + " s ago" : "none yet";
    parts.push("heartbeat " + seen);
  }
  return parts.join(", ");
}

function failsafeText(out) {
  const nodes = out.failsafe_nodes.length ? " for node " + out.failsafe_nodes.join(", ") : "";
  return "sending failsafe" + nodes;
}

function outputCard(out, now) {
  const open = out.port_open !== false;
  const state = !open ? "port not open" : out.failsafe ? "FAILSAFE" : "sending";
  const card = el("article", {
    class: "output" + (open && !out.failsafe ? "" : " bad"),
    "data-output": out.name, "data-open": open, "data-failsafe": out.failsafe, "data-writes": out.writes,
  });
  card.append(el("h3", {}, out.name, el("span", { class: "state" }, state)));
  card.append(el("div", { class: "port" }, el("span", { class: "dim" }, "port "), out.url,
    out.port_from === "--port" ? el("span", { class: "dim" }, " (from --port)") : null));
  if (!open) card.append(el("div", { class: "problem" }, "not open: " + out.port_error));
  else if (out.failsafe) card.append(el("div", { class: "problem" }, failsafeText(out)));
  card.append(el("div", { class: "counters" },
    "writes " + out.writes + " · ticks " + out.ticks + " · late " + out.late_ticks +
    " · stalls " + out.stalls + " · queue full " + out.queue_full_skips));
  const age = out.input_age_ms;
  if (age) card.append(el("div", { class: "age", "data-age-max": age.max },
    "input age p50 " + age.p50.toFixed(1) + " · p99 " + age.p99.toFixed(1) + " · max " + age.max.toFixed(1) + " ms"));
  const link = linkText(out, now);
  if (link) card.append(el("div", { class: "dim" }, link));
  return card;
}

// --- Telemetry & feedback (docs/CONFIG.md "Feedback", docs/ICD.md "Downlink") ----------
const TELEMETRY_STALE_S = 3;  // CRSF or MAVLink silent this long: its values are unknown
// [source, label, unit, digits] in the order a row shows them (null digits: as it comes)
const TELEMETRY_FIELDS = {
  crsf: [["link_quality", "LQ", " %", null], ["rssi", "RSSI", " dBm", null], ["snr", "SNR", " dB", null],
    ["battery_voltage", "battery", " V", 1], ["battery_remaining", "", " %", null], ["flight_mode", "mode", "", null]],
  mavlink: [["armed", "", "", null], ["mode", "mode", "", null], ["battery_voltage", "battery", " V", 1],
    ["battery_remaining", "", " %", null], ["failsafe", "failsafe", "", null]],
};
const SOURCE_NAMES = { crsf: "CRSF", mavlink: "MAVLink" };

function seconds(s) {
  return s.toFixed(1) + " s ago";
}

function telemetryValue(source, key, value) {
  if (value === null || value === undefined) return "--";
  if (source === "mavlink" && key === "armed") return value ? "ARMED" : "disarmed";
  if (typeof value === "boolean") return value ? "yes" : "no";
  return value;
}

function telemetryChip(source, [key, label, unit, digits], values) {
  const value = values[source + "." + key];
  let shown = telemetryValue(source, key, value);
  if (typeof shown === "number" && digits !== null) shown = shown.toFixed(digits);
  const known = value !== null && value !== undefined;
  return el("span", { class: "tv" + (known ? "" : " dim"), "data-key": source + "." + key, "data-value": String(value) },
    (label ? label + " " : "") + shown + (known ? unit : ""));
}

// A source's row: its values, or that it was never heard or went quiet.
// A row: its label in the first column, its items wrapping in the second.
function labelled(label, attrs, items) {
  return el("div", attrs, el("span", { class: "src" }, label), " ", el("div", { class: "vals" }, ...spaced(...items)));
}

function telemetryRow(source, values) {
  const age = values[source + ".age"];
  const state = age === null || age === undefined ? "not-heard" : age >= TELEMETRY_STALE_S ? "stale" : "fresh";
  let shown;
  if (state === "not-heard") shown = [el("span", { class: "dim" }, "not heard")];
  else if (state === "stale") shown = [el("span", { class: "stale-word" }, "stale: nothing for " + age.toFixed(1) + " s")];
  else shown = [...TELEMETRY_FIELDS[source].map((field) => telemetryChip(source, field, values)),
    el("span", { class: "dim" }, seconds(age))];
  return labelled(SOURCE_NAMES[source], { class: "telemetry " + state, "data-source": source, "data-state": state }, shown);
}

// Each node's downlink: fresh (1 s) or stale, with the age of its last frame.
function downlinkRows(values, c2) {
  const rows = [];
  for (const [key, age] of Object.entries(values)) {
    const match = /^node(\d+)\.downlink_age$/.exec(key);
    if (!match) continue;
    const fresh = values["node" + match[1] + ".downlink"] === true;
    const state = fresh ? "fresh" : "stale";
    rows.push(labelled("node " + match[1], { class: "telemetry " + state, "data-downlink": match[1], "data-state": state },
      [el("span", { class: fresh ? "" : "stale-word" }, "downlink " + state), el("span", { class: "dim" }, seconds(age))]));
  }
  if (!rows.length && c2) rows.push(labelled("downlink", { class: "telemetry not-heard", "data-downlink": "none", "data-state": "not-heard" },
    [el("span", { class: "dim" }, "none heard")]));
  return rows;
}

function telemetryCard(record, values) {
  const protocols = new Set(record.stats.outputs.map((o) => o.protocol));
  const sources = ["crsf", "mavlink"].filter((s) => protocols.has(s) || values[s + ".age"] != null);
  const rows = [...sources.map((s) => telemetryRow(s, values)), ...downlinkRows(values, protocols.has("c2-16b"))];
  return el("article", { class: "fb", id: "telemetry" }, el("h3", {}, "Telemetry"),
    ...(rows.length ? rows : [el("div", { class: "dim" }, "no output hears telemetry")]));
}

function rulesCard(actions) {
  const rows = actions.map((a) => labelled("rule " + a.rule, { class: "action", "data-rule": a.rule },
    [el("span", { class: "dim", title: a.where }, a.where.replace(/^.*\//, "")), el("span", {}, a.did),
      el("span", { class: "dim" }, seconds(a.ago_s))]));
  return el("article", { class: "fb", id: "actions" }, el("h3", {}, "Rules' last actions"),
    ...(rows.length ? rows : [el("div", { class: "dim" }, "no rule has acted yet")]));
}

function outputCounts(stats) {
  if (!stats || stats.outputs_written === undefined) return el("div", { class: "dim" }, "no output written yet");
  return el("div", { class: "writes" + (stats.outputs_refused ? " problem" : "") },
    "outputs written " + stats.outputs_written + " · refused " + stats.outputs_refused +
    (stats.output_error ? " (" + stats.output_error + ")" : ""));
}

function drivenCard(device, stats) {
  const card = el("article", { class: "fb", "data-driven": device.name }, el("h3", {}, device.name));
  const chips = device.lit.map((name) => el("span", { class: "chip led", "data-lit": name }, name));
  card.append(el("div", { class: "lit" }, ...spaced(
    el("span", { class: "dim" }, chips.length ? "lit" : "nothing lit"), ...chips,
    device.indicators ? el("span", { class: "dim" }, "(of " + count(device.indicators, "indicator") + ")") : null)));
  const analog = Object.entries(device.analog).map(([name, value]) =>
    el("span", { class: "tv", "data-analog": name, "data-value": value }, name.replace(/_/g, " ") + " " + value.toFixed(2)));
  if (analog.length) card.append(el("div", { class: "analog" }, ...spaced(...analog)));
  device.texts.forEach((text, i) => {
    if (text) card.append(el("div", { class: "text-line", "data-line": i + 1 }, el("span", { class: "dim" }, "line " + (i + 1) + ": "), text));
  });
  card.append(outputCounts(stats));
  return card;
}

// The section shows only when the daemon judges feedback (it has outputs): no key, no card.
function feedbackPanel(record) {
  const feedback = record.stats.feedback;
  const section = document.getElementById("feedback-section");
  section.hidden = !feedback;
  if (!feedback) {
    document.getElementById("feedback").replaceChildren();
    return;
  }
  const reports = new Map(record.stats.devices.map((d) => [d.name, d]));
  document.getElementById("feedback").replaceChildren(telemetryCard(record, feedback.telemetry),
    rulesCard(feedback.actions), ...feedback.devices.map((d) => drivenCard(d, reports.get(d.name))));
}

function devicesTable(record) {
  const reports = new Map(record.stats.devices.map((d) => [d.name, d]));
  const head = ["device", "vid:pid", "node", "entry", "reports/s"];
  const rows = record.devices.map((d) => [d.name + (d.present ? "" : " (unplugged)"), d.vid_pid, d.node_id, d.entry,
    reports.has(d.name) ? reports.get(d.name).reports_per_s.toFixed(0) : "-"]);
  document.getElementById("devices").replaceChildren(el("tr", {}, ...head.map((h) => el("th", {}, h))),
    ...rows.map((row) => el("tr", {}, ...row.map((cell, i) => el("td", { "data-label": head[i] }, cell)))));
}

function portLine(out) {
  const whence = out.port_from === "--port"
    ? " (from --port" + (out.config_port ? "; the config says " + out.config_port : "") + ")" : "";
  return out.name + ": " + out.url + whence;
}

function checkPanel(record) {
  const check = record.check;
  document.getElementById("check").replaceChildren(
    el("div", {}, check.source + ": " + (check.ok ? "OK" : "errors")),
    el("div", { class: "ports" }, el("span", { class: "dim" }, "ports in use"),
      ...record.stats.outputs.map((o) => el("div", {}, portLine(o)))),
    ...check.warnings.map((w) => el("div", { class: "warning" },
      (w.file || "") + ":" + (w.line || "") + ": " + (w.key || "") + ": warning: " + w.message)),
    el("pre", {}, check.summary.join("\n")));
}

// The daemon's state for the header: [data-state, words]. Worst first in data-state.
function daemonState(record) {
  const failsafe = record.nodes.filter((n) => n.failsafe).length;
  const closed = record.stats.outputs.filter((o) => o.port_open === false).length;
  const parts = [];
  if (failsafe) parts.push(count(failsafe, "node") + " in failsafe");
  if (closed) parts.push(count(closed, "output") + " not sending (port not open)");
  if (!record.nodes.length) parts.push("no nodes yet");
  const state = failsafe ? "failsafe" : closed ? "not-sending" : record.nodes.length ? "all-live" : "no-nodes";
  return [state, parts.join(" · ") || "all live"];
}

function setBadge(state, text, connected, connects) {
  const badge = document.getElementById("connection");
  badge.className = "badge " + state;
  badge.dataset.state = state;
  badge.dataset.connected = String(connected);
  if (connects !== undefined) badge.dataset.connects = connects;
  badge.textContent = text;
}

function renderAway(web) {
  setBadge("no-daemon", "daemon not running", false, web ? web.connects : 0);
  document.getElementById("uptime").textContent = "";
  const why = web && web.error ? web.error + ": " : "";
  document.getElementById("nodes").replaceChildren(
    el("p", { class: "problem" }, "no data from the daemon (" + why + "retrying)"),
    el("p", { class: "dim", id: "hint" }, web ? web.hint : ""));
  for (const id of ["outputs", "feedback", "devices", "events", "check"]) document.getElementById(id).replaceChildren();
  document.getElementById("feedback-section").hidden = true;
}

function render(record) {
  const web = record.web;
  if (!web || !web.connected) {
    renderAway(web);
    return;
  }
  const [state, text] = daemonState(record);
  setBadge(state, text, true, web.connects);
  const now = Date.now();
  const cpu = record.stats.cpu_pct;  // % of one core since start (null: not known)
  document.getElementById("uptime").textContent =
    "up " + Math.round(record.stats.uptime_s) + " s" + (cpu == null ? "" : ", CPU " + cpu.toFixed(1) + " % of a core");
  document.getElementById("nodes").replaceChildren(...record.nodes.map(nodeCard));
  document.getElementById("outputs").replaceChildren(...record.stats.outputs.map((o) => outputCard(o, now)));
  feedbackPanel(record);
  devicesTable(record);
  document.getElementById("events").replaceChildren(...record.events.slice().reverse().map((e) =>
    el("li", {}, "node " + e.node_id + ": " + e.kind + (e.device ? " " + e.device : "") +
      (e.error_code !== undefined ? " 0x" + e.error_code.toString(16) : ""))));
  checkPanel(record);
}

function connect() {
  const stream = new EventSource("/api/events");
  stream.onmessage = (event) => render(JSON.parse(event.data));
  // the web server itself is gone: EventSource retries by itself; say so meanwhile
  stream.onerror = () => setBadge("no-web", "web server unreachable: retrying", false);
}

connect();
