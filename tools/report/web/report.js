// voxfmt report page: summary, plots, a virtual table, an asset card and its 3D view. Plain scripts (no
// modules, no fetch): the page opens from file://. Everything is inside one function so three.js, loaded later
// as a classic script, cannot collide with a name of ours.
(function () {
  'use strict';

  const R = window.VOXFMT_REPORT;
  const $ = (id) => document.getElementById(id);

  // ---- small helpers
  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === undefined || v === null || v === false) continue;
      if (k === 'class') e.className = v;
      else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
      else e.setAttribute(k, v === true ? '' : v);
    }
    for (const c of children.flat()) if (c !== null && c !== undefined) e.append(c instanceof Node ? c : String(c));
    return e;
  }
  const num = (v) => (typeof v === 'number' && isFinite(v) ? v : null);
  function bytes(b) {
    b = num(b);
    if (b === null) return '';
    if (b >= 1 << 30) return (b / (1 << 30)).toFixed(2) + ' GiB';
    if (b >= 1 << 20) return (b / (1 << 20)).toFixed(1) + ' MiB';
    if (b >= 1024) return (b / 1024).toFixed(1) + ' KiB';
    return b + ' B';
  }
  function seconds(s) {
    s = num(s);
    if (s === null) return '';
    if (s >= 3600) return (s / 3600).toFixed(2) + ' h';
    if (s >= 60) return (s / 60).toFixed(1) + ' min';
    return s >= 10 ? s.toFixed(1) + ' s' : s.toFixed(2) + ' s';
  }
  // Axis ticks sit at powers of ten: named in decimal units ("10 kB", "1 ms"), where bytes() and seconds() would
  // round them ("9.8 KiB", "0.00 s").
  function tickBytes(b) {
    const units = [[1e12, 'TB'], [1e9, 'GB'], [1e6, 'MB'], [1e3, 'kB']];
    for (const [size, unit] of units) if (b >= size) return Number((b / size).toPrecision(3)) + ' ' + unit;
    return Number(b.toPrecision(3)) + ' B';
  }
  function tickSeconds(s) {
    if (s >= 1) return Number(s.toPrecision(3)).toLocaleString('en-US') + ' s';
    if (s >= 1e-3) return Number((s * 1e3).toPrecision(3)) + ' ms';
    return Number((s * 1e6).toPrecision(3)) + ' µs';
  }
  // Only the report's own keys, never inherited ones, name files to load.
  const own = (o, key) => Object.prototype.hasOwnProperty.call(o, key) && typeof o[key] === 'string' && /^(img|assets)\/[0-9]+[-a-z]*\.(png|js)$/.test(o[key]);
  const count = (v) => (num(v) === null ? '' : v.toLocaleString('en-US'));
  const text = (v) => (v === undefined || v === null ? '' : typeof v === 'object' ? JSON.stringify(v) : String(v));

  if (!R || !Array.isArray(R.rows)) {
    const f = $('fatal');
    f.hidden = false;
    f.textContent = 'data.js is missing or damaged: run `voxfmt report` again.';
    return;
  }

  const built = (st) => st === 'ok' || st === 'up_to_date';

  // ---- the rows, with the fields the page sorts and filters on
  const rows = R.rows.map((r) => {
    const warnings = Array.isArray(r.warnings) ? r.warnings.filter((w) => w && typeof w === 'object') : [];
    const error = r.error && typeof r.error === 'object' ? r.error : r.asset_error && typeof r.asset_error === 'object' ? r.asset_error : null;
    const dims = r.voxelmap && Array.isArray(r.voxelmap.dims) && r.voxelmap.dims.length === 3 ? r.voxelmap.dims.map(Number) : null;
    const unreadable = !!r.asset_error;
    const state = unreadable ? 'unreadable' : text(r.status) || 'unknown';
    // Only a readable built asset's grid, size and distances are a file's now: an unreadable asset's in the manifest
    // are the bake's (the card shows them as recorded at bake, the table its real size), and a failed mesh has no
    // file. The table, the plots and the totals leave the others out.
    const readable = !unreadable && (r.status === 'ok' || r.status === 'up_to_date');
    const current = readable ? dims : null;
    return {
      raw: r, id: r.id, name: text(r.name), output: text(r.output_name), state, warnings,
      warningCodes: warnings.map((w) => text(w.code)),
      errorCode: error ? text(error.code) : '',
      error,
      triangles: num(r.input_triangles),
      dims: current,
      recordedDims: dims,
      resolution: current ? Math.max(current[0], current[1], current[2]) : null,
      size: unreadable ? num(r.asset_bytes) : readable ? num(r.file_size_bytes) : null,
      time: num(r.total_s) !== null ? r.total_s : num(r.wall_s),
      stored: r.voxelmap && readable ? num(r.voxelmap.stored_distances) : null,
    };
  });
  // Names shared by meshes in different subfolders: those rows also say where they lie below the library.
  const nameCount = new Map();
  for (const r of rows) nameCount.set(r.name, (nameCount.get(r.name) || 0) + 1);
  const ambiguous = (name) => nameCount.get(name) > 1;
  const byId = new Map(rows.map((r) => [r.id, r]));

  // ---- header
  const single = R.kind === 'asset';
  $('title').textContent = single ? 'voxfmt asset: ' + (rows[0] ? rows[0].name : '') : 'voxfmt library report';
  $('subtitle').textContent = (single ? '' : R.library + ' · ') + 'written ' + text(R.generated_utc) + ' by voxfmt ' + text(R.tool_version) +
    (R.skipped_lines ? ' · ' + R.skipped_lines + ' manifest line(s) were not records and are not shown' : '');

  // ---- filters and sorting state
  const filter = { name: '', status: '', code: '', size: '', time: '' };
  let sortKey = 'name', sortDesc = false;
  let visible = rows.slice();

  // ---- summary
  function summary() {
    const s = $('summary');
    const by = (status) => rows.filter((r) => r.raw.status === status).length;
    const sum = (key) => rows.reduce((a, r) => a + (r[key] || 0), 0);
    // A folder of assets without a manifest knows no bake times or inputs: unknown, not zero.
    const known = (key, show) => (rows.some((r) => r[key] !== null) ? show(sum(key)) : '—');
    const warned = rows.filter((r) => r.warnings.length).length;
    const tile = (cls, value, label, state) => el('div', { class: 'tile ' + cls, 'data-count': label, onclick: state ? () => setFilter({ status: state }) : null },
      el('b', {}, value), el('span', {}, label));
    s.append(el('h2', {}, 'Summary'), el('div', { class: 'tiles', id: 'tiles' },
      tile('', count(rows.length), 'meshes'),
      tile('ok', count(by('ok')), 'built', 'ok'),
      tile('ok', count(by('up_to_date')), 'up to date', 'up_to_date'),
      tile('failed', count(by('failed')), 'failed', 'failed'),
      tile('failed', count(rows.filter((r) => r.state === 'unreadable').length), 'unreadable assets', 'unreadable'),
      tile('warn', count(warned), 'with warnings'),
      tile('', known('time', seconds), 'total bake time'),
      tile('', known('triangles', count), 'input triangles'),
      tile('', count(sum('stored')), 'stored distances'),
      // Readable assets only: an unreadable one's bytes are a broken file's (its distances are left out already).
      tile('', bytes(rows.reduce((a, r) => a + (r.state === 'unreadable' ? 0 : r.size || 0), 0)), 'asset bytes')));
    const codes = (list) => {
      const m = new Map();
      for (const c of list) m.set(c, (m.get(c) || 0) + 1);
      return [...m.entries()].sort((a, b) => b[1] - a[1] || a[0].localeCompare(b[0]));
    };
    const failures = codes(rows.filter((r) => r.errorCode).map((r) => r.errorCode));
    const warnings = codes(rows.flatMap((r) => [...new Set(r.warningCodes)]));
    const bars = (title, list, cls) => {
      if (!list.length) return null;
      const most = list[0][1];
      return [el('h3', {}, title), el('div', { class: 'bars' }, list.flatMap(([code, n]) => [
        el('span', { class: 'bar-label', 'data-code': code, onclick: () => setFilter({ code }) }, code),
        el('div', { class: 'bar ' + cls, style: 'width:' + Math.max(4, (100 * n) / most) + '%', title: n + ' mesh(es)', onclick: () => setFilter({ code }) }, String(n)),
      ]))];
    };
    s.append(...[bars('Failures by code', failures, 'fail'), bars('Warnings by code (meshes)', warnings, 'warn')].flat().filter(Boolean));
    for (const [code] of failures.concat(warnings)) $('filter-code').append(el('option', { value: code }, code));
    // Every state a tile can filter on, present or not: the dropdown always names the filter that emptied the table.
    const states = new Set(['ok', 'up_to_date', 'failed', 'unreadable', ...rows.map((r) => r.state)]);
    for (const st of [...states].sort()) $('filter-status').append(el('option', { value: st }, st.replace(/_/g, ' ')));
  }

  // ---- comparison with another bake
  function compare() {
    if (!R.against || !Array.isArray(R.against.rows)) return;
    const sec = $('compare');
    sec.hidden = false;
    // Keyed by the asset's path below each library: meshes of one name in two subfolders stay apart.
    const old = new Map(R.against.rows.map((r) => [text(r.output), r]));
    const now = new Map(rows.map((r) => [r.output, r]));
    // Each side's state as its table would show it: an asset the manifest calls built that is gone or unreadable
    // is not built, whatever the manifest says.
    const oldState = (o) => (o.asset_error ? 'unreadable' : text(o.status) || 'unknown');
    const oldError = (o) => (o.error && typeof o.error === 'object' ? o.error : o.asset_error && typeof o.asset_error === 'object' ? o.asset_error : null);
    const kind = (st) => (built(st) ? 'built' : st);
    // A name two meshes share (here or there) is followed by the asset's path, which tells them apart.
    const nameCount = new Map();
    for (const key of new Set([...old.keys(), ...now.keys()])) {
      const name = now.has(key) ? now.get(key).name : text(old.get(key).name);
      nameCount.set(name, (nameCount.get(name) || 0) + 1);
    }
    const label = (name, key) => (nameCount.get(name) > 1 ? name + ' (' + key + ')' : name);
    const t = R.thresholds || { size: 0.1, time: 0.25 };
    const changes = { appeared: [], disappeared: [], status: [], grew: [], shrank: [], slower: [] };
    for (const [key, r] of now) {
      const o = old.get(key);
      const line = (what) => [label(r.name, key), what, key];
      if (!o) { changes.appeared.push(line(r.state)); continue; }
      const os = oldState(o), oe = oldError(o), oc = oe ? text(oe.code) : '';
      // A folder's asset without a manifest was not read for the comparison: whether it was readable is not known.
      const unknown = o.unread === true && r.state === 'unreadable';
      if (!unknown && (kind(os) !== kind(r.state) || oc !== r.errorCode))
        changes.status.push(line(os.replace(/_/g, ' ') + (oc ? ' ' + oc : '') + ' → ' + r.state.replace(/_/g, ' ') + (r.errorCode ? ' ' + r.errorCode : '')));
      // Sizes and times of readable bakes on both sides only: an unreadable asset's figures are not its file's.
      if (!built(os) || !built(r.state)) continue;
      if (num(o.file_size_bytes) && r.size) {
        const ratio = r.size / o.file_size_bytes - 1;
        if (ratio > t.size) changes.grew.push(line(bytes(o.file_size_bytes) + ' → ' + bytes(r.size) + ' (+' + (100 * ratio).toFixed(0) + ' %)'));
        if (ratio < -t.size) changes.shrank.push(line(bytes(o.file_size_bytes) + ' → ' + bytes(r.size) + ' (' + (100 * ratio).toFixed(0) + ' %)'));
      }
      // Only fresh bakes on both sides: an up-to-date record keeps the older bake's time.
      if (num(o.total_s) && r.time && o.status === 'ok' && r.raw.status === 'ok' && r.time / o.total_s - 1 > t.time)
        changes.slower.push(line(seconds(o.total_s) + ' → ' + seconds(r.time) + ' (×' + (r.time / o.total_s).toFixed(2) + ')'));
    }
    for (const [key, o] of old) if (!now.has(key)) changes.disappeared.push([label(text(o.name), key), oldState(o).replace(/_/g, ' '), key]);
    const labels = {
      appeared: 'appeared', disappeared: 'disappeared', status: 'changed status',
      grew: 'grew by more than ' + Math.round(100 * t.size) + ' %', shrank: 'shrank by more than ' + Math.round(100 * t.size) + ' %',
      slower: 'bake more than ' + Math.round(100 * t.time) + ' % slower',
    };
    sec.append(el('h2', {}, 'Against ' + text(R.against.library)));
    const table = el('table', { id: 'compare-counts' }, Object.keys(changes).map((k) => el('tr', { 'data-change': k }, el('th', {}, labels[k]), el('td', {}, String(changes[k].length)))));
    sec.append(table);
    for (const k of Object.keys(changes)) {
      if (!changes[k].length) continue;
      sec.append(el('h3', {}, labels[k]), el('div', { class: 'change-list', 'data-change-list': k },
        changes[k].map(([name, what, key]) => el('div', { 'data-output': key, title: key }, el('b', {}, name), ' ', what))));
    }
  }

  // ---- plots (canvas, log-log)
  function plot(canvas, xKey, yKey, xLabel, yLabel, xFmt, yFmt) {
    const pts = rows.filter((r) => r[xKey] > 0 && r[yKey] > 0);
    const ctx = canvas.getContext('2d');
    const W = canvas.width, H = canvas.height, L = 58, B = 36, T = 10, Rm = 12;
    ctx.fillStyle = '#fff';
    ctx.fillRect(0, 0, W, H);
    if (!pts.length) {
      ctx.fillStyle = '#5c6776';
      // Built meshes without these figures: assets reported without their batch's manifest.
      const message = rows.some((r) => built(r.state)) ? 'no ' + yLabel + ' recorded (no manifest)' : 'no built meshes';
      ctx.fillText(message, W / 2 - 3 * message.length, H / 2);
      return;
    }
    const lx = pts.map((r) => Math.log10(r[xKey])), ly = pts.map((r) => Math.log10(r[yKey]));
    let [x0, x1] = [Math.min(...lx), Math.max(...lx)], [y0, y1] = [Math.min(...ly), Math.max(...ly)];
    if (x1 - x0 < 1) { x0 -= 0.5; x1 += 0.5; }
    if (y1 - y0 < 1) { y0 -= 0.5; y1 += 0.5; }
    x0 = Math.floor(x0); y0 = Math.floor(y0); x1 = Math.ceil(x1); y1 = Math.ceil(y1);
    const X = (v) => L + ((v - x0) / (x1 - x0)) * (W - L - Rm), Y = (v) => H - B - ((v - y0) / (y1 - y0)) * (H - B - T);
    ctx.strokeStyle = '#d9dee5';
    ctx.fillStyle = '#5c6776';
    ctx.font = '11px system-ui, sans-serif';
    for (let e = x0; e <= x1; ++e) {
      ctx.beginPath(); ctx.moveTo(X(e), T); ctx.lineTo(X(e), H - B); ctx.stroke();
      const label = xFmt(Math.pow(10, e));
      ctx.fillText(label, Math.min(X(e) - 12, W - Rm - ctx.measureText(label).width), H - B + 14);
    }
    for (let e = y0; e <= y1; ++e) {
      ctx.beginPath(); ctx.moveTo(L, Y(e)); ctx.lineTo(W - Rm, Y(e)); ctx.stroke();
      ctx.fillText(yFmt(Math.pow(10, e)), 4, Y(e) + 4);
    }
    ctx.fillText(xLabel, W / 2 - 30, H - 6);
    ctx.fillText(yLabel, L + 4, T + 10);
    const placed = pts.map((r, i) => ({ r, x: X(lx[i]), y: Y(ly[i]) }));
    for (const p of placed) {
      ctx.fillStyle = p.r.warnings.length ? 'rgba(183,121,31,.75)' : 'rgba(47,109,181,.7)';
      ctx.beginPath(); ctx.arc(p.x, p.y, 3, 0, 2 * Math.PI); ctx.fill();
    }
    canvas.title = 'click a point to open its card';
    canvas.addEventListener('click', (ev) => {
      const box = canvas.getBoundingClientRect();
      const mx = ((ev.clientX - box.left) * W) / box.width, my = ((ev.clientY - box.top) * H) / box.height;
      let best = null, bestD = 64;
      for (const p of placed) {
        const d = (p.x - mx) ** 2 + (p.y - my) ** 2;
        if (d < bestD) { best = p; bestD = d; }
      }
      if (best) openCard(best.r.id);
    });
  }

  // ---- the table: only the rows in view are in the DOM (10,000 meshes stay fast)
  const columns = [
    { key: 'name', label: 'mesh', title: (r) => r.output, cell: (r) => [r.name, ambiguous(r.name) ? el('span', { class: 'where' }, ' ' + r.output) : null] },
    { key: 'state', label: 'status', cell: (r) => el('span', { class: 'status ' + r.state }, r.state.replace(/_/g, ' ')) },
    { key: 'codes', label: 'codes', cell: (r) => [r.errorCode ? el('span', { class: 'code error' }, r.errorCode) : null, ...r.warningCodes.map((c) => el('span', { class: 'code' }, c))] },
    { key: 'triangles', label: 'triangles', num: true, cell: (r) => count(r.triangles) },
    { key: 'resolution', label: 'grid', num: true, cell: (r) => (r.dims ? r.dims.join(' × ') : '') },
    { key: 'size', label: 'size', num: true, cell: (r) => bytes(r.size) },
    { key: 'time', label: 'time', num: true, cell: (r) => seconds(r.time) },
  ];
  const ROW = 26;
  function tableHead() {
    const head = $('table-head');
    for (const c of columns) {
      head.append(el('div', { role: 'columnheader', 'data-key': c.key, class: c.num ? 'num' : '', onclick: () => {
        if (sortKey === c.key) sortDesc = !sortDesc; else { sortKey = c.key; sortDesc = !!c.num; }
        apply();
      } }, c.label));
    }
    $('table-body').addEventListener('scroll', renderRows, { passive: true });
  }
  function sortValue(r, key) {
    if (key === 'codes') return (r.errorCode ? '0' + r.errorCode : '1') + r.warningCodes.join(',');
    return r[key];
  }
  function apply() {
    const q = filter.name.toLowerCase();
    visible = rows.filter((r) => (!q || r.name.toLowerCase().includes(q)) &&
      (!filter.status || r.state === filter.status || r.raw.status === filter.status) &&
      (!filter.code || r.errorCode === filter.code || r.warningCodes.includes(filter.code)) &&
      (filter.size === '' || (r.size !== null && r.size >= Number(filter.size) * 1048576)) &&
      (filter.time === '' || (r.time !== null && r.time >= Number(filter.time))));
    const dir = sortDesc ? -1 : 1;
    visible.sort((a, b) => {
      const x = sortValue(a, sortKey), y = sortValue(b, sortKey);
      if (x === y) return a.name.localeCompare(b.name);
      if (x === null || x === undefined) return 1;
      if (y === null || y === undefined) return -1;
      return (typeof x === 'string' ? x.localeCompare(y) : x - y) * dir;
    });
    for (const h of $('table-head').children) {
      h.classList.toggle('sorted', h.dataset.key === sortKey);
      h.classList.toggle('desc', h.dataset.key === sortKey && sortDesc);
    }
    $('filter-count').textContent = visible.length + ' of ' + rows.length + ' meshes';
    $('table-spacer').style.height = visible.length * ROW + 'px';
    $('table-body').scrollTop = 0;
    renderRows();
  }
  function renderRows() {
    const body = $('table-body');
    const first = Math.max(0, Math.floor(body.scrollTop / ROW) - 5);
    const last = Math.min(visible.length, first + Math.ceil(body.clientHeight / ROW) + 10);
    const box = $('table-rows');
    box.style.top = first * ROW + 'px';
    box.replaceChildren(...visible.slice(first, last).map((r) =>
      el('div', { class: 'trow', role: 'row', 'data-id': r.id, onclick: () => openCard(r.id) },
        columns.map((c) => el('div', { class: c.num ? 'num' : '', role: 'cell', title: c.title ? c.title(r) : null }, c.cell(r))))));
  }
  function setFilter(change) {
    Object.assign(filter, change);
    $('filter-name').value = filter.name;
    $('filter-status').value = filter.status;
    $('filter-code').value = filter.code;
    $('filter-size').value = filter.size;
    $('filter-time').value = filter.time;
    apply();
    $('library').scrollIntoView({ block: 'start' });
  }

  // ---- asset details, loaded on demand as scripts (assets/ID.js calls voxfmtReport.addAsset)
  const details = new Map(), waiting = new Map();
  window.voxfmtReport = {
    addAsset(id, detail) {
      details.set(id, detail);
      for (const f of waiting.get(id) || []) f(detail);
      waiting.delete(id);
    },
  };
  function loadScript(src) {
    return new Promise((resolve, reject) => {
      const s = el('script', { src });
      s.onload = resolve;
      s.onerror = () => reject(new Error(src + ' could not be loaded'));
      document.body.append(s);
    });
  }
  function loadDetail(row) {
    if (details.has(row.id)) return Promise.resolve(details.get(row.id));
    if (!own(row.raw, 'detail')) return Promise.resolve(null);
    return new Promise((resolve, reject) => {
      if (!waiting.has(row.id)) {
        waiting.set(row.id, []);
        loadScript(row.raw.detail).catch(reject);
      }
      waiting.get(row.id).push(resolve);
    });
  }

  function table(pairs) {
    return el('table', {}, pairs.filter((p) => p && p[1] !== '' && p[1] !== null && p[1] !== undefined).map(([k, v]) => el('tr', {}, el('th', {}, k), el('td', {}, v))));
  }
  // A heading and its table, or nothing when no row has a value (an asset alone has no manifest record: no input,
  // no bake settings).
  function titled(title, pairs) {
    const t = table(pairs);
    return t.rows.length ? [el('h3', {}, title), t] : null;
  }

  let viewer = null;
  function closeCard() {
    if (viewer) { viewer.dispose(); viewer = null; }
    $('card').hidden = true;
    if (location.hash) history.replaceState(null, '', location.pathname + location.search);
  }
  function openCard(id) {
    const row = byId.get(id);
    if (!row) return;
    if (viewer) { viewer.dispose(); viewer = null; }
    const r = row.raw, card = $('card');
    card.hidden = false;
    card.scrollTop = 0;
    card.dataset.id = id;
    const p = r.build_parameters && typeof r.build_parameters === 'object' ? r.build_parameters : {};
    const warnings = row.warnings.map((w) => el('li', {}, el('span', { class: 'code' }, text(w.code)), text(w.message)));
    // An open surface is baked solid by the winding number unless the bake fell back to a shell (SHELL_MODE) or
    // was asked for one (--shell-thickness).
    const shell = row.warningCodes.includes('SHELL_MODE') || num(p.shell_thickness) > 0;
    const closed = r.closed === undefined ? '' : (r.closed ? 'yes' : 'no (open border)') + (shell ? ', baked as a shell' : '');
    card.replaceChildren(...[
      single ? null : el('button', { class: 'close', type: 'button', onclick: closeCard, title: 'close (Esc)' }, '×'),
      el('h2', { id: 'card-name', title: row.output || null }, row.name),
      ambiguous(row.name) && !single ? el('div', { class: 'note', id: 'card-where' }, row.output) : null,
      el('div', {}, el('span', { class: 'status ' + row.state, id: 'card-status' }, row.state.replace(/_/g, ' ')), r.tool_version ? ' · voxfmt ' + text(r.tool_version) : '', r.finished_utc ? ' · ' + text(r.finished_utc) : ''),
      row.error ? el('div', { class: 'error-box', id: 'card-error' }, el('span', { class: 'code error', id: 'card-error-code' }, text(row.error.code)), text(row.error.message)) : null,
      el('div', { class: 'pictures', id: 'card-pictures' },
        own(r, 'views') ? el('figure', {}, el('img', { src: r.views, alt: 'front, side and top views of the point shell', width: 384, height: 128 }), el('figcaption', {}, 'point shell: front · side · top')) : null,
        own(r, 'slice') ? el('figure', {}, el('img', { src: r.slice, alt: 'middle slice of the voxelmap' }), el('figcaption', {}, 'mid slice: inside red, outside blue, surface black')) : null),
      own(r, 'detail') && r.has_3d === true ? el('div', { id: 'viewer' }, el('button', { type: 'button', id: 'open-3d', onclick: () => open3d(row) }, 'Open the 3D view')) : null,
      titled('Input', [['file', text(r.input)], ['triangles', count(r.input_triangles)], ['vertices', count(r.input_vertices)], ['bytes', bytes(r.input_bytes)],
        ['closed', closed], ['sha256', text(r.source_sha256)]]),
      warnings.length ? [el('h3', {}, 'Bake warnings'), el('ul', { class: 'findings', id: 'card-warnings' }, warnings)] : null,
      assetSection(row),
      titled('Bake settings', Object.entries(p).map(([k, v]) => [k.replace(/_/g, ' '), text(v)])),
      r.timings_s && typeof r.timings_s === 'object' ? [el('h3', {}, 'Time per stage'),
        table([...Object.entries(r.timings_s).map(([k, v]) => [k, seconds(v)]), ['total', seconds(r.total_s)], ['wall (with the process)', seconds(r.wall_s)], ['peak memory', bytes(r.peak_memory_bytes)]])] : null,
      validation(r),
      el('div', { id: 'card-provenance' })].flat().filter((c) => c !== null && c !== undefined));
    if (!single) history.replaceState(null, '', '#asset-' + id);
    loadDetail(row).then((d) => d && provenance(d)).catch((e) => {
      $('card-provenance').append(el('p', { class: 'note' }, e.message));
    });
  }
  // The asset's facts: none for a mesh that failed (no file was ever written); for an unreadable one, the file as it
  // is now, and the manifest's figures labelled as the bake's.
  function assetSection(row) {
    const r = row.raw;
    if (row.state !== 'unreadable' && r.status !== 'ok' && r.status !== 'up_to_date') return null;
    const figures = [['grid', row.recordedDims ? row.recordedDims.join(' × ') + ' voxels' : ''],
      ['voxel size', r.voxelmap && num(r.voxelmap.voxel_size) ? (r.voxelmap.voxel_size * 1000).toPrecision(4) + ' mm' : ''],
      ['stored distances', r.voxelmap ? count(num(r.voxelmap.stored_distances)) : ''],
      ['points per level', r.pointshell && Array.isArray(r.pointshell.points_per_level) ? r.pointshell.points_per_level.join(', ') : ''],
      ['volume', num(r.volume) !== null ? r.volume.toPrecision(4) + ' m³' : '']];
    if (row.state !== 'unreadable')
      return titled('Asset', [['file', text(r.output)], ['file size', bytes(r.file_size_bytes)], ['memory (loaded)', bytes(r.memory_bytes)], ...figures]);
    return [...titled('Asset', [['file', text(r.output)], ['file size now', row.size === null ? 'no file' : bytes(row.size)]]),
      ...(titled('Recorded at bake (not this file now)', [['file size', bytes(r.file_size_bytes)], ...figures]) || [])];
  }
  function validation(r) {
    if (!r.validation) return null;
    const v = r.validation;
    return [el('h3', {}, 'Validation'),
      el('div', { id: 'card-validation', class: 'verdict ' + (v.valid ? 'valid' : 'invalid') },
        v.valid ? 'valid' + (v.count ? ' (' + v.count + ' warning(s))' : '') : 'invalid: ' + v.count + ' finding(s)'),
      Array.isArray(v.findings) && v.findings.length ? el('ul', { class: 'findings' }, v.findings.map((f) =>
        el('li', {}, el('span', { class: 'code' + (f.severity === 'error' ? ' error' : '') }, text(f.code)), text(f.path) + ': ' + text(f.message)))) : null];
  }
  function provenance(detail) {
    const i = detail.inspect;
    if (!i || typeof i !== 'object') return;
    const pr = i.provenance || {};
    $('card-provenance').append(el('h3', {}, 'Provenance'), table([
      ['format', Array.isArray(i.format_version) ? i.format_version.join('.') : ''],
      ['estimates', i.voxelmap ? text(i.voxelmap.estimates) : ''],
      ['generator', text(pr.generator) + ' ' + text(pr.generator_version)],
      ['source', text(pr.source_file)], ['created', text(pr.created_utc)],
      ['dependencies', pr.dependency_versions ? Object.entries(pr.dependency_versions).map(([k, v]) => k + ' ' + v).join(', ') : ''],
    ]));
  }

  // ---- the 3D view (three.js, loaded the first time it is opened)
  let threeLoading = null;
  function loadThree() {
    if (window.THREE) return Promise.resolve(window.THREE);
    if (!threeLoading) {
      window.exports = {};  // three.cjs assigns its classes to `exports`
      threeLoading = loadScript('three.cjs.js').then(() => {
        window.THREE = window.exports;
        return window.THREE;
      }, () => { throw new Error('three.js is not in this report (voxfmt was built without it), so there is no 3D view'); });
    }
    return threeLoading;
  }
  async function inflate(b64) {
    const raw = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const stream = new Blob([raw]).stream().pipeThrough(new DecompressionStream('deflate'));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }
  async function open3d(row) {
    const box = $('viewer');
    box.replaceChildren(el('p', { class: 'note' }, 'loading…'));
    try {
      const [THREE, detail] = await Promise.all([loadThree(), loadDetail(row)]);
      if (!detail || !detail.scene) throw new Error('this asset has no 3D data in the report');
      if ($('card').dataset.id !== String(row.id)) return;  // another card opened meanwhile
      viewer = await makeViewer(THREE, box, detail.scene);
    } catch (e) {
      box.replaceChildren(el('p', { class: 'note', id: 'viewer-error' }, e.message));
    }
  }

  async function makeViewer(THREE, box, scene) {
    const shell = scene.shell, field = scene.field;
    const [shellBytes, fieldBytes] = await Promise.all([inflate(shell.data), inflate(field.data)]);
    const [lo, hi] = scene.bounds;
    const n = shell.points;
    const centre = lo.map((v, a) => 0.5 * (v + hi[a]));
    const extent = Math.max(...hi.map((v, a) => v - lo[a]), 1e-9);
    // Points: 12 bits over the bounds (low bytes, then high bytes), then int8 normals.
    const pos = new Float32Array(3 * n), nor = new Float32Array(3 * n);
    for (let i = 0; i < 3 * n; ++i) {
      const a = i % 3;
      pos[i] = lo[a] + ((shellBytes[i] | (shellBytes[3 * n + i] << 8)) / 4095) * (hi[a] - lo[a]) - centre[a];
      nor[i] = ((shellBytes[6 * n + i] << 24) >> 24) / 127;
    }
    const offsets = shell.level_offsets;
    const levelOf = new Uint8Array(n);
    for (let l = 0; l + 1 < offsets.length; ++l) levelOf.fill(l, offsets[l], offsets[l + 1]);
    const colours = new Float32Array(3 * n);
    const palette = [[0.85, 0.2, 0.2], [0.95, 0.55, 0.1], [0.85, 0.8, 0.1], [0.3, 0.7, 0.3], [0.2, 0.6, 0.85], [0.35, 0.35, 0.85], [0.6, 0.3, 0.75], [0.4, 0.4, 0.4]];
    function colourBy(mode) {
      for (let i = 0; i < n; ++i) {
        const c = mode === 'normal' ? [0.5 + 0.5 * nor[3 * i], 0.5 + 0.5 * nor[3 * i + 1], 0.5 + 0.5 * nor[3 * i + 2]] : palette[levelOf[i] % palette.length];
        colours.set(c, 3 * i);
      }
    }
    colourBy('level');

    const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    const canvas = renderer.domElement;
    box.replaceChildren();
    const controls = el('div', { class: 'controls' });
    box.append(controls, canvas, el('div', { class: 'note' }, 'drag to turn, wheel to zoom · ' + n.toLocaleString('en-US') + ' of ' +
      shell.total_points.toLocaleString('en-US') + ' points (levels 0–' + (shell.levels_shown - 1) + ' of 0–' + (shell.levels - 1) + ') · distance grid ' + field.dims.join(' × ')));
    const width = box.clientWidth || 700, height = 420;
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setSize(width, height, false);
    renderer.setClearColor(0xf3f5f8, 1);
    const world = new THREE.Scene();
    const camera = new THREE.PerspectiveCamera(35, width / height, extent / 100, extent * 100);
    world.add(new THREE.AmbientLight(0xffffff, 0.55));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    world.add(sun);

    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(pos, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
    const points = new THREE.Points(geometry, new THREE.PointsMaterial({ size: extent / 150, vertexColors: true }));
    world.add(points);

    // The field's surface: surface nets over the coarse grid (one vertex per cell the surface crosses).
    const dims = field.dims, q = field.quantum, cell = field.cell;
    const value = (i, j, k) => ((fieldBytes[i + dims[0] * (j + dims[1] * k)] << 24) >> 24) * q;
    const origin = field.origin.map((v, a) => v - centre[a]);
    const surface = surfaceNets(THREE, dims, value, origin, cell);
    const surfaceMesh = new THREE.Mesh(surface, new THREE.MeshLambertMaterial({ color: 0xb8c4d6, transparent: true, opacity: 0.55, side: THREE.DoubleSide, depthWrite: false }));
    surfaceMesh.visible = false;
    world.add(surfaceMesh);

    // The slicing plane: the grid's values on one plane, inside red, outside blue, the surface dark.
    const sliceCanvas = document.createElement('canvas');
    const sliceTexture = new THREE.CanvasTexture(sliceCanvas);
    sliceTexture.magFilter = THREE.NearestFilter;
    const slice = new THREE.Mesh(new THREE.PlaneGeometry(1, 1), new THREE.MeshBasicMaterial({ map: sliceTexture, side: THREE.DoubleSide, transparent: true, opacity: 0.9 }));
    slice.visible = false;
    world.add(slice);
    let sliceAxis = 2, sliceIndex = Math.floor(dims[2] / 2);
    function drawSlice() {
      const [u, v] = sliceAxis === 0 ? [1, 2] : sliceAxis === 1 ? [0, 2] : [0, 1];
      if (sliceCanvas.width !== dims[u] || sliceCanvas.height !== dims[v]) {
        sliceTexture.dispose();  // a texture keeps its first size: a new one for the new axis's
        sliceCanvas.width = dims[u];
        sliceCanvas.height = dims[v];
      }
      const g = sliceCanvas.getContext('2d');
      const img = g.createImageData(dims[u], dims[v]);
      const limit = 8 * cell;
      for (let b = 0; b < dims[v]; ++b)
        for (let a = 0; a < dims[u]; ++a) {
          const idx = [0, 0, 0];
          idx[u] = a; idx[v] = b; idx[sliceAxis] = sliceIndex;
          const d = value(idx[0], idx[1], idx[2]);
          const t = Math.min(1, Math.abs(d) / limit);
          const o = 4 * ((dims[v] - 1 - b) * dims[u] + a);
          const c = Math.abs(d) < 0.5 * cell ? [30, 30, 30] : d < 0 ? [240 - 80 * t, 140 - 100 * t, 130 - 90 * t] : [190 - 150 * t, 215 - 120 * t, 250 - 60 * t];
          img.data.set([c[0], c[1], c[2], 255], o);
        }
      g.putImageData(img, 0, 0);
      sliceTexture.needsUpdate = true;
      const size = dims.map((d) => d * cell);
      slice.scale.set(size[u], size[v], 1);
      const mid = origin.map((o, a) => o + 0.5 * (dims[a] - 1) * cell);
      slice.position.set(mid[0], mid[1], mid[2]);
      slice.position.setComponent(sliceAxis, origin[sliceAxis] + sliceIndex * cell);
      // The plane's local x and y onto the slice's (u, v): x -> (y, z), y -> (x, z), z -> (x, y).
      slice.rotation.set(sliceAxis === 2 ? 0 : Math.PI / 2, sliceAxis === 0 ? Math.PI / 2 : 0, 0);
    }
    drawSlice();

    // Orbit by hand: three's OrbitControls is an ES module, which file:// pages cannot load.
    // The pictures' front frame ([axis, sign] each; +Y up when a page predates it): the camera orbits the up axis.
    const frame = scene.view || { right: [0, 1], up: [1, 1], toward: [2, 1] };
    const along = (axis, length) => new THREE.Vector3(0, 0, 0).setComponent(axis[0], axis[1] * length);
    camera.up.copy(along(frame.up, 1));
    let yaw = 0.6, pitch = 0.35, distance = extent * 2.4;
    function render() {
      const c = Math.cos(pitch), s = Math.sin(pitch);
      const eye = along(frame.right, distance * c * Math.sin(yaw)).add(along(frame.toward, distance * c * Math.cos(yaw))).add(along(frame.up, distance * s));
      camera.position.copy(eye);
      camera.lookAt(0, 0, 0);
      sun.position.copy(camera.position).add(along(frame.up, extent));
      renderer.render(world, camera);
    }
    let drag = null;
    canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener('pointermove', (e) => {
      if (!drag) return;
      yaw -= (e.clientX - drag[0]) * 0.01;
      pitch = Math.max(-1.5, Math.min(1.5, pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      render();
    });
    canvas.addEventListener('pointerup', () => { drag = null; });
    canvas.addEventListener('wheel', (e) => { e.preventDefault(); distance *= Math.exp(e.deltaY * 0.001); render(); }, { passive: false });

    // Controls
    const levelLabel = el('span', { id: 'level-label' });
    const level = el('input', { type: 'range', id: 'level', min: 0, max: shell.levels_shown - 1, value: shell.levels_shown - 1 });
    const showLevel = () => {
      const l = Number(level.value);
      geometry.setDrawRange(0, offsets[l + 1]);
      levelLabel.textContent = 'levels 0–' + l + ' (' + offsets[l + 1].toLocaleString('en-US') + ' points)';
      render();
    };
    level.addEventListener('input', showLevel);
    const colourMode = el('select', { id: 'colour-mode' }, el('option', { value: 'level' }, 'by level'), el('option', { value: 'normal' }, 'by normal'));
    colourMode.addEventListener('change', () => { colourBy(colourMode.value); geometry.attributes.color.needsUpdate = true; render(); });
    const toggle = (label, id, object, checked) => {
      const box = el('input', { type: 'checkbox', id, checked });
      object.visible = !!checked;
      box.addEventListener('change', () => { object.visible = box.checked; render(); });
      return el('label', {}, box, ' ', label);
    };
    const axis = el('select', { id: 'slice-axis' }, ['x', 'y', 'z'].map((a, i) => el('option', { value: i, selected: i === 2 }, a)));
    const position = el('input', { type: 'range', id: 'slice-position', min: 0, max: dims[2] - 1, value: sliceIndex });
    axis.addEventListener('change', () => {
      sliceAxis = Number(axis.value);
      position.max = dims[sliceAxis] - 1;
      sliceIndex = Math.floor(dims[sliceAxis] / 2);
      position.value = sliceIndex;
      drawSlice(); render();
    });
    position.addEventListener('input', () => { sliceIndex = Number(position.value); drawSlice(); render(); });
    controls.append(el('label', {}, 'point shell ', level), levelLabel, el('label', {}, 'colour ', colourMode),
      toggle('points', 'show-points', points, true), toggle('surface', 'show-surface', surfaceMesh, false),
      toggle('slice', 'show-slice', slice, false), el('label', {}, 'slice axis ', axis), el('label', {}, 'at ', position));
    showLevel();
    return {
      canvas,
      dispose() {
        geometry.dispose(); surface.dispose(); sliceTexture.dispose();
        renderer.dispose();
      },
    };
  }

  // Surface nets (Gibson 1998): a vertex in every cell whose corners change sign, at the mean of its edges'
  // crossings; a quad across every grid edge that changes sign.
  function surfaceNets(THREE, dims, value, origin, cell) {
    const [nx, ny, nz] = dims;
    const vertexOf = new Int32Array(nx * ny * nz).fill(-1);
    const positions = [], indices = [];
    const cellIndex = (i, j, k) => i + nx * (j + ny * k);
    const corners = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]];
    const edges = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
    for (let k = 0; k + 1 < nz; ++k)
      for (let j = 0; j + 1 < ny; ++j)
        for (let i = 0; i + 1 < nx; ++i) {
          const v = corners.map(([a, b, c]) => value(i + a, j + b, k + c));
          const inside = v.map((d) => d < 0);
          if (inside.every((x) => x) || inside.every((x) => !x)) continue;
          let sx = 0, sy = 0, sz = 0, m = 0;
          for (const [a, b] of edges) {
            if (inside[a] === inside[b]) continue;
            const t = v[a] / (v[a] - v[b]);
            sx += corners[a][0] + t * (corners[b][0] - corners[a][0]);
            sy += corners[a][1] + t * (corners[b][1] - corners[a][1]);
            sz += corners[a][2] + t * (corners[b][2] - corners[a][2]);
            ++m;
          }
          vertexOf[cellIndex(i, j, k)] = positions.length / 3;
          positions.push(origin[0] + (i + sx / m) * cell, origin[1] + (j + sy / m) * cell, origin[2] + (k + sz / m) * cell);
        }
    // Each grid edge from p along axis a that changes sign joins the 4 cells around it: p, p - e_b, p - e_b - e_c,
    // p - e_c (b, c the other axes, in cyclic order, so every quad winds the same way).
    for (let k = 0; k < nz; ++k)
      for (let j = 0; j < ny; ++j)
        for (let i = 0; i < nx; ++i) {
          const p = [i, j, k];
          const d0 = value(i, j, k) < 0;
          for (let a = 0; a < 3; ++a) {
            const q = p.slice();
            if (++q[a] >= dims[a] || (value(q[0], q[1], q[2]) < 0) === d0) continue;
            const b = (a + 1) % 3, c = (a + 2) % 3;
            const ids = [[0, 0], [1, 0], [1, 1], [0, 1]].map(([db, dc]) => {
              const cellAt = p.slice();
              cellAt[b] -= db;
              cellAt[c] -= dc;
              if (cellAt.some((x, t) => x < 0 || x > dims[t] - 2)) return -1;
              return vertexOf[cellIndex(cellAt[0], cellAt[1], cellAt[2])];
            });
            if (ids.some((x) => x < 0)) continue;
            if (d0) indices.push(ids[0], ids[1], ids[2], ids[0], ids[2], ids[3]);
            else indices.push(ids[0], ids[2], ids[1], ids[0], ids[3], ids[2]);
          }
        }
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.Float32BufferAttribute(positions, 3));
    g.setIndex(indices);
    g.computeVertexNormals();
    return g;
  }

  // ---- start
  document.addEventListener('keydown', (e) => { if (e.key === 'Escape' && !single) closeCard(); });
  if (single) {
    $('page').hidden = true;  // the library's summary, plots and table; the card stands alone
    const card = $('card');
    card.style.position = 'static';
    card.style.width = 'auto';
    card.style.boxShadow = 'none';
    card.style.border = 'none';
    openCard(rows[0].id);
  } else {
    summary();
    compare();
    plot($('plot-time'), 'triangles', 'time', 'input triangles', 'bake time', count, tickSeconds);
    plot($('plot-size'), 'resolution', 'size', 'longest grid side (voxels)', 'file size', count, tickBytes);
    tableHead();
    $('filter-name').addEventListener('input', (e) => { filter.name = e.target.value; apply(); });
    $('filter-status').addEventListener('change', (e) => { filter.status = e.target.value; apply(); });
    $('filter-code').addEventListener('change', (e) => { filter.code = e.target.value; apply(); });
    $('filter-size').addEventListener('input', (e) => { filter.size = e.target.value; apply(); });
    $('filter-time').addEventListener('input', (e) => { filter.time = e.target.value; apply(); });
    $('filter-clear').addEventListener('click', () => setFilter({ name: '', status: '', code: '', size: '', time: '' }));
    apply();
    const m = /^#asset-(\d+)$/.exec(location.hash);
    if (m) openCard(Number(m[1]));
  }
  document.body.dataset.readyMs = performance.now().toFixed(1);  // for the tests and the benchmark
  document.body.dataset.ready = 'true';
})();
