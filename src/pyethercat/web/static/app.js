/* pyethercat dashboard: one page, seven views, fed by the /ws WebSocket.
 *
 * The server sends the segment (static: slaves, ports, PDO entries) and the
 * history when the socket opens, then one "live" message per poll. Views are
 * drawn from the last message when shown and on every message while shown.
 * No inline code, no secrets in the page: the token (when there is one) is
 * an HttpOnly cookie the server set, sent by the browser on its own.
 */
"use strict";

const S = {
  segment: null, live: null, page: "topology", charts: {}, series: {}, events: [],
  writesEnabled: false, sdoPosition: null, mbxSlave: null, browseSeq: 0, lastMessage: 0, connected: false,
};
const MAX_POINTS = 600;
const STATE_ORDER = ["INIT", "PREOP", "BOOT", "SAFEOP", "OP"];
const PAGE_TITLES = {
  topology: "Topology", slaves: "Slaves", pdo: "Process data", cycle: "Cycle",
  dc: "Distributed clocks", drives: "Drives", mailbox: "Mailbox",
};
const PALETTE = ["#2f6fde", "#d64545", "#1f9d55", "#d69e2e", "#805ad5", "#0f8a9d", "#c05621",
                 "#4a5568", "#b83280", "#2c7a7b", "#6b46c1", "#975a16"];

/* ---------- small DOM helpers ---------- */
function $(id) { return document.getElementById(id); }
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  if (attrs) {
    for (const [k, v] of Object.entries(attrs)) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") e.className = v;
      else if (k === "text") e.textContent = v;
      else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
      else e.setAttribute(k, v === true ? "" : v);
    }
  }
  for (const c of children) {
    if (c === null || c === undefined) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}
const SVGNS = "http://www.w3.org/2000/svg";
function sv(tag, attrs, text) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}
function hex(v, w) { return v === null || v === undefined ? "–" : "0x" + v.toString(16).toUpperCase().padStart(w || 4, "0"); }
function fmt(v, digits) {
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  if (typeof v === "number") return digits === undefined ? String(v) : v.toFixed(digits);
  return String(v);
}
function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); }
function stateClass(name, answered) {
  if (!answered) return "LOST";
  if (name.includes("ERR")) return "ERR";
  const base = name.split("+")[0];
  return STATE_ORDER.includes(base) ? base : "INIT";
}
function slaveName(pos) {
  const s = S.segment && S.segment.slaves[pos];
  return s ? s.name : "slave " + pos;
}
/* One formatter for all: toLocaleTimeString builds a new one per call, which took most of
   the page's time once a few hundred events were listed. */
const CLOCK = new Intl.DateTimeFormat([], { hour: "2-digit", minute: "2-digit", second: "2-digit", hour12: false });
function timeText(t) {
  const d = new Date(t * 1000);
  return CLOCK.format(d) + "." + String(d.getMilliseconds()).padStart(3, "0");
}

/* ---------- API ---------- */
async function api(path, body) {
  const opts = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const r = await fetch(path, opts);
  const type = r.headers.get("content-type") || "";
  if (!r.ok) {
    const j = type.includes("json") ? await r.json() : { error: r.statusText };
    throw new Error(j.error || ("HTTP " + r.status));
  }
  return type.includes("json") ? r.json() : r.blob();
}

/* ---------- live connection ---------- */
function connect() {
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
  ws.addEventListener("open", () => { S.connected = true; });
  ws.addEventListener("message", (ev) => {
    const m = JSON.parse(ev.data);
    S.lastMessage = Date.now();
    if (m.type === "segment") onSegment(m);
    else if (m.type === "history") onHistory(m);
    else if (m.type === "live") onLive(m);
    else if (m.type === "error") showBanner("master: " + m.text);
  });
  ws.addEventListener("close", (ev) => {
    S.connected = false;
    showBanner(ev.code === 1008 ? "refused: " + (ev.reason || "this dashboard needs its token")
      : "connection to the dashboard lost; retrying…");
    if (ev.code !== 1008) setTimeout(connect, 1500);
  });
}
function showBanner(text) {
  const b = $("banner");
  if (!text) { b.classList.add("hidden"); return; }
  b.textContent = text; b.classList.remove("hidden");
}

function onSegment(seg) {
  S.segment = seg;
  $("linkname").textContent = seg.link;
  $("navfoot").textContent = seg.writable ? "writes allowed (token)" : "read-only";
  buildPdo(); buildMailbox(); buildTopologyLegend();
  render();
}
function onHistory(h) {
  S.series = {};
  for (const [k, rows] of Object.entries(h.series)) S.series[k] = rows.slice(-MAX_POINTS);
  S.events = h.events.slice(-500);
  eventsShown = null;
}
function push(name, row) {
  const s = S.series[name] || (S.series[name] = []);
  s.push(row);
  if (s.length > MAX_POINTS) s.splice(0, s.length - MAX_POINTS);
}
let lastCounts = null;
function onLive(m) {
  showBanner(m.registers_error ? m.registers_error : "");
  S.live = m;
  const c = m.cycle;
  const now = [c.late, c.wkc_errors, c.lost_frames];
  const delta = lastCounts ? now.map((v, i) => Math.max(0, v - lastCounts[i])) : [0, 0, 0];
  lastCounts = now;
  const t = Math.round(m.time * 1000) / 1000;
  push("cycle", [t, c.period_mean_us, c.jitter_p99_us, c.jitter_max_us, c.rtt_p50_us, c.rtt_p99_us, ...delta]);
  push("dc", [t, ...m.slaves.map((s) => s.dc_difference_ns)]);
  for (const d of m.drives) push("drive" + d.position, [t, d.position_actual, d.following_error, d.velocity]);
  for (const e of m.events) S.events.push(e);
  if (S.events.length > 500) S.events.splice(0, S.events.length - 500);
  render();
}

