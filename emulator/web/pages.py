"""The live view's pages: HTML shells whose inline script fills them from the server-sent
events, with the report's style sheet (emulator/report/assets.py) and its plots' colours
(emulator/report/plots.py). Nothing is fetched from anywhere else: the pages hold their style
and script, and the Content-Security-Policy the app sends forbids any other source.
"""

import json
from html import escape

from fake_marlin import __version__
from fake_marlin.emulator.report.assets import STYLE as REPORT_STYLE
from fake_marlin.emulator.report.plots import COLOURS, FAULT_COLOUR, MARK_COLOURS

PAGE_SIZES = (50, 100, 200, 500)
DEFAULT_PAGE_SIZE = 200
FILTERS = {  # the farm page's filters, in the order offered
    "all": "all",
    "connected": "with a host",
    "printing": "printing",
    "heating": "heating",
    "halted": "halted",
    "errors": "errors or resends",
}

STYLE = REPORT_STYLE + r"""
header { display: flex; align-items: baseline; gap: 18px; flex-wrap: wrap; }
header .live { margin-left: auto; font-size: 13px; color: #c3cbd3; }
header .live::before { content: ""; display: inline-block; width: 9px; height: 9px;
  border-radius: 50%; background: #7d8791; margin-right: 6px; vertical-align: 0; }
header .live.on::before { background: #3ccf6e; box-shadow: 0 0 0 3px rgba(60,207,110,.25); }
header .live.off::before { background: #e5484d; }
header a { color: #fff; }
main { max-width: none; padding: 16px 24px 40px; }
.cards { grid-template-columns: repeat(auto-fit, minmax(118px, 1fr)); gap: 10px; }
.card { padding: 8px 12px; }
.card .value { font-size: 22px; white-space: nowrap; overflow: hidden; text-overflow: ellipsis; }
.card .label { font-size: 14px; }
.card .note { font-size: 12px; overflow-wrap: anywhere; }
.card.wide { grid-column: span 2; }
#printer .cards { grid-template-columns: repeat(6, minmax(0, 1fr)); }
@media (max-width: 900px) { #printer .cards { grid-template-columns: repeat(3, minmax(0, 1fr)); } }
.card.wide .value { font-size: 15px; white-space: normal; line-height: 1.3; padding: 4px 0 2px; }
.card.good { border-top-color: var(--good); } .card.good .value { color: var(--good); }
.card.info { border-top-color: #1f77b4; } .card.info .value { color: #1f5f99; }
.toolbar { display: flex; flex-wrap: wrap; gap: 8px 16px; align-items: center; margin: 16px 0 8px; }
.filters { display: flex; flex-wrap: wrap; gap: 4px; }
.filters button, .pager button, .toolbar select, .toolbar input { font: inherit; font-size: 14px;
  padding: 3px 10px; border: 1px solid #b9c1c9; border-radius: 5px; background: var(--paper);
  color: var(--ink); cursor: pointer; }
.filters button.on { background: #20262d; border-color: #20262d; color: #fff; }
.filters .count { color: var(--muted); font-variant-numeric: tabular-nums; margin-left: 4px; }
.filters button.on .count { color: #c3cbd3; }
.toolbar .pager { margin: 0; }
.toolbar input { width: 6.5em; cursor: text; }
.toolbar label { font-size: 14px; color: var(--muted); }
.table-wrap { background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  overflow: auto; }
table.farm { border-collapse: collapse; width: 100%; font-size: 12.5px;
  font-variant-numeric: tabular-nums; }
table.farm th { position: sticky; top: 0; background: #f0f2f4; text-align: left; z-index: 1;
  color: var(--muted); font-weight: 600; padding: 6px 6px; border-bottom: 1px solid var(--line);
  white-space: nowrap; }
table.farm td { padding: 3px 6px; border-bottom: 1px solid #f0f2f4; white-space: nowrap; }
table.farm tbody tr:hover td { background: #f7f9fb; }
table.farm .n { text-align: right; }
table.farm td.number a { font-weight: 650; color: #1f5f99; text-decoration: none; }
table.farm td.number a:hover { text-decoration: underline; }
table.farm td.path, table.farm td.last { font-family: var(--mono); font-size: 12px; }
table.farm td.path { max-width: 14em; overflow: hidden; text-overflow: ellipsis; }
table.farm td.last { max-width: 11em; overflow: hidden; text-overflow: ellipsis; color: #39424c; }
table.farm td.error { max-width: 15em; overflow: hidden; text-overflow: ellipsis; color: var(--warn); }
table.farm td.error.fault { color: var(--bad); font-weight: 600; }
table.farm td.firmware { color: #39424c; }
table.farm td.firmware .proto { color: var(--muted); }
table.farm .dim { color: #9aa5b1; }
table.farm td.bad { color: var(--bad); font-weight: 600; }
table.farm td.warn { color: var(--warn); font-weight: 600; }
table.farm tr.flash td { animation: flash 1.2s ease-out; }
@keyframes flash { from { background: #fff5c2; } to { background: transparent; } }
.dot { display: inline-block; width: 8px; height: 8px; border-radius: 50%; background: #d0d5da;
  margin-right: 5px; vertical-align: 1px; }
.dot.on { background: #2ca02c; }
table.farm td.host { color: var(--muted); }
.badge { display: inline-block; padding: 0 7px; border-radius: 10px; font-size: 12px;
  font-weight: 600; background: #eef0f2; color: #5f6b76; }
.badge.printing { background: #dbeafb; color: #1f4e8c; }
.badge.heating { background: #fff0d6; color: #8a5a00; }
.badge.halted { background: var(--bad-wash); color: var(--bad); }
.badge.booting, .badge.bootloader { background: #f1eafb; color: #5b2a9a; }
.meter { display: inline-block; width: 40px; height: 7px; border-radius: 4px; background: #e8ebee;
  vertical-align: middle; margin-right: 6px; overflow: hidden; }
.meter > span { display: block; height: 100%; background: #2ca02c; border-radius: 4px; }
.meter.job > span { background: #1f77b4; }
.temp .target { color: var(--muted); }
.temp.hot { color: #b53d00; }
.empty { padding: 24px; text-align: center; color: var(--muted); font-style: italic; }
.panels { display: grid; grid-template-columns: minmax(0, 3fr) minmax(340px, 2fr); gap: 14px;
  margin-top: 14px; align-items: start; }
@media (max-width: 1100px) { .panels { grid-template-columns: 1fr; } }
.box { background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  padding: 4px 14px 12px; }
.box h2 { font-size: 16px; margin: 10px 0 6px; display: flex; align-items: baseline; gap: 10px; }
.box h2 .note { font-size: 13px; font-weight: 400; color: var(--muted); }
#plots svg { display: block; width: 100%; }
#plots svg text { font: 11px system-ui, "DejaVu Sans", sans-serif; fill: #39424c; }
#plots svg text.title { font-weight: 700; font-size: 12px; fill: var(--ink); }
#plots svg text.none { fill: #777; font-style: italic; }
#plots svg .grid { stroke: #e4e4e4; stroke-width: 1; }
#plots svg .axis { stroke: #9aa5b1; stroke-width: 1; }
#tail { max-height: 640px; overflow: auto; border-top: 1px solid var(--line); }
#tail table { border-collapse: collapse; width: 100%; font-size: 12px; table-layout: fixed; }
#tail td { padding: 1px 6px; border-bottom: 1px solid #f3f4f6; vertical-align: top; }
#tail td.time { width: 6.5em; text-align: right; color: var(--muted);
  font-variant-numeric: tabular-nums; }
#tail td.dir { width: 3.2em; }
#tail td.text { font-family: var(--mono); white-space: pre-wrap; word-break: break-all; }
#tail tr.in td.text { color: #1f4e8c; }
#tail tr.out td.text { color: #1e6b34; }
#tail tr.error td.text { color: var(--bad); font-weight: 600; }
#tail tr.partial td.text { opacity: .6; }
.dir-tag { display: inline-block; padding: 0 5px; border-radius: 4px; font-size: 11px;
  font-weight: 600; }
tr.in .dir-tag { background: #e3eefb; color: #1f4e8c; }
tr.out .dir-tag { background: #e6f4ea; color: #1e6b34; }
.tail-controls { display: flex; gap: 14px; font-size: 13px; color: var(--muted); margin: 0 0 6px; }
#events { list-style: none; margin: 0; padding: 0; font-size: 13px; max-height: 220px;
  overflow: auto; }
#events li { padding: 2px 0; border-bottom: 1px solid #f3f4f6; }
#events .t { color: var(--muted); font-variant-numeric: tabular-nums; display: inline-block;
  min-width: 6em; }
#events .kind { font-weight: 600; display: inline-block; min-width: 6.5em; }
.facts { width: 100%; border-collapse: collapse; font-size: 13px; }
.facts th { text-align: left; color: var(--muted); font-weight: 500; width: 34%;
  padding: 2px 8px 2px 0; vertical-align: top; }
.facts td { padding: 2px 0; font-family: var(--mono); font-size: 12px; word-break: break-all; }
.notfound { max-width: 640px; margin: 60px auto; background: var(--paper); padding: 20px 28px;
  border: 1px solid var(--line); border-radius: 8px; }
"""

