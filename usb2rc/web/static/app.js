// usb2rc's status page: renders each record of the live stream (/api/events, server-sent
// events). Text from devices (names) only ever goes in as textContent, never as HTML.
"use strict";

const AXIS_MIN = -32768, AXIS_SPAN = 65535;
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

function axisRow(nodeId, name, value) {
  const frac = (value - AXIS_MIN) / AXIS_SPAN;           // 0..1
  const left = Math.min(frac, 0.5), width = Math.abs(frac - 0.5);
  const fill = el("div", { class: "fill" });
  fill.style.left = (left * 100).toFixed(1) + "%";
  fill.style.width = (width * 100).toFixed(1) + "%";
  return el("div", { class: "axis", "data-node": nodeId, "data-axis": name, "data-value": value },
    el("span", {}, name), el("div", { class: "track" }, fill), el("span", { class: "num" }, value));
}

function nodeCard(node) {
  const card = el("article", {
    class: "node" + (node.failsafe ? " failsafe" : ""),
    "data-node": node.node_id, "data-status": node.status, "data-failsafe": node.failsafe,
  });
  const label = node.failsafe ? "! FAILSAFE" : node.status;
  card.append(el("h3", {}, "Node " + node.node_id, el("span", { class: "status" }, label)));
  for (const why of node.waiting_for) card.append(el("div", { class: "waits" }, "waits for " + why));
  for (const dev of node.devices) {
    card.append(el("div", { class: "dim" }, dev.name + " " + dev.vid_pid + (dev.present ? "" : " (unplugged)")));
  }
  for (const [name, value] of Object.entries(node.axes)) {
    if (value !== 0 || ["x", "y", "z", "rz", "slider"].includes(name)) card.append(axisRow(node.node_id, name, value));
  }
  const buttons = node.buttons.length ? node.buttons.join(" ") : "none";
  card.append(el("div", {}, el("span", { class: "dim" }, "buttons "), buttons,
    el("span", { class: "dim" }, "  hat "), node.hat));
  return card;
}

function table(id, head, rows) {
  const target = document.getElementById(id);
  target.replaceChildren(el("tr", {}, ...head.map((h) => el("th", {}, h))),
    ...rows.map((row) => el("tr", {}, ...row.map((cell) => el("td", {}, cell)))));
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
  return parts.join(", ") || "-";
}

function render(record) {
  const badge = document.getElementById("connection");
  const live = record.web && record.web.connected;
  badge.className = "badge " + (live ? "on" : "off");
  badge.dataset.connected = String(Boolean(live));
  badge.dataset.connects = record.web ? record.web.connects : 0;
  badge.textContent = live ? "live" : "daemon not running: retrying (" + (record.web ? record.web.error : "") + ")";
  if (!live) {
    document.getElementById("nodes").replaceChildren(el("p", { class: "dim" }, "no data from the daemon"));
    return;
  }
  const now = Date.now();
  const stats = record.stats;
  document.getElementById("uptime").textContent = "up " + Math.round(stats.uptime_s) + " s";
  document.getElementById("nodes").replaceChildren(...record.nodes.map(nodeCard));
  table("outputs", ["output", "port", "ticks", "late", "stalls", "queue full", "link"],
    stats.outputs.map((o) => [o.name, o.url, o.ticks, o.late_ticks, o.stalls, o.queue_full_skips, linkText(o, now)]));
  const reports = new Map(stats.devices.map((d) => [d.name, d]));
  table("devices", ["device", "vid:pid", "node", "entry", "reports/s"],
    record.devices.map((d) => [d.name + (d.present ? "" : " (unplugged)"), d.vid_pid, d.node_id, d.entry,
      reports.has(d.name) ? reports.get(d.name).reports_per_s.toFixed(0) : "-"]));
  document.getElementById("events").replaceChildren(...record.events.slice().reverse().map((e) =>
    el("li", {}, "node " + e.node_id + ": " + e.kind + (e.device ? " " + e.device : "") +
      (e.error_code !== undefined ? " 0x" + e.error_code.toString(16) : ""))));
  const check = record.check;
  document.getElementById("check").replaceChildren(
    el("div", {}, check.source + ": " + (check.ok ? "OK" : "errors")),
    ...check.warnings.map((w) => el("div", { class: "warning" },
      (w.file || "") + ":" + (w.line || "") + ": " + (w.key || "") + ": warning: " + w.message)),
    el("pre", {}, check.summary.join("\n")));
}

function connect() {
  const stream = new EventSource("/api/events");
  stream.onmessage = (event) => render(JSON.parse(event.data));
  stream.onerror = () => {
    // the web server itself is gone: EventSource retries by itself; say so meanwhile
    const badge = document.getElementById("connection");
    badge.className = "badge off";
    badge.dataset.connected = "false";
    badge.textContent = "web server unreachable: retrying";
  };
}

connect();