/* ---------- header chips ---------- */
function renderChips() {
  const chips = $("chips");
  clear(chips);
  const m = S.live;
  if (!m || !S.segment) { chips.append(el("span", { class: "chip" }, "waiting for data…")); return; }
  const c = m.cycle;
  const inOp = m.slaves.filter((s) => s.answered && s.state === "OP" && !s.error).length;
  const lost = m.slaves.filter((s) => !s.answered).length;
  chips.append(el("span", { class: "chip " + (c.running ? "good" : "warn"), id: "chip-cycle" },
    c.running ? `cycling ${fmt(c.period_us)} µs` : "not cycling"));
  if (c.link_up !== null) chips.append(el("span", { class: "chip " + (c.link_up ? "good" : "bad") }, c.link_up ? "link up" : "LINK DOWN"));
  chips.append(el("span", { class: "chip " + (inOp === m.slaves.length ? "good" : "bad"), id: "chip-op" },
    el("b", null, `${inOp}/${m.slaves.length}`), " slaves in OP"));
  if (lost) chips.append(el("span", { class: "chip bad" }, `${lost} not answering`));
  const wkcBad = m.groups.some((g) => !g.ok);
  if (m.groups.length) chips.append(el("span", { class: "chip " + (wkcBad ? "bad" : "good") }, wkcBad ? "WKC wrong" : "WKC ok"));
  chips.append(el("span", { class: "chip", id: "chip-time" }, "updated " + timeText(m.time)));
}