# What both pages' scripts share: formatting, and the state's words.
COMMON_SCRIPT = r"""
"use strict";
const $ = (id) => document.getElementById(id);
const fmt = new Intl.NumberFormat("en-US");
function number(value) { return value === null || value === undefined ? "—" : fmt.format(value); }
function rate(value) {
  if (value === null || value === undefined) return "—";
  return value >= 100 ? fmt.format(Math.round(value)) : value.toFixed(1);
}
function temperature(heater) {
  if (!heater) return "—";
  return heater.actual.toFixed(1) + " / " + Math.round(heater.target) + " °C";
}
function faultsText(faults) {
  const kinds = Object.keys(faults);
  return kinds.map((kind) => kind + " ×" + faults[kind]).join(", ");
}
function setText(element, text) {
  if (element.textContent !== text) element.textContent = text;
}
function setClass(element, name) {
  if (element.className !== name) element.className = name;
}
function live(state, text) {
  const element = $("live");
  setClass(element, "live " + state);
  setText(element, text);
}
"""

FARM_SCRIPT = COMMON_SCRIPT + r"""
const FILTERS = JSON.parse($("filters-data").textContent);
const SIZE_DATA = JSON.parse($("sizes-data").textContent);
const SIZES = SIZE_DATA.sizes;
const params = new URLSearchParams(location.search);
const view = {
  page: Math.max(0, parseInt(params.get("page") || "1", 10) - 1) || 0,
  size: SIZES.includes(parseInt(params.get("size"), 10)) ? parseInt(params.get("size"), 10) : SIZE_DATA.default,
  filter: FILTERS[params.get("filter")] ? params.get("filter") : "all",
};
const body = $("rows");
const rows = new Map();  // printer number -> its <tr>
let order = [];
let source = null;
let updates = 0;
let pages = 1;

const COLUMNS = ["number", "path", "firmware", "host", "state", "hotend", "bed", "planner", "rate",
                 "commands", "job", "last", "resends", "faults", "error"];
function makeRow(number) {
  const tr = document.createElement("tr");
  tr.dataset.number = number;
  for (const name of COLUMNS) {
    const td = document.createElement("td");
    td.className = name;
    tr.appendChild(td);
  }
  const link = document.createElement("a");
  link.href = "/printer/" + number;
  link.textContent = number;
  tr.cells[0].appendChild(link);
  tr.cells[3].innerHTML = '<span class="dot"></span><span></span>';
  tr.cells[4].innerHTML = '<span class="badge"></span>';
  tr.cells[7].innerHTML = '<span class="meter"><span></span></span><span></span>';
  tr.cells[10].innerHTML = '<span class="meter job"><span></span></span><span></span>';
  return tr;
}

function fill(tr, row) {
  const cell = tr.cells;
  setText(cell[1], row.path.replace(/^socket:\/\//, "")); cell[1].title = row.path;
  const firmware = row.firmware + " · " + (row.protocol || (row.protocol_setting === "auto" ? "auto" : row.protocol_setting));
  setText(cell[2], firmware); cell[2].title = row.firmware_title + " · UUID " + row.uuid;
  setClass(cell[3].firstChild, row.connected ? "dot on" : "dot");
  setText(cell[3].lastChild, row.connected ? "yes" : "no");
  cell[3].title = row.connects + " connection" + (row.connects === 1 ? "" : "s") + " since power-on";
  const badge = cell[4].firstChild;
  setClass(badge, "badge " + row.state);
  setText(badge, row.state);
  for (const [index, heater] of [[5, row.hotend], [6, row.bed]]) {
    setText(cell[index], heater ? heater.actual.toFixed(1) + " / " + Math.round(heater.target) : "—");
    setClass(cell[index], "temp" + (heater && heater.actual > 50 ? " hot" : ""));
  }
  const planner = row.planner;
  cell[7].firstChild.firstChild.style.width = Math.round(100 * planner.queued / Math.max(1, planner.size)) + "%";
  setText(cell[7].lastChild, planner.queued + "/" + planner.size);
  setText(cell[8], rate(row.rate));
  setClass(cell[8], "rate n" + (row.rate ? "" : " dim"));
  setText(cell[9], number(row.commands));
  setClass(cell[9], "commands n");
  const job = row.job;
  const meter = cell[10].firstChild;
  if (job) {
    meter.style.display = "";
    meter.firstChild.style.width = job.percent + "%";
    setText(cell[10].lastChild, job.percent.toFixed(1) + "% " + job.file);
  } else {
    meter.style.display = "none";
    setText(cell[10].lastChild, row.state === "printing" && row.rate ? "host stream" : "—");
  }
  setText(cell[11], row.last_command || "—"); cell[11].title = row.last_command;
  setText(cell[12], number(row.resends));
  setClass(cell[12], "resends n" + (row.resends ? " warn" : " dim"));
  setText(cell[13], row.faults_fired ? number(row.faults_fired) : "0");
  cell[13].title = faultsText(row.faults);
  setClass(cell[13], "faults n" + (row.faults_fired ? " warn" : " dim"));
  const error = row.last_error ? row.last_error.text : "";
  setText(cell[14], error || "—");
  cell[14].title = row.last_error ? (row.last_error.t - row.powered_on).toFixed(1) + " s after power-on: " + error : "";
  setClass(cell[14], !error ? "error dim" : row.last_error.kind === "fault" || row.halted ? "error fault" : "error");
}

function summary(data) {
  const s = data.summary;
  setText($("s-printers"), number(s.printers));
  setText($("s-connected"), number(s.connected));
  setText($("s-printing"), number(s.printing));
  setText($("s-heating"), number(s.heating));
  setText($("s-halted"), number(s.halted));
  setText($("s-errors"), number(s.errors));
  setText($("s-rate"), rate(s.rate));
  setText($("s-commands"), number(s.commands));
  for (const button of document.querySelectorAll(".filters button")) {
    const key = button.dataset.filter;
    setClass(button, key === view.filter ? "on" : "");
    setText(button.querySelector(".count"), number(s.counts[key]));
  }
}

function pager(data) {
  pages = data.pages;
  view.page = data.page;
  const first = data.total ? data.page * data.size + 1 : 0;
  const last = Math.min(data.total, (data.page + 1) * data.size);
  setText($("page-count"), data.total ? `printers ${fmt.format(first)}–${fmt.format(last)} of ${fmt.format(data.total)} · page ${data.page + 1} of ${data.pages}` : "no printers match");
  $("first").disabled = $("prev").disabled = data.page <= 0;
  $("next").disabled = $("last").disabled = data.page >= data.pages - 1;
}

function update(data) {
  if (data.error) { live("off", "the farm did not answer: " + data.error); return; }
  summary(data);
  pager(data);
  const numbers = data.numbers;
  if (numbers.length !== order.length || numbers.some((n, i) => n !== order[i])) {
    const keep = new Set(numbers);
    for (const [n, tr] of rows) if (!keep.has(n)) rows.delete(n);
    const fragment = document.createDocumentFragment();
    for (const n of numbers) {
      if (!rows.has(n)) rows.set(n, makeRow(n));
      fragment.appendChild(rows.get(n));
    }
    body.replaceChildren(fragment);
    order = numbers;
    $("none").hidden = numbers.length > 0;
  }
  for (const row of data.rows) {
    const tr = rows.get(row.number);
    if (!tr) continue;
    const before = tr.dataset.commands;
    fill(tr, row);
    tr.dataset.commands = row.commands;
    if (before !== undefined && before !== String(row.commands)) {
      tr.classList.remove("flash"); void tr.offsetWidth; tr.classList.add("flash");
    }
  }
  updates += 1;
  $("farm").dataset.updates = updates;
  live("on", "live · updated " + new Date().toLocaleTimeString());
}

function connect() {
  if (source) source.close();
  const query = new URLSearchParams({ page: view.page + 1, size: view.size, filter: view.filter });
  const shown = new URLSearchParams(query);
  if (view.filter === "all") shown.delete("filter");
  if (view.page === 0) shown.delete("page");
  if (view.size === SIZE_DATA.default) shown.delete("size");
  history.replaceState(null, "", shown.toString() ? "?" + shown : location.pathname);
  source = new EventSource("/events?" + query);
  source.onmessage = (event) => update(JSON.parse(event.data));
  source.onerror = () => live("off", "reconnecting…");
}

function turn(page) {
  view.page = Math.max(0, Math.min(pages - 1, page));
  connect();
}
$("first").onclick = () => turn(0);
$("prev").onclick = () => turn(view.page - 1);
$("next").onclick = () => turn(view.page + 1);
$("last").onclick = () => turn(pages - 1);
$("size").value = String(view.size);
$("size").onchange = () => { view.size = parseInt($("size").value, 10); view.page = 0; connect(); };
for (const button of document.querySelectorAll(".filters button")) {
  button.onclick = () => { view.filter = button.dataset.filter; view.page = 0; connect(); };
}
$("goto").onkeydown = (event) => {
  if (event.key === "Enter" && $("goto").value) location.href = "/printer/" + parseInt($("goto").value, 10);
};
addEventListener("pagehide", () => { if (source) source.close(); });
connect();
"""

