"""The report page's style sheet and script, inline in every page (it must open offline).

Kept as Python strings rather than files beside the module so that every kind of install
carries them without package data.

The script shows the wire log: the records come as one JSON array (the `log-data` element),
and only one page of rows (PAGE) is in the document at a time, so a big trace stays quick.
Search is a case-insensitive substring match on the text; the ticks choose the kinds; "go to
time" turns to the page with the first shown record at or after that simulated second.
"""

STYLE = r"""
:root { --ink: #1d2126; --muted: #5f6b76; --line: #dde1e5; --paper: #ffffff; --wash: #f5f7f9;
  --good: #1e7d3a; --good-wash: #e8f5ec; --bad: #b42318; --bad-wash: #fdecea; --warn: #8a5a00;
  --warn-wash: #fff5e0; --mono: ui-monospace, "DejaVu Sans Mono", Menlo, Consolas, monospace; }
* { box-sizing: border-box; }
body { margin: 0; background: var(--wash); color: var(--ink);
  font: 15px/1.45 system-ui, -apple-system, "Segoe UI", "DejaVu Sans", sans-serif; }
header { background: #20262d; color: #fff; padding: 18px 32px 16px; }
header h1 { margin: 0; font-size: 24px; font-weight: 650; }
header .subtitle { margin: 4px 0 0; color: #c3cbd3; font-size: 14px; }
header code { color: #fff; }
main { max-width: 1320px; margin: 0 auto; padding: 20px 32px 48px; }
h2 { font-size: 19px; margin: 28px 0 10px; }
h3 { font-size: 14px; margin: 0 0 6px; color: var(--muted); text-transform: uppercase;
  letter-spacing: .04em; }
code, pre { font-family: var(--mono); font-size: 13px; }
.verdict { border-radius: 8px; padding: 12px 18px; margin: 0 0 16px; border: 1px solid; }
.verdict p { margin: 4px 0; }
.verdict.pass { background: var(--good-wash); border-color: #a6d8b4; color: #14532d; }
.verdict.fail { background: var(--bad-wash); border-color: #f3b3ac; color: #7a1a12; }
.verdict.unknown { background: var(--paper); border-color: var(--line); color: var(--muted); }
.verdict details { margin-top: 6px; }
.verdict pre { background: rgba(255,255,255,.6); padding: 8px 10px; border-radius: 6px;
  white-space: pre-wrap; margin: 6px 0 0; color: var(--ink); }
.cards { display: grid; grid-template-columns: repeat(auto-fit, minmax(150px, 1fr)); gap: 12px; }
.card { background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  padding: 10px 14px; border-top: 4px solid #9aa5b1; }
.card .value { font-size: 28px; font-weight: 650; font-variant-numeric: tabular-nums; }
.card .label { font-weight: 600; }
.card .note { color: var(--muted); font-size: 13px; min-height: 1.2em; }
.card.bad { border-top-color: var(--bad); } .card.bad .value { color: var(--bad); }
.card.warn { border-top-color: #d99a00; } .card.warn .value { color: var(--warn); }
.tables { display: grid; grid-template-columns: repeat(auto-fit, minmax(300px, 1fr)); gap: 12px;
  margin-top: 12px; }
.tables > div { background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  padding: 12px 14px; }
.tables table { border-collapse: collapse; width: 100%; font-size: 14px; }
.tables th, .tables td { text-align: left; padding: 3px 8px 3px 0; vertical-align: top;
  border-bottom: 1px solid #eef0f2; }
.tables .facts th { color: var(--muted); font-weight: 500; width: 40%; }
.tables thead th { color: var(--muted); font-weight: 500; }
.tables td code { white-space: nowrap; }
.tables .n { text-align: right; font-variant-numeric: tabular-nums; }
.tables .none { color: var(--muted); font-style: italic; }
.notes { background: var(--warn-wash); border: 1px solid #f0d08a; border-radius: 8px;
  padding: 6px 14px; margin-top: 12px; }
.plot { margin: 0; background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  padding: 8px; }
.plot svg { display: block; width: 100%; height: auto; }
#log { background: var(--paper); border: 1px solid var(--line); border-radius: 8px;
  padding: 4px 16px 16px; margin-top: 28px; }
#log h2 { margin-top: 14px; }
.controls { display: flex; flex-wrap: wrap; gap: 10px 18px; align-items: center; }
#search { flex: 1 1 320px; font: inherit; padding: 7px 10px; border: 1px solid #b9c1c9;
  border-radius: 6px; }
.goto input { width: 7em; font: inherit; padding: 5px 6px; border: 1px solid #b9c1c9;
  border-radius: 6px; }
.kinds { display: flex; flex-wrap: wrap; gap: 4px 14px; flex-basis: 100%; font-size: 14px; }
.kinds label { white-space: nowrap; cursor: pointer; }
.kinds .count { color: var(--muted); font-variant-numeric: tabular-nums; }
.pager { display: flex; gap: 6px; align-items: center; margin: 10px 0 6px; font-size: 14px; }
.pager button { font: inherit; padding: 2px 10px; border: 1px solid #b9c1c9; border-radius: 5px;
  background: var(--wash); cursor: pointer; }
.pager button:disabled { opacity: .4; cursor: default; }
#log-count { flex: 1; text-align: center; color: var(--muted); }
#log-table { border-collapse: collapse; width: 100%; table-layout: fixed; font-size: 13px; }
#log-table th { text-align: left; color: var(--muted); font-weight: 500;
  border-bottom: 2px solid var(--line); padding: 4px 8px; }
#log-table td { padding: 2px 8px; border-bottom: 1px solid #f0f2f4; vertical-align: top; }
#log-table .time { width: 7.5em; text-align: right; font-variant-numeric: tabular-nums; }
#log-table .kind { width: 7.5em; }
#log-table td.text { font-family: var(--mono); white-space: pre-wrap; word-break: break-all; }
#log-table tr.target td { box-shadow: inset 0 2px 0 #f0b429, inset 0 -2px 0 #f0b429; }
#log-table td.time a { color: inherit; text-decoration: none; }
#log-table td.time a:hover { text-decoration: underline; }
.presets { display: flex; gap: 6px; align-items: center; font-size: 14px; color: var(--muted); }
.presets button { font: inherit; padding: 3px 10px; border: 1px solid #b9c1c9; border-radius: 5px;
  background: var(--wash); cursor: pointer; color: var(--ink); }
#log-table mark { background: #ffe58a; color: inherit; padding: 0; }
.tag { display: inline-block; padding: 0 6px; border-radius: 4px; font-size: 12px;
  font-weight: 600; background: #eef0f2; color: #444; }
.k-in .tag { background: #e3eefb; color: #1f4e8c; }
.k-out .tag { background: #e6f4ea; color: #1e6b34; }
.k-cmd .tag { background: #eef0f2; color: #39424c; }
.k-reject .tag, .k-reject td { background: var(--bad-wash); color: var(--bad); }
.k-fault .tag, .k-fault td { background: #f1eafb; color: #5b2a9a; }
.k-reset .tag { background: #20262d; color: #fff; }
.k-reset td { background: #e6e9ed; font-weight: 600; }
.k-connect .tag, .k-disconnect .tag { background: #fff0d6; color: #7a4b00; }
.k-verdict td { background: var(--good-wash); }
.k-room .tag, .k-temp .tag { background: #f6f6f6; color: #777; }
.index td, .index th { padding: 6px 12px 6px 0; }
.index .pass { color: var(--good); font-weight: 650; }
.index .fail { color: var(--bad); font-weight: 650; }
"""