/* ---------- topology ---------- */
function buildTopologyLegend() {
  const lg = $("topo-legend");
  clear(lg);
  for (const s of ["OP", "SAFEOP", "PREOP", "INIT", "ERR", "LOST"])
    lg.append(el("span", null, el("i", { class: s }), s === "LOST" ? "not answering" : s === "ERR" ? "error" : s));
  lg.append(el("span", null, "— — broken link"));
}
function treeOrder() {
  /* Rows in the order a frame meets the slaves (ports 0 -> 3 -> 1 -> 2); branches indent. */
  const seg = S.segment;
  const rows = [];
  const visit = (pos, depth, via) => {
    rows.push({ pos, depth, via });
    const ch = seg.slaves[pos].children;
    for (const port of ["3", "2"]) if (ch[port] !== undefined) visit(ch[port], depth + 1, Number(port));
    if (ch["1"] !== undefined) visit(ch["1"], depth, 1);
  };
  const roots = seg.slaves.filter((s) => s.parent === null);
  if (roots.length) visit(roots[0].position, 0, null);
  for (const s of seg.slaves) if (!rows.some((r) => r.pos === s.position)) rows.push({ pos: s.position, depth: 0, via: null });
  return rows;
}
function renderTopology() {
  const host = $("topo");
  if (!S.segment) return;
  const live = S.live;
  const rows = treeOrder();
  const W = 420, H = 48, GAP = 16, INDENT = 56, X0 = 150, Y0 = 22;
  const maxDepth = Math.max(0, ...rows.map((r) => r.depth));
  const width = X0 + maxDepth * INDENT + W + 520;
  const marks = [];
  const height = Y0 + rows.length * (H + GAP) + 30;
  const svg = sv("svg", { width, height, viewBox: `0 0 ${width} ${height}`, id: "topo-svg" });
  const at = {};
  rows.forEach((r, i) => { at[r.pos] = { x: X0 + r.depth * INDENT, y: Y0 + i * (H + GAP), row: r }; });
  const links = live ? live.links : [];
  const broken = new Map(links.map((l) => [l.to, l]));
  /* master */
  const m = sv("g", { class: "master" });
  m.append(sv("rect", { x: 10, y: Y0, width: 100, height: H, rx: 6 }));
  m.append(sv("text", { x: 60, y: Y0 + 20, "text-anchor": "middle" }, "Master"));
  const portText = (live && live.ports.length)
    ? live.ports.map((p) => `${p.name}:${p.returning ? "ok" : "—"}`).join(" · ") : (S.segment.redundant ? "ports A · B" : "port A");
  m.append(sv("text", { x: 60, y: Y0 + 36, "text-anchor": "middle", "font-size": "10" }, portText));
  svg.append(m);
  /* edges first, under the nodes */
  for (const r of rows) {
    const s = S.segment.slaves[r.pos];
    const me = at[r.pos];
    const info = broken.get(r.pos);
    const isBroken = info ? info.broken : false;
    let d, lx, ly, label;
    if (s.parent === null) {
      d = `M110 ${Y0 + H / 2} L${me.x} ${me.y + H / 2}`;
      lx = 116; ly = Y0 + H / 2 - 6; label = "A → 0";
    } else {
      const p = at[s.parent];
      if (s.parent_port === 1) {
        const x = p.x + 24;
        d = `M${x} ${p.y + H} L${x} ${me.y}`;
        lx = x + 6; ly = me.y - 4; label = "1 → 0";
      } else {
        const x = p.x + 24;
        d = `M${x} ${p.y + H} L${x} ${me.y + H / 2} L${me.x} ${me.y + H / 2}`;
        lx = x + 6; ly = me.y + H / 2 - 5; label = `${s.parent_port} → 0`;
      }
    }
    const crc = info && info.crc;
    svg.append(sv("path", { d, class: "edge" + (isBroken ? " broken" : crc ? " crc" : ""), "data-to": r.pos, "data-broken": isBroken ? "1" : "0" }));
    svg.append(sv("text", { x: lx, y: ly, class: "edgelabel" }, label));
    if (isBroken) {
      /* drawn after the nodes: a cross on the cable and the text beside the column */
      const mx = s.parent === null ? 125 : at[s.parent].x + 24;
      const my = s.parent === null ? Y0 + H / 2 : me.y - GAP / 2 + (s.parent_port === 1 ? 0 : H / 2 + GAP / 2);
      const where = s.parent === null ? "master port A" : `#${s.parent} ${slaveName(s.parent)} port ${s.parent_port}`;
      marks.push(sv("text", { x: mx - 5, y: my + 5, class: "breaklabel" }, "✕"));
      /* beside the tree, one short line each (the svg grows to the longest, see below) */
      const tx = X0 + maxDepth * INDENT + W + 16;
      /* data-since(-push): the snapshot (its time, its push number) that first showed the cut */
      const text = sv("text", { x: tx, y: my + 4, class: "breaklabel", id: "break-" + r.pos,
        "data-since": info.since === null ? "" : info.since, "data-since-push": info.since_push === null ? "" : info.since_push });
      text.append(sv("tspan", { x: tx }, `✕ link down: #${s.parent === null ? "master" : s.parent} port ${s.parent === null ? "A" : s.parent_port} → #${r.pos} port 0`
        + (info.since ? `  since ${timeText(info.since)}` : "")));
      text.append(sv("tspan", { x: tx + 14, dy: 14, class: "names" }, `${where} → #${r.pos} ${s.name}`));
      marks.push(text);
      /* where the ring service put it, without its details (the list under the drawing has them) */
      if (info.fault) marks.push(sv("text", { x: tx + 14, y: my + 32, class: "edgelabel" }, "located: " + info.fault.split(" (")[0]));
    }
  }
  /* nodes */
  for (const r of rows) {
    const s = S.segment.slaves[r.pos];
    const me = at[r.pos];
    const ls = live ? live.slaves[r.pos] : null;
    const answered = ls ? ls.answered : true;
    const stName = ls ? ls.state_full : "?";
    const cls = ls ? stateClass(stName, answered) : "INIT";
    const side = ls && ls.side ? ls.side : "";
    const g = sv("g", { class: "node" + (answered ? "" : " lost"), id: "node-" + r.pos, "data-state": cls, "data-side": side });
    g.append(sv("rect", { class: "box", x: me.x, y: me.y, width: W, height: H, rx: 6 }));
    g.append(sv("text", { class: "pos", x: me.x + 10, y: me.y + 19 }, "#" + r.pos));
    g.append(sv("text", { x: me.x + 40, y: me.y + 19 }, s.name.length > 44 ? s.name.slice(0, 43) + "…" : s.name));
    /* In a ring, the master port this slave's answers come back on (B: the ring is open before it). */
    const via = S.segment.redundant && side ? ` · via ${side}` : "";
    g.append(sv("text", { class: "sub" + (side === "B" ? " via-b" : ""), x: me.x + 40, y: me.y + 36 },
      `${hex(s.station)} · ${hex(s.vendor, 8)}:${hex(s.product, 8)}` + (ls && ls.code ? ` · AL ${hex(ls.code)}` : "") + via));
    const label = answered ? stName : "NO ANSWER";
    const bw = 74;
    g.append(sv("rect", { class: "state", x: me.x + W - bw - 8, y: me.y + 8, width: bw, height: 16, rx: 3, fill: cssColor(cls) }));
    g.append(sv("text", { class: "state", x: me.x + W - bw / 2 - 8, y: me.y + 20, "text-anchor": "middle" }, label));
    /* port dots: green link, grey none, red expected cable without link */
    const ports = ls ? ls.ports : s.ports.map((p) => ({ n: p.n, implemented: p.implemented, known: false }));
    ports.forEach((p, k) => {
      if (!p.implemented) return;
      const cabled = (s.parent !== null || p.n === 0) && p.n === 0 || s.children[String(p.n)] !== undefined;
      let fill = "#cfd6df", link = p.known ? "none" : "unknown";
      if (p.known && p.link) { fill = "#1f9d55"; link = "up"; }
      else if (p.known && cabled) { fill = "#d64545"; link = "down"; }
      const cx = me.x + W - 82 + k * 20, cy = me.y + 35;
      g.append(sv("circle", { class: "port", cx, cy, r: 5, fill, "data-port": p.n, "data-link": link }));
      g.append(sv("text", { class: "sub", x: cx + 7, y: cy + 4, "font-size": "9" }, String(p.n)));
    });
    svg.append(g);
  }
  for (const mk of marks) svg.append(mk);
  clear(host);
  host.append(svg);
  /* long names or a long fault text: widen the drawing rather than clip it (the card scrolls) */
  const bb = svg.getBBox();
  const need = Math.ceil(bb.x + bb.width + 12);
  const wide = Math.max(width, need + (S.segment.redundant ? 40 : 0));
  if (wide > width) { svg.setAttribute("width", wide); svg.setAttribute("viewBox", `0 0 ${wide} ${height}`); }
  if (S.segment.redundant && rows.length) {
    /* the ring's return from the last slave to master port B, right of everything else */
    const last = at[rows[rows.length - 1].pos];
    const x = wide - 30;
    svg.insertBefore(sv("path", { d: `M${last.x + W} ${last.y + H / 2} L${x} ${last.y + H / 2} L${x} ${Y0 - 10} L60 ${Y0 - 10} L60 ${Y0}`, class: "edge ring" }), svg.firstChild);
    svg.append(sv("text", { x: x - 150, y: Y0 - 14, class: "edgelabel" }, "ring: back to master port B"));
  }
  const faults = live ? live.faults : [];
  const box = el("div", { class: "faults", id: "faults" });
  if (live && live.ring_state && S.segment.redundant) box.append(el("div", { class: "muted" }, "ring: " + live.ring_state));
  for (const f of faults) box.append(el("div", { class: "fault" }, el("b", null, f.kind), " " + f.text + (f.detail ? " — " + f.detail : "")));
  if (live && !faults.length) box.append(el("div", { class: "muted" }, "No fault located (DL status, lost-link and CRC counters of every slave)."));
  host.append(box);
}
function cssColor(cls) {
  return { OP: "#1f9d55", SAFEOP: "#d69e2e", PREOP: "#3182ce", INIT: "#8a94a6", BOOT: "#805ad5", ERR: "#d64545", LOST: "#8b1c1c" }[cls];
}
let eventsShown = null;
function renderEvents() {
  const box = $("events");
  /* The list only changes when an event arrives: redrawn then, not on every message. */
  const last = S.events.length ? S.events[S.events.length - 1].seq : -1;
  if (eventsShown === last && box.firstChild) return;
  eventsShown = last;
  clear(box);
  const list = S.events.slice(-200).reverse();
  if (!list.length) { box.append(el("p", { class: "muted" }, "No events yet.")); return; }
  for (const e of list) {
    box.append(el("div", { class: "event " + e.kind }, el("time", null, timeText(e.time)), el("span", { class: "kind" }, e.kind), el("span", null, e.text)));
  }
}