PRINTER_SCRIPT = COMMON_SCRIPT + r"""
const NUMBER = parseInt($("printer").dataset.number, 10);
const COLOURS = JSON.parse($("colours-data").textContent);
const NS = "http://www.w3.org/2000/svg";
let updates = 0;
let source = null;

function escapeText(text) {
  return String(text).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}
function niceStep(span, count) {
  const raw = span / Math.max(1, count);
  const power = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 2.5, 5, 10]) if (raw <= m * power) return m * power;
  return 10 * power;
}
function ticks(low, high, count) {
  const step = niceStep(high - low || 1, count);
  const out = [];
  for (let v = Math.ceil(low / step) * step; v <= high + step * 1e-9; v += step) out.push(+v.toFixed(10));
  return out;
}
function decimalsOf(step) {
  for (let d = 0; d < 3; d++) if (Math.abs(step * 10 ** d - Math.round(step * 10 ** d)) < 1e-6) return d;
  return 3;
}
function label(value, step) {
  const decimals = step ? decimalsOf(step) : 2;
  return Math.abs(value) >= 1000 && decimals === 0 ? fmt.format(Math.round(value)) : value.toFixed(decimals);
}

// One panel of the figure, as the report draws it: a title, a y axis, series on the shared
// simulated time axis; step series hold their value until the next point.
function panel(spec, width, x0, x1, height) {
  const left = 58, right = 132, top = 24, bottom = spec.last ? 30 : 10;
  const w = Math.max(80, width - left - right), h = height - top - bottom;
  const y0 = spec.y0, y1 = spec.y1 > spec.y0 ? spec.y1 : spec.y0 + 1;
  const X = (t) => left + (x1 > x0 ? (t - x0) / (x1 - x0) : 0) * w;
  const Y = (v) => top + h - (v - y0) / (y1 - y0) * h;
  const parts = [`<text class="title" x="${left}" y="15">${escapeText(spec.title)}</text>`];
  const xt = ticks(x0, x1, Math.max(2, Math.floor(w / 90)));
  const xstep = xt.length > 1 ? xt[1] - xt[0] : 1;
  for (const t of xt) {
    parts.push(`<line class="grid" x1="${X(t)}" x2="${X(t)}" y1="${top}" y2="${top + h}"/>`);
    if (spec.last) parts.push(`<text x="${X(t)}" y="${top + h + 15}" text-anchor="middle">${label(t, xstep)}</text>`);
  }
  if (!spec.rows) {
    const yt = ticks(y0, y1, 4);
    const ystep = yt.length > 1 ? yt[1] - yt[0] : 1;
    for (const v of yt) {
      parts.push(`<line class="grid" x1="${left}" x2="${left + w}" y1="${Y(v)}" y2="${Y(v)}"/>`);
      parts.push(`<text x="${left - 6}" y="${Y(v) + 4}" text-anchor="end">${label(v, ystep)}</text>`);
    }
    parts.push(`<text x="14" y="${top + h / 2}" transform="rotate(-90 14 ${top + h / 2})" text-anchor="middle">${escapeText(spec.ylabel)}</text>`);
  }
  parts.push(`<line class="axis" x1="${left}" x2="${left}" y1="${top}" y2="${top + h}"/>`);
  parts.push(`<line class="axis" x1="${left}" x2="${left + w}" y1="${top + h}" y2="${top + h}"/>`);
  if (spec.last) parts.push(`<text x="${left + w / 2}" y="${height - 1}" text-anchor="middle">simulated time since power-on (s)</text>`);
  let legend = 0;
  for (const s of spec.series || []) {
    if (!s.t.length) continue;
    let d = "";
    let first = null;
    for (let i = 0; i < s.t.length; i++) {
      if (s.v[i] === null) continue;  // (the first rate: no sample before it)
      const x = X(s.t[i]).toFixed(1), y = Y(s.v[i]).toFixed(1);
      if (first === null) { d += `M${x},${y}`; first = x; }
      else if (s.step) d += `H${x}V${y}`;
      else d += `L${x},${y}`;
    }
    if (first === null) continue;
    if (s.step) d += `H${X(x1).toFixed(1)}`;
    if (s.fill) {
      parts.push(`<path d="${d}V${Y(y0)}H${first}Z" fill="${s.colour}" fill-opacity="0.25" stroke="none"/>`);
    }
    parts.push(`<path d="${d}" fill="none" stroke="${s.colour}" stroke-width="${s.width || 1.3}"${s.dash ? ' stroke-dasharray="5,3"' : ""}/>`);
    if (s.label) {
      const ly = top + 6 + legend * 16;
      parts.push(`<line x1="${left + w + 12}" x2="${left + w + 30}" y1="${ly}" y2="${ly}" stroke="${s.colour}" stroke-width="2"${s.dash ? ' stroke-dasharray="5,3"' : ""}/>`);
      parts.push(`<text x="${left + w + 35}" y="${ly + 4}">${escapeText(s.label)}</text>`);
      legend += 1;
    }
  }
  for (const [index, row] of (spec.rows || []).entries()) {
    const y = top + (index + 0.5) * h / spec.rows.length;
    parts.push(`<text x="${left - 6}" y="${y + 4}" text-anchor="end">${escapeText(row.name)} (${row.t.length})</text>`);
    for (const t of row.t) {
      if (t < x0 || t > x1) continue;
      parts.push(`<line x1="${X(t).toFixed(1)}" x2="${X(t).toFixed(1)}" y1="${y - 7}" y2="${y + 7}" stroke="${row.colour}" stroke-width="2.2"/>`);
    }
  }
  if (spec.empty) parts.push(`<text class="none" x="${left + w / 2}" y="${top + h / 2 + 4}" text-anchor="middle">${escapeText(spec.empty)}</text>`);
  return parts.join("");
}

function figure(detail) {
  const series = detail.series;
  const holder = $("plots");
  const width = holder.clientWidth || 900;
  const t0 = detail.row.powered_on;
  const t = series.t.map((value) => value - t0);
  const now = detail.time - t0;
  const x0 = t.length ? t[0] : now - 1;
  const x1 = Math.max(now, x0 + 1);
  const size = series.planner_size || detail.row.planner.size;
  const rateTop = Math.max(1, ...series.rate.filter((v) => v !== null)) * 1.15;
  const heaters = Object.entries(series.heaters);
  let hot = 50;
  for (const [, heater] of heaters) hot = Math.max(hot, ...heater.actual, ...heater.target);
  const heaterSeries = [];
  heaters.forEach(([name, heater], index) => {
    const colour = COLOURS.series[(index + 1) % COLOURS.series.length];
    heaterSeries.push({ t, v: heater.actual, colour, label: name, width: 1.6 });
    heaterSeries.push({ t, v: heater.target, colour, dash: true, step: true, label: name + " target" });
  });
  const kinds = new Map();
  for (const event of detail.events) {
    const at = event.t - t0;
    if (at < x0) continue;
    const name = event.kind === "fault" ? "fault: " + event.text.split(" ")[0] : event.kind + "s";
    if (!kinds.has(name)) kinds.set(name, []);
    kinds.get(name).push(at);
  }
  const order = ["resends", ...[...kinds.keys()].filter((k) => k.startsWith("fault:")), "disconnects", "resets", "connects"];
  const markRows = order.filter((k) => kinds.has(k)).map((name) => ({
    name, t: kinds.get(name), colour: COLOURS.marks[name] || COLOURS.fault,
  }));
  const few = t.length < 2 ? "collecting samples: one a second while this page is open" : "";
  const specs = [
    { title: "Commands executed per second", ylabel: "commands/s", y0: 0, y1: rateTop, height: 150,
      series: [{ t, v: series.rate, colour: COLOURS.series[0], step: true, fill: true }], empty: few },
    { title: `Planner: blocks queued, of ${size} (its room is the rest; 0 = starved)`, ylabel: "blocks queued",
      y0: 0, y1: size * 1.1 + 0.5, height: 130,
      series: [{ t, v: series.queued, colour: COLOURS.series[2], step: true, fill: true }], empty: few },
    { title: "Heaters: temperature (solid) against target (dashed)", ylabel: "°C", y0: 0, y1: hot * 1.1,
      height: 170, series: heaterSeries, empty: few },
    { title: "Marks: resends, errors, faults, resets", rows: markRows, y0: 0, y1: 1,
      height: 66 + 22 * Math.max(1, markRows.length), last: true,
      empty: markRows.length ? "" : "nothing went wrong while this page was open: no resends, faults or resets" },
  ];
  let y = 0;
  const groups = [];
  for (const spec of specs) {
    groups.push(`<g transform="translate(0 ${y})">${panel(spec, width, x0, x1, spec.height)}</g>`);
    y += spec.height + 6;
  }
  holder.innerHTML = `<svg xmlns="${NS}" width="${width}" height="${y}" viewBox="0 0 ${width} ${y}" role="img" aria-label="plots">${groups.join("")}</svg>`;
}

function cards(detail) {
  const row = detail.row;
  setText($("c-state"), row.state);
  setClass($("card-state"), "card " + ({ halted: "bad", printing: "info", heating: "warn" }[row.state] || ""));
  setText($("c-host"), row.connected ? "connected" : "none");
  setText($("c-host-note"), row.connects + " connection" + (row.connects === 1 ? "" : "s") + ", " + row.boots + " boot" + (row.boots === 1 ? "" : "s"));
  setText($("c-hotend"), row.hotend ? row.hotend.actual.toFixed(1) + " °C" : "—");
  setText($("c-hotend-note"), row.hotend ? "target " + Math.round(row.hotend.target) + " °C" : "");
  setText($("c-bed"), row.bed.actual.toFixed(1) + " °C");
  setText($("c-bed-note"), "target " + Math.round(row.bed.target) + " °C");
  setText($("c-planner"), row.planner.queued + "/" + row.planner.size);
  setText($("c-planner-note"), "blocks queued");
  setText($("c-resends-note"), "lines refused");
  setText($("c-rate"), rate(row.rate));
  setText($("c-commands"), number(row.commands));
  setText($("c-commands-note"), row.last_command ? "last: " + row.last_command : "");
  setText($("c-job"), row.job ? row.job.percent.toFixed(1) + "%" : "—");
  setText($("c-job-note"), row.job ? row.job.file + (row.job.printing ? "" : " (paused)") : (row.state === "printing" ? "streamed by the host" : "no SD print"));
  setText($("c-resends"), number(row.resends));
  setText($("c-faults"), number(row.faults_fired));
  setText($("c-faults-note"), faultsText(row.faults));
  setClass($("card-faults"), "card" + (row.faults_fired ? " warn" : ""));
  setText($("c-error"), row.last_error ? row.last_error.text : "none");
  setText($("c-error-note"), row.last_error ? (row.last_error.t - row.powered_on).toFixed(1) + " s after power-on" : "");
  setClass($("card-error"), "card wide" + (!row.last_error ? "" : row.last_error.kind === "fault" || row.halted ? " bad" : " warn"));
  setClass($("card-resends"), "card" + (row.resends ? " warn" : ""));
  setText($("f-protocol"), (row.protocol || "not yet known") + " (--protocol " + row.protocol_setting + ")");
  setText($("f-firmware"), row.firmware_title);
  setText($("f-uuid"), detail.identity.uuid);
  setText($("f-serial"), detail.identity.serial || "—");
  setText($("f-machine"), detail.identity.machine_name || "—");
  setText($("f-time"), (detail.time - row.powered_on).toFixed(1) + " s since power-on");
}

function tail(detail) {
  const holder = $("tail");
  const t0 = detail.row.powered_on;
  const follow = $("follow").checked;
  const table = document.createElement("table");
  const body = document.createElement("tbody");
  for (const line of detail.tail) {
    const tr = document.createElement("tr");
    const error = line.dir === "out" && /^(echo:)?(Error|ProtoError|!!)/.test(line.text);
    tr.className = line.dir + (error ? " error" : "") + (line.partial ? " partial" : "");
    const time = document.createElement("td"); time.className = "time"; time.textContent = (line.t - t0).toFixed(3);
    const dir = document.createElement("td"); dir.className = "dir";
    dir.innerHTML = `<span class="dir-tag" title="${line.dir === "in" ? "to the printer" : "to the host"}">${line.dir}</span>`;
    const text = document.createElement("td"); text.className = "text"; text.textContent = line.text;
    tr.append(time, dir, text);
    body.appendChild(tr);
  }
  table.appendChild(body);
  holder.replaceChildren(table);
  if (!detail.tail.length) {
    const empty = document.createElement("div");
    empty.className = "empty";
    empty.textContent = "nothing has crossed the wire since this page opened";
    holder.replaceChildren(empty);
  }
  if (follow) holder.scrollTop = holder.scrollHeight;
  setText($("tail-note"), detail.watching ? `in: to the printer, out: to the host · recorded since ${(detail.watching.since - t0).toFixed(1)} s` : "");
}

function events(detail) {
  const list = $("events");
  list.replaceChildren();
  const shown = detail.events.slice(-40).reverse();
  for (const event of shown) {
    const li = document.createElement("li");
    li.innerHTML = `<span class="t">${(event.t - detail.row.powered_on).toFixed(1)} s</span><span class="kind"></span><span class="text"></span>`;
    li.querySelector(".kind").textContent = event.kind;
    li.querySelector(".kind").style.color = COLOURS.marks[event.kind + "s"] || COLOURS.fault;
    li.querySelector(".text").textContent = event.text;
    list.appendChild(li);
  }
  if (!shown.length) list.innerHTML = '<li class="dim">none yet</li>';
}

function update(detail) {
  if (detail.gone) { live("off", "this printer is gone"); return; }
  if (detail.error) { live("off", "the farm did not answer: " + detail.error); return; }
  cards(detail);
  if (!$("pause").checked) { figure(detail); tail(detail); }
  events(detail);
  updates += 1;
  $("printer").dataset.updates = updates;
  live("on", "live · updated " + new Date().toLocaleTimeString());
}

function connect() {
  source = new EventSource("/printer/" + NUMBER + "/events");
  source.onmessage = (event) => update(JSON.parse(event.data));
  source.onerror = () => live("off", "reconnecting…");
}
addEventListener("pagehide", () => { if (source) source.close(); });
connect();
"""