SCRIPT = r"""
(function () {
  "use strict";
  var PAGE = 200;
  var data = JSON.parse(document.getElementById("log-data").textContent);
  var rows = data.rows, kinds = data.kinds;
  var shown = data.hidden.map(function (hidden) { return !hidden; });
  var lower = null;  // the texts in lower case, made at the first search
  var search = document.getElementById("search");
  var goto = document.getElementById("goto");
  var table = document.getElementById("log-table");
  var body = table.querySelector("tbody");
  var counter = document.getElementById("log-count");
  var buttons = {first: document.getElementById("first"), prev: document.getElementById("prev"),
                 next: document.getElementById("next"), last: document.getElementById("last")};
  var matching = [], page = 0, target = -1, query = "";

  var counts = kinds.map(function () { return 0; });
  rows.forEach(function (row) { counts[row[1]] += 1; });
  var box = document.getElementById("kinds");
  kinds.forEach(function (kind, i) {
    if (!counts[i]) { return; }
    var label = document.createElement("label");
    label.className = "k-" + kind;
    var input = document.createElement("input");
    input.type = "checkbox";
    input.checked = shown[i];
    input.setAttribute("data-kind", kind);
    input.addEventListener("change", function () { shown[i] = input.checked; refilter(); });
    var count = document.createElement("span");
    count.className = "count";
    count.textContent = "(" + counts[i].toLocaleString("en") + ")";
    label.appendChild(input);
    label.appendChild(document.createTextNode(" " + data.labels[i] + " "));
    label.appendChild(count);
    box.appendChild(label);
  });

  var inputs = box.querySelectorAll("input");
  function showKinds(wanted) {  // wanted(kind, i): whether to show that kind
    kinds.forEach(function (kind, i) { shown[i] = wanted(kind, i); });
    inputs.forEach(function (input) { input.checked = shown[kinds.indexOf(input.dataset.kind)]; });
  }
  var PROBLEMS = ["reject", "fault", "reset", "connect", "disconnect", "verdict"];
  var presets = {
    "preset-conversation": function (kind, i) { return !data.hidden[i]; },
    "preset-problems": function (kind) { return PROBLEMS.indexOf(kind) >= 0; },
    "preset-all": function () { return true; }
  };
  Object.keys(presets).forEach(function (id) {
    document.getElementById(id).addEventListener("click", function () {
      showKinds(presets[id]);
      refilter();
    });
  });

  function refilter() {
    query = search.value.toLowerCase();
    if (query && lower === null) {
      lower = rows.map(function (row) { return String(row[2]).toLowerCase(); });
    }
    matching = [];
    for (var i = 0; i < rows.length; i++) {
      if (shown[rows[i][1]] && (!query || lower[i].indexOf(query) >= 0)) { matching.push(i); }
    }
    page = 0;
    target = -1;
    render();
  }

  function pages() { return Math.max(1, Math.ceil(matching.length / PAGE)); }

  function cell(text, className) {
    var td = document.createElement("td");
    if (className) { td.className = className; }
    if (typeof text === "string") { td.textContent = text; } else { td.appendChild(text); }
    return td;
  }

  function marked(text) {
    var part = document.createDocumentFragment();
    if (!query) { part.appendChild(document.createTextNode(text)); return part; }
    var low = text.toLowerCase(), at = 0, found;
    while ((found = low.indexOf(query, at)) >= 0) {
      part.appendChild(document.createTextNode(text.slice(at, found)));
      var mark = document.createElement("mark");
      mark.textContent = text.slice(found, found + query.length);
      part.appendChild(mark);
      at = found + query.length;
    }
    part.appendChild(document.createTextNode(text.slice(at)));
    return part;
  }

  function render() {
    var fragment = document.createDocumentFragment();
    var start = page * PAGE, stop = Math.min(matching.length, start + PAGE);
    for (var j = start; j < stop; j++) {
      var row = rows[matching[j]];
      var tr = document.createElement("tr");
      tr.className = "k-" + kinds[row[1]] + (matching[j] === target ? " target" : "");
      var tag = document.createElement("span");
      tag.className = "tag";
      tag.textContent = kinds[row[1]];
      var time = document.createElement("a");
      time.href = "#log";
      time.title = "show this record among the whole conversation";
      time.setAttribute("data-record", String(matching[j]));
      time.textContent = row[0].toFixed(3);
      tr.appendChild(cell(time, "time"));
      tr.appendChild(cell(tag, "kind"));
      tr.appendChild(cell(marked(String(row[2])), "text"));
      fragment.appendChild(tr);
    }
    body.replaceChildren(fragment);
    table.setAttribute("data-query", query);  // what the rows shown were filtered by
    counter.textContent = matching.length
      ? "records " + (start + 1).toLocaleString("en") + "\u2013" + stop.toLocaleString("en") +
        " of " + matching.length.toLocaleString("en") + " shown (" +
        rows.length.toLocaleString("en") + " in the trace)"
      : "no record matches";
    buttons.first.disabled = buttons.prev.disabled = page === 0;
    buttons.next.disabled = buttons.last.disabled = page >= pages() - 1;
  }

  function turn(to) { page = Math.min(Math.max(0, to), pages() - 1); target = -1; render(); }

  function context(record) {  // the record among the conversation, with no search
    search.value = "";
    showKinds(function (kind, i) { return !data.hidden[i] || i === rows[record][1]; });
    refilter();
    var at = matching.indexOf(record);
    page = Math.floor(at / PAGE);
    target = record;
    render();
    var row = body.querySelector("tr.target");
    if (row) { row.scrollIntoView({block: "center"}); }
  }
  body.addEventListener("click", function (event) {
    var link = event.target.closest("a[data-record]");
    if (link) { event.preventDefault(); context(Number(link.getAttribute("data-record"))); }
  });

  function jump() {
    var when = parseFloat(goto.value);
    if (isNaN(when) || !matching.length) { return; }
    var low = 0, high = matching.length;  // the first shown record at or after `when`
    while (low < high) {
      var middle = (low + high) >> 1;
      if (rows[matching[middle]][0] < when) { low = middle + 1; } else { high = middle; }
    }
    low = Math.min(low, matching.length - 1);
    page = Math.floor(low / PAGE);
    target = matching[low];
    render();
    var row = body.querySelector("tr.target");
    if (row) { row.scrollIntoView({block: "center"}); }
  }

  var timer = null;
  search.addEventListener("input", function () {
    clearTimeout(timer);
    timer = setTimeout(refilter, rows.length > 20000 ? 250 : 60);
  });
  goto.addEventListener("change", jump);
  buttons.first.addEventListener("click", function () { turn(0); });
  buttons.prev.addEventListener("click", function () { turn(page - 1); });
  buttons.next.addEventListener("click", function () { turn(page + 1); });
  buttons.last.addEventListener("click", function () { turn(pages() - 1); });
  document.addEventListener("keydown", function (event) {
    var typing = /^(INPUT|TEXTAREA|SELECT)$/.test(document.activeElement.tagName);
    if (event.key === "/" && !typing) { event.preventDefault(); search.focus(); }
  });
  refilter();
})();
"""