/* ---------- slaves ---------- */
function renderSlaves() {
  const t = $("slaves-table");
  if (!S.segment) return;
  clear(t);
  const dc = S.live ? Object.fromEntries(S.live.dc.slaves.map((d) => [d.position, d])) : {};
  t.append(el("thead", null, el("tr", null, ...["#", "Station", "Name · identity", "State", "AL status", "Supervision",
    "Port 0", "Port 1", "Port 2", "Port 3", "Errors/s", "DC"].map((h) => el("th", null, h)))));
  const body = el("tbody");
  for (const s of S.segment.slaves) {
    const ls = S.live ? S.live.slaves[s.position] : null;
    const answered = ls ? ls.answered : true;
    const state = ls ? ls.state_full : "?";
    const cls = ls ? stateClass(state, answered) : "INIT";
    const row = el("tr", { class: answered ? "" : "lost", id: "slave-row-" + s.position });
    row.append(el("td", { class: "num" }, s.position));
    row.append(el("td", { class: "mono" }, hex(s.station), s.alias ? el("div", { class: "muted" }, `alias ${s.alias}`) : null));
    /* Identity on two short lines, so the table fits a laptop screen without scrolling. */
    row.append(el("td", { class: "name" }, s.name,
      el("div", { class: "mono muted nowrap" }, `${hex(s.vendor, 8)}:${hex(s.product, 8)}`),
      el("div", { class: "mono muted nowrap" }, `rev ${hex(s.revision, 8)} · sn ${s.serial ?? "–"}`)));
    row.append(el("td", null, el("span", { class: "badge " + cls, "data-state": state }, answered ? state : "NO ANSWER")));
    row.append(el("td", { class: "alstatus" }, ls && ls.code
      ? el("span", { "data-code": ls.code }, el("b", { class: "mono" }, hex(ls.code)), " ", ls.code_text) : el("span", { class: "muted" }, "–")));
    const h = ls ? ls.health : "–";
    row.append(el("td", { class: h === "ok" ? "health-ok" : "health-bad" }, h,
      ls && ls.recoveries ? el("div", { class: "muted nowrap" }, `${ls.recoveries} recovered`) : null));
    for (let n = 0; n < 4; n++) {
      const desc = s.ports[n];
      if (!desc || !desc.implemented) { row.append(el("td", { class: "muted" }, "–")); continue; }
      const p = ls ? ls.ports[n] : null;
      const cnt = ls && ls.counters ? ls.counters.ports[n] : null;
      const dot = el("span", { class: "dot " + (p && p.known ? (p.link ? "up" : "down") : "") });
      const text = p && p.known ? (p.link ? (p.loop_closed ? "link, loop closed" : "link, loop open") : "no link") : "not read";
      const counts = el("span", { class: "counts" + (cnt && cnt.some((x) => x) ? " nz" : "") }, cnt ? cnt.join("/") : "–");
      row.append(el("td", { class: "portcell", title: text, "data-link": p && p.known ? (p.link ? "up" : "down") : "" }, el("span", { class: "port" }, dot, counts)));
    }
    const rate = ls && ls.rates ? ls.rates.reduce((a, b) => a + b, 0) : null;
    row.append(el("td", { class: "num rate" + (rate ? " health-bad" : "") }, rate === null ? "–" : rate.toFixed(1)));
    const d = dc[s.position];
    const ns = (v) => (v === null || v === undefined ? "–" : v + " ns");
    /* delay, offset and |Δt| one under the other: three short lines instead of one wide one */
    const dcLine = (label, v) => el("div", { class: "nowrap" }, el("span", { class: "muted" }, label + " "), ns(v));
    row.append(el("td", { class: "num dc" }, ...(d || (ls && ls.dc_difference_ns !== null)
      ? [dcLine("delay", d && d.delay_ns), dcLine("offset", d && d.offset_ns), dcLine("|Δt|", ls && ls.dc_difference_ns)]
      : ["–"])));
    body.append(row);
  }
  t.append(body);
}