def _head(title: str) -> str:
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="fake-marlin {escape(__version__)}">
<title>{escape(title)}</title>
<link rel="icon" href="data:,">
<style>
{STYLE}</style>
</head>
"""


def farm_page(printers: int) -> str:
    """The farm: a summary, filters, and one row per printer of the page shown."""
    filters = "".join(f'<button type="button" data-filter="{key}">{escape(label)}'
                      f'<span class="count"></span></button>' for key, label in FILTERS.items())
    sizes = "".join(f'<option value="{size}">{size} a page</option>' for size in PAGE_SIZES)
    cards = "".join(
        f'<div class="card {tone}"><div class="value" id="s-{key}">—</div>'
        f'<div class="label">{label}</div></div>'
        for key, label, tone in (
            ("printers", "printers", ""), ("connected", "with a host", "good"),
            ("printing", "printing", "info"), ("heating", "heating", "warn"),
            ("halted", "halted", "bad"), ("errors", "errors or resends", "warn"),
            ("rate", "commands/s in all", "info"), ("commands", "commands executed", "")))
    head = ("<tr><th>#</th><th>port</th><th>firmware · protocol</th><th>host</th><th>state</th>"
            "<th>hotend °C</th><th>bed °C</th><th>planner</th><th class=\"n\">cmd/s</th>"
            "<th class=\"n\">commands</th><th>job</th><th>last command</th>"
            "<th class=\"n\">resends</th><th class=\"n\">faults</th><th>last error</th></tr>")
    size_data = json.dumps({"sizes": list(PAGE_SIZES), "default": DEFAULT_PAGE_SIZE})
    return _head(f"fake-marlin farm · {printers:,} printers") + f"""<body>