/* ---------- process data ---------- */
function buildPdo() {
  const tb = $("pdo-toolbar");
  clear(tb);
  const seg = S.segment;
  if (!seg.writable) {
    tb.append(el("span", { class: "hint" }, "Read-only dashboard: outputs are shown, not written (start with --allow-writes and a token to write)."));
  } else {
    const box = el("input", { type: "checkbox", id: "pdo-writes" });
    box.addEventListener("change", () => {
      if (box.checked) {
        confirmDialog("Enable output writes?", "Values you enter will be sent to the slaves with the next cycle. Outputs drive real machinery.", "Enable", () => {
          S.writesEnabled = true; renderPdo(true);
        }, () => { box.checked = false; });
      } else { S.writesEnabled = false; renderPdo(true); }
    });
    tb.append(el("label", { class: "switch" }, box, "Enable output writes"));
    tb.append(el("span", { class: "hint" }, "Every write asks for confirmation."));
  }
  const host = $("pdo");
  clear(host);
  if (!seg.pdo.length) { host.append(el("div", { class: "empty" }, seg.configured ? "No process data mapped." : "The master has not configured process data.")); return; }
  for (const slave of seg.pdo) {
    const t = el("table", { class: "grid" });
    t.append(el("thead", null, el("tr", null, ...["Entry", "Object", "Type", "Dir", "Value", ""].map((h) => el("th", null, h)))));
    const body = el("tbody");
    for (const e of slave.entries) {
      const cell = el("td", { class: "value", "data-pos": slave.position, "data-name": e.name }, "–");
      const action = el("td", { class: "action" });
      if (e.output && seg.writable) {
        const input = el("input", { class: "pdo-edit", placeholder: "value", "data-name": e.name });
        const btn = el("button", { type: "button", class: "danger", disabled: true }, "Set");
        btn.addEventListener("click", () => writeOutput(slave.position, e.name, input.value));
        action.append(input, btn);
      }
      body.append(el("tr", null, el("td", { class: "nowrap" }, e.name, e.pdo && !e.name.startsWith(e.pdo + ".") ? el("div", { class: "muted" }, e.pdo) : null),
        el("td", { class: "mono" }, `${hex(e.index)}:${e.subindex.toString(16).toUpperCase().padStart(2, "0")}`),
        el("td", { class: "mono nowrap" }, e.bits > 1 ? `${e.type} · ${e.bits} bit` : e.type),
        el("td", null, el("span", { class: "dir " + (e.output ? "out" : "in") }, e.output ? "out" : "in")),
        cell, action));
    }
    t.append(body);
    host.append(el("div", { class: "card pdo-card", id: "pdo-" + slave.position },
      el("div", { class: "cardhead" }, `#${slave.position} ${slaveName(slave.position)}`, el("span", { class: "hint" }, "group " + slave.group)), t));
  }
}
function renderPdo(buttonsOnly) {
  for (const b of document.querySelectorAll(".pdo-card button")) b.disabled = !S.writesEnabled;
  if (buttonsOnly || !S.live) return;
  const values = S.live.values;
  for (const cell of document.querySelectorAll(".pdo-card td.value")) {
    const list = values[cell.dataset.pos];
    if (!list) continue;
    const found = list.find((x) => x[0] === cell.dataset.name);
    if (found && cell.textContent !== found[1]) cell.textContent = found[1];
  }
}
function writeOutput(pos, name, value) {
  if (!S.writesEnabled) return;
  confirmDialog("Write output", `Set ${name} of #${pos} ${slaveName(pos)} to ${value}?`, "Write", async () => {
    try { await api("/api/pdo/write", { position: pos, name, value }); }
    catch (err) { showBanner("write refused: " + err.message); }
  });
}
function confirmDialog(title, text, okText, onOk, onCancel) {
  $("modal-title").textContent = title;
  $("modal-text").textContent = text;
  $("modal-ok").textContent = okText;
  const modal = $("modal");
  modal.classList.remove("hidden");
  const done = (ok) => {
    modal.classList.add("hidden");
    $("modal-ok").onclick = null; $("modal-cancel").onclick = null;
    if (ok) onOk(); else if (onCancel) onCancel();
  };
  $("modal-ok").onclick = () => done(true);
  $("modal-cancel").onclick = () => done(false);
}