<header>
<h1>fake-marlin farm</h1>
<p class="subtitle">{printers:,} printer{"s" * (printers != 1)} in this farm · live view by fake-marlin {escape(__version__)}</p>
<span id="live" class="live">connecting…</span>
</header>
<main id="farm" data-updates="0">
<section class="cards">{cards}</section>
<div class="toolbar">
<div class="filters" role="group" aria-label="show these printers">{filters}</div>
<div class="pager"><button id="first" type="button" title="the first page">&laquo;</button><button id="prev" type="button" title="the page before">&lsaquo;</button><span id="page-count"></span><button id="next" type="button" title="the next page">&rsaquo;</button><button id="last" type="button" title="the last page">&raquo;</button></div>
<select id="size" aria-label="printers a page">{sizes}</select>
<label>printer <input id="goto" type="number" min="1" placeholder="number" aria-label="go to printer"></label>
</div>
<div class="table-wrap">
<table class="farm" id="farm-table">
<thead>{head}</thead>
<tbody id="rows"></tbody>
</table>
<div id="none" class="empty" hidden>no printer matches this filter</div>
</div>
</main>
<script type="application/json" id="filters-data">{json.dumps(FILTERS)}</script>
<script type="application/json" id="sizes-data">{size_data}</script>
<script>
{FARM_SCRIPT}</script>
</body>
</html>
"""


def printer_page(number: int, path: str, firmware: str) -> str:
    """A printer: its state as cards, its plots, its live wire tail and its recent events."""
    colours = json.dumps({"series": list(COLOURS), "marks": MARK_COLOURS, "fault": FAULT_COLOUR})

    def card(key: str, label: str, note: bool = False, extra: str = "") -> str:
        return (f'<div class="card {extra}" id="card-{key}"><div class="value" id="c-{key}">—</div>'
                f'<div class="label">{label}</div>'
                + (f'<div class="note" id="c-{key}-note"></div>' if note else "") + "</div>")

    cards = "".join((
        card("state", "state"), card("host", "host", True),
        card("hotend", "hotend", True), card("bed", "bed", True),
        card("planner", "planner", True), card("rate", "commands/s"),
        card("commands", "commands", True), card("job", "SD job", True),
        card("resends", "resends", True), card("faults", "faults", True),
        card("error", "last error", True, "wide"),
    ))
    return _head(f"printer {number} · fake-marlin farm") + f"""<body>
<header>
<h1>Printer {number}</h1>
<p class="subtitle"><code>{escape(path)}</code> · {escape(firmware)} · <a href="/">the farm</a></p>
<span id="live" class="live">connecting…</span>
</header>
<main id="printer" data-number="{number}" data-updates="0">
<section class="cards">{cards}</section>
<div class="panels">
<section class="box" id="plots-box"><h2>Over time <span class="note">sampled once a second while this page is open</span></h2><div id="plots"></div></section>
<div>
<section class="box"><h2>Wire tail <span class="note" id="tail-note"></span></h2>
<div class="tail-controls"><label><input id="follow" type="checkbox" checked> follow the newest</label><label><input id="pause" type="checkbox"> pause</label></div>
<div id="tail"></div></section>
<section class="box" style="margin-top:14px"><h2>Events <span class="note">resends, faults, resets, connections</span></h2><ul id="events"></ul></section>
<section class="box" style="margin-top:14px"><h2>The printer</h2><table class="facts">
<tr><th>protocol</th><td id="f-protocol"></td></tr>
<tr><th>firmware</th><td id="f-firmware"></td></tr>
<tr><th>UUID</th><td id="f-uuid"></td></tr>
<tr><th>serial</th><td id="f-serial"></td></tr>
<tr><th>machine name</th><td id="f-machine"></td></tr>
<tr><th>simulated time</th><td id="f-time"></td></tr>
</table></section>
</div>
</div>
</main>
<script type="application/json" id="colours-data">{colours}</script>
<script>
{PRINTER_SCRIPT}</script>
</body>
</html>
"""


def not_found_page(what: str) -> str:
    return _head("not found · fake-marlin farm") + f"""<body>
<header><h1>fake-marlin farm</h1></header>
<main><div class="notfound"><h2>Not found</h2><p>{escape(what)}</p>
<p><a href="/">Back to the farm</a></p></div></main>
</body>
</html>
"""