/* ---------- charts ---------- */
function chart(id, series, opts) {
  const host = $(id);
  const width = Math.max(320, host.clientWidth - 4);
  let c = S.charts[id];
  if (c && Math.abs(c.width - width) > 20) { c.destroy(); c = null; delete S.charts[id]; }
  if (!c) {
    const o = Object.assign({ width, height: host.classList.contains("tall") ? 300 : 220,
      scales: { x: { time: true } }, series: [{}].concat(series), axes: [{}, { size: 60 }],
      legend: { live: false } }, opts || {});
    clear(host);
    c = S.charts[id] = new uPlot(o, [[]].concat(series.map(() => [])), host);
  }
  return c;
}
function columns(rows, n) {
  const out = [];
  for (let i = 0; i < n; i++) out.push(rows.map((r) => (r[i] === undefined ? null : r[i])));
  return out;
}
function kpi(label, value, unit, bad) {
  return el("div", { class: "kpi" + (bad ? " bad" : "") }, el("div", { class: "label" }, label),
    el("div", { class: "value" }, value, unit ? el("small", null, unit) : null));
}
function renderCycle() {
  const m = S.live;
  if (!m) return;
  const c = m.cycle;
  const k = $("cycle-kpis");
  clear(k);
  if (!c.running && !c.cycles) {
    k.append(el("div", { class: "empty" }, "The master is not exchanging process data (start it with 'pyethercat run')."));
  }
  k.append(kpi("Cycle", fmt(c.period_us), "µs"), kpi("Period mean", fmt(c.period_mean_us, 2), "µs"),
    kpi("Jitter p50", fmt(c.jitter_p50_us, 1), "µs"), kpi("Jitter p99", fmt(c.jitter_p99_us, 1), "µs"),
    kpi("Jitter max", fmt(c.jitter_max_us, 1), "µs"), kpi("Round trip p50", fmt(c.rtt_p50_us, 1), "µs"),
    kpi("Round trip p99", fmt(c.rtt_p99_us, 1), "µs"), kpi("Cycles", c.cycles.toLocaleString()),
    kpi("Late cycles", c.late, null, c.late > 0), kpi("WKC errors", c.wkc_errors, null, c.wkc_errors > 0),
    kpi("Lost frames", c.lost_frames, null, c.lost_frames > 0), kpi("Skipped", c.skipped, null, c.skipped > 0));
  const rows = S.series.cycle || [];
  const cols = columns(rows, 9);
  chart("chart-jitter", [{ label: "p99", stroke: PALETTE[0], width: 1.5 }, { label: "max", stroke: PALETTE[1], width: 1 }])
    .setData([cols[0], cols[2], cols[3]]);
  chart("chart-rtt", [{ label: "p50", stroke: PALETTE[2], width: 1.5 }, { label: "p99", stroke: PALETTE[3], width: 1 }])
    .setData([cols[0], cols[4], cols[5]]);
  const bars = uPlot.paths.bars({ size: [0.8, 40] });
  chart("chart-errors", [{ label: "late", stroke: PALETTE[3], fill: "#d69e2e55", paths: bars },
    { label: "WKC errors", stroke: PALETTE[1], fill: "#d6454555", paths: bars },
    { label: "lost frames", stroke: PALETTE[7], fill: "#4a556855", paths: bars }])
    .setData([cols[0], cols[6], cols[7], cols[8]]);
  const labels = c.bins_us.map((b) => "<" + b).concat(["≥" + c.bins_us[c.bins_us.length - 1]]);  /* µs */
  const xs = labels.map((_, i) => i);
  const hist = chart("chart-hist", [{ label: "periods", stroke: PALETTE[0], fill: "#2f6fde55", paths: uPlot.paths.bars({ size: [0.7, 60] }) }], {
    scales: { x: { time: false, range: [-0.5, labels.length - 0.5] }, y: { distr: 3 } },
    axes: [{ label: "|period − nominal| (µs)", values: (u, ticks) => ticks.map((i) => (labels[i] !== undefined && Number.isInteger(i) ? labels[i] : "")), splits: () => xs }, { size: 60 }],
  });
  hist.setData([xs, c.histogram.map((v) => (v > 0 ? v : null))]);
  /* A period is measured between two cycles on consecutive deadlines: one that spans
     skipped deadlines (an overrun) is no jitter sample, so the bars sum to fewer than the
     cycles when deadlines were skipped. */
  const periods = c.histogram.reduce((a, b) => a + b, 0);
  $("hist-note").textContent = `${periods.toLocaleString()} periods in ${c.cycles.toLocaleString()} cycles`
    + (c.skipped ? `; periods across the ${c.skipped.toLocaleString()} skipped deadlines are not counted` : "");
  const gt = $("groups-table");
  clear(gt);
  gt.append(el("thead", null, el("tr", null, ...["Group", "WKC", "Expected", "State", "Exchanges", "WKC errors", "Lost"].map((h) => el("th", null, h)))));
  const body = el("tbody");
  for (const g of m.groups) body.append(el("tr", null, el("td", null, g.name), el("td", { class: "num" }, g.wkc), el("td", { class: "num" }, g.expected),
    el("td", { class: g.ok ? "health-ok" : "health-bad" }, g.ok ? "ok" : "WRONG"), el("td", { class: "num" }, g.exchanges),
    el("td", { class: "num" }, g.errors), el("td", { class: "num" }, g.lost)));
  gt.append(body);
}

/* ---------- DC ---------- */
function renderDc() {
  const m = S.live;
  if (!m || !S.segment) return;
  const d = m.dc;
  const k = $("dc-kpis");
  clear(k);
  if (!d.set_up) {
    k.append(el("div", { class: "empty" }, "Distributed clocks are not set up on this master (run with --dc, or 'pyethercat dc')."));
  } else {
    k.append(kpi("Reference", d.reference === null ? "–" : "#" + d.reference),
      kpi("Mode", d.mode || "set up only"), kpi("Phase error", fmt(d.phase_error_ns), "ns"),
      kpi("Locked", d.locked === null ? "–" : d.locked ? "yes" : "no", null, d.locked === false),
      kpi("Monitor |Δt|", fmt(d.monitor_last_ns), "ns"), kpi("Worst |Δt|", fmt(d.monitor_worst_ns), "ns"),
      kpi("Sync", d.unstable === null ? "–" : d.unstable ? "UNSTABLE" : "in sync", null, d.unstable === true));
  }
  const dcSlaves = S.segment.slaves.filter((s) => m.slaves[s.position].dc_difference_ns !== null);
  const rows = S.series.dc || [];
  const key = dcSlaves.map((s) => s.position).join(",");
  if (S.charts["chart-dc"] && S.charts["chart-dc"]._key !== key) { S.charts["chart-dc"].destroy(); delete S.charts["chart-dc"]; }
  if (dcSlaves.length) {
    const c = chart("chart-dc", dcSlaves.map((s, i) => ({ label: `#${s.position} ${s.name}`, stroke: PALETTE[i % PALETTE.length], width: 1.2 })));
    c._key = key;
    c.setData([rows.map((r) => r[0])].concat(dcSlaves.map((s) => rows.map((r) => (r[s.position + 1] === undefined ? null : r[s.position + 1])))));
  } else {
    const host = $("chart-dc");
    if (!host.querySelector(".empty")) { clear(host); host.append(el("div", { class: "empty" }, "No slave reports a system-time difference (0x092C) yet.")); }
  }
  const t = $("dc-table");
  clear(t);
  t.append(el("thead", null, el("tr", null, ...["#", "Name", "Clock", "Reference", "Delay", "Offset", "|Δt| now"].map((h) => el("th", null, h)))));
  const body = el("tbody");
  const bySlave = Object.fromEntries(d.slaves.map((x) => [x.position, x]));
  for (const s of S.segment.slaves) {
    const x = bySlave[s.position];
    body.append(el("tr", null, el("td", { class: "num" }, s.position), el("td", null, s.name),
      el("td", null, x ? x.kind : s.dc ? "DC" : "no"), el("td", null, x && x.reference ? "reference" : ""),
      el("td", { class: "num" }, x && x.delay_ns !== null ? x.delay_ns + " ns" : "–"),
      el("td", { class: "num" }, x && x.offset_ns !== null ? x.offset_ns + " ns" : "–"),
      el("td", { class: "num" }, m.slaves[s.position].dc_difference_ns === null ? "–" : m.slaves[s.position].dc_difference_ns + " ns")));
  }
  t.append(body);
}

/* ---------- drives ---------- */
function renderDrives() {
  const host = $("drives");
  const m = S.live;
  if (!m || !S.segment) return;
  if (!S.segment.drives.length) {
    if (!host.querySelector(".empty")) { clear(host); host.append(el("div", { class: "empty" }, "No CiA 402 drive on this segment (a drive maps controlword 0x6040 and statusword 0x6041).")); }
    return;
  }
  for (const d of m.drives) {
    let card = $("drive-" + d.position);
    if (!card) {
      card = el("div", { class: "card drive", id: "drive-" + d.position },
        el("div", { class: "cardhead" }, `#${d.position} ${slaveName(d.position)}`),
        el("div", { class: "kv" }), el("div", { class: "chart", id: "chart-drive-" + d.position }));
      host.append(card);
    }
    const kv = card.querySelector(".kv");
    clear(kv);
    const item = (label, value) => el("div", null, el("span", null, label), el("b", null, value));
    kv.append(item("State", d.state || "statusword " + hex(d.statusword)), item("Mode", d.mode || fmt(d.mode_value)),
      item("Statusword", hex(d.statusword)), item("Position", fmt(d.position_actual)),
      item("Velocity", fmt(d.velocity)), item("Following error", fmt(d.following_error)));
    const rows = S.series["drive" + d.position] || [];
    const cols = columns(rows, 4);
    chart("chart-drive-" + d.position, [{ label: "position", stroke: PALETTE[0], scale: "pos" }, { label: "following error", stroke: PALETTE[1], scale: "fe" }],
      { axes: [{}, { scale: "pos", size: 70 }, { scale: "fe", side: 1, size: 60, grid: { show: false } }], scales: { x: { time: true }, pos: {}, fe: {} } })
      .setData([cols[0], cols[1], cols[2]]);
  }
}

/* ---------- mailbox ---------- */
/* A slave is the same device across segment messages when its position and identity are. */
function slaveKey(s) {
  return s ? [s.position, s.vendor, s.product, s.revision, s.serial, s.name].join("/") : "";
}
function buildMailbox() {
  const sel = $("mbx-slave");
  const before = S.sdoPosition === null ? "" : slaveKey(S.mbxSlave);
  clear(sel);
  for (const s of S.segment.slaves) {
    if (!s.mailbox.length) continue;
    sel.append(el("option", { value: s.position }, `#${s.position} ${s.name}`));
  }
  if (!sel.options.length) sel.append(el("option", { value: "" }, "no slave with a mailbox"));
  sel.onchange = mailboxSlaveChanged;
  $("sdo-write").disabled = !S.segment.writable;
  // A segment message comes on every (re)connection and after a rescan: when the slave
  // chosen is still there, the browsed dictionary, the result and the FoE list stay
  // (rebuilding cleared a browse the user was reading, or one still on its way).
  const same = before !== "" && S.segment.slaves.some((s) => s.mailbox.length && slaveKey(s) === before);
  if (same) { sel.value = String(S.sdoPosition); S.mbxSlave = S.segment.slaves[S.sdoPosition]; return; }
  mailboxSlaveChanged();
}
function mailboxSlaveChanged() {
  const v = $("mbx-slave").value;
  S.sdoPosition = v === "" ? null : Number(v);
  const s = S.sdoPosition === null ? null : S.segment.slaves[S.sdoPosition];
  S.mbxSlave = s;
  S.browseSeq += 1;  // a browse of the slave chosen before must not fill this one's list
  $("mbx-protocols").textContent = s ? "mailbox: " + s.mailbox.join(", ") : "";
  clear($("sdo-list"));
  $("sdo-list").append(el("p", { class: "muted" }, s && s.coe ? "Press Browse to read the object dictionary (SDO information)." : "This slave does not announce CoE."));
  $("sdo-browse").disabled = !(s && s.coe);
  refreshFoe();
}
async function browseSdo() {
  const box = $("sdo-list");
  const seq = ++S.browseSeq;
  clear(box);
  box.append(el("p", { class: "muted" }, "reading the object dictionary…"));
  try {
    const r = await api(`/api/sdo/list?position=${S.sdoPosition}`);
    if (seq !== S.browseSeq) return;
    clear(box);
    for (const o of r.objects) {
      const d = el("details", null, el("summary", null, el("span", { class: "idx" }, hex(o.index)), o.name || o.error || ""));
      const t = el("table", { class: "grid" });
      for (const e of o.entries) {
        const tr = el("tr", { class: "entry" }, el("td", { class: "mono" }, ":" + e.subindex.toString(16).toUpperCase().padStart(2, "0")),
          el("td", null, e.name), el("td", { class: "mono" }, e.type), el("td", { class: "mono" }, e.access), el("td", { class: "num" }, e.bits + " bit"));
        tr.addEventListener("click", () => { $("sdo-index").value = hex(o.index); $("sdo-sub").value = String(e.subindex); readSdo(); });
        t.append(tr);
      }
      d.append(t);
      box.append(d);
    }
  } catch (err) {
    if (seq !== S.browseSeq) return;
    clear(box); box.append(el("p", { class: "result error" }, err.message)); }
}
async function readSdo(ev) {
  if (ev) ev.preventDefault();
  const out = $("sdo-result");
  out.className = "result"; out.textContent = "reading…";
  try {
    const r = await api(`/api/sdo/read?position=${S.sdoPosition}&index=${encodeURIComponent($("sdo-index").value)}&subindex=${encodeURIComponent($("sdo-sub").value || "0")}`);
    out.textContent = `${$("sdo-index").value}:${$("sdo-sub").value || 0} = ${r.value}` + (r.type ? ` (${r.type})` : "") + `   [${r.hex}]`;
  } catch (err) { out.className = "result error"; out.textContent = err.message; }
}
function writeSdo() {
  const idx = $("sdo-index").value, sub = $("sdo-sub").value || "0", value = $("sdo-value").value;
  confirmDialog("Write SDO", `Write ${value} to ${idx}:${sub} of #${S.sdoPosition} ${slaveName(S.sdoPosition)}?`, "Write", async () => {
    const out = $("sdo-result");
    try {
      const r = await api("/api/sdo/write", { position: S.sdoPosition, index: idx, subindex: sub, value });
      out.className = "result"; out.textContent = `written ${r.written} (${r.type})`;
    } catch (err) { out.className = "result error"; out.textContent = err.message; }
  });
}
async function refreshFoe() {
  const box = $("foe-files");
  clear(box);
  if (S.sdoPosition === null) return;
  try {
    const r = await api(`/api/foe/files?position=${S.sdoPosition}`);
    if (!r.files.length) { box.append(el("p", { class: "muted" }, "No file moved through this master yet.")); return; }
    const t = el("table", { class: "grid" });
    t.append(el("thead", null, el("tr", null, ...["File", "Size", "Last", "When"].map((h) => el("th", null, h)))));
    for (const f of r.files) t.append(el("tr", null, el("td", { class: "mono" }, f.name), el("td", { class: "num" }, f.size + " B"), el("td", null, f.direction), el("td", null, timeText(f.time))));
    box.append(t);
  } catch (err) { box.append(el("p", { class: "result error" }, err.message)); }
}
async function readFoe(ev) {
  ev.preventDefault();
  const out = $("foe-result");
  const name = $("foe-name").value;
  out.className = "result"; out.textContent = "reading " + name + "…";
  try {
    const blob = await api("/api/foe/read", { position: S.sdoPosition, name, password: $("foe-password").value || "0" });
    out.textContent = `${name}: ${blob.size} bytes`;
    const a = el("a", { href: URL.createObjectURL(blob), download: name }, " save");
    out.append(a);
    refreshFoe();
  } catch (err) { out.className = "result error"; out.textContent = err.message; }
}
function renderMailbox() {
  const t = $("emcy-table");
  clear(t);
  t.append(el("thead", null, el("tr", null, ...["Time", "Slave", "Code", "Register", "Data", "Text"].map((h) => el("th", null, h)))));
  const body = el("tbody");
  const list = S.events.filter((e) => e.kind === "emergency").reverse();
  if (!list.length) body.append(el("tr", null, el("td", { class: "muted", colspan: "6" }, "No emergency received.")));
  for (const e of list) body.append(el("tr", null, el("td", { class: "mono" }, timeText(e.time)), el("td", null, e.position === null ? "–" : `#${e.position} ${slaveName(e.position)}`),
    el("td", { class: "mono" }, hex(e.code)), el("td", { class: "mono" }, hex(e.register, 2)), el("td", { class: "mono" }, e.data || "–"), el("td", null, e.text)));
  t.append(body);
}

/* ---------- navigation and render loop ---------- */
function showPage() {
  const page = (location.hash || "#topology").slice(1);
  S.page = PAGE_TITLES[page] ? page : "topology";
  for (const sec of document.querySelectorAll(".page")) sec.classList.toggle("hidden", sec.id !== "page-" + S.page);
  for (const a of document.querySelectorAll("nav a")) a.classList.toggle("active", a.dataset.page === S.page);
  $("title").textContent = PAGE_TITLES[S.page];
  document.title = PAGE_TITLES[S.page] + " · pyethercat";
  render();
}
function render() {
  renderChips();
  if (!S.segment) return;
  switch (S.page) {
    case "topology": renderTopology(); renderEvents(); break;
    case "slaves": renderSlaves(); break;
    case "pdo": renderPdo(false); break;
    case "cycle": renderCycle(); break;
    case "dc": renderDc(); break;
    case "drives": renderDrives(); break;
    case "mailbox": renderMailbox(); break;
  }
}
document.addEventListener("DOMContentLoaded", () => {
  window.addEventListener("hashchange", showPage);
  $("sdo-browse").addEventListener("click", browseSdo);
  $("sdo-form").addEventListener("submit", readSdo);
  $("sdo-write").addEventListener("click", writeSdo);
  $("foe-form").addEventListener("submit", readFoe);
  showPage();
  connect();
});
