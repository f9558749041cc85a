// The salient page: API calls and the DOM. The 3D view lives in view.js.
//
// Integrators and the browser test rely on: #query-file, #mode, #method, #tag, #status (class
// "error" on errors, "busy" while a request runs), .result[data-model-id][data-rank],
// .model[data-model-id], buttons .similar and .download, #key-panel / #api-key / #key-save,
// and #view (data-models, data-matches, data-result, data-placed for a part laid on its
// result, data-drawn once a frame of them is drawn).

import { View, parseGlb, PALETTE } from '/page/view.js';

const $ = (selector) => document.querySelector(selector);
const KEY_STORAGE = 'salient.apiKey';
const PAGE_SIZE = 24;
const K = 24;
const MESH_EXTENSIONS = ['obj', 'gltf', 'glb', 'off', 'ply', 'stl', '3mf', 'zip'];
const METHOD_NAMES = { hybrid: 'hybrid', ecc: 'ECC', d2: 'D2', lfd: 'LFD', geodesic: 'geodesic' };

const state = {
  query: null, // the last query: { kind: 'upload', files, label } or { kind: 'model', id, label }
  hits: [],
  partial: false, // whether the hits are a part search's (mode=partial)
  selected: null, // id of the selected result
  run: 0, // bumped by every query, so that late answers of older ones are dropped
  controller: null,
  retry: null, // what to do again once a key is saved after a 401
  lib: { pages: [null], page: 0, next: null },
};

// ---------------------------------------------------------------------------------------------
// API

class ApiError extends Error {
  constructor(status, code, message, retryAfter = null) {
    super(message);
    Object.assign(this, { status, code, retryAfter });
  }
}

function apiKey() {
  try { return sessionStorage.getItem(KEY_STORAGE) || ''; } catch { return ''; }
}

// fetch with the key (a header, never the URL) and JSON errors turned into ApiError.
async function api(path, { method = 'GET', body, signal } = {}) {
  const headers = {};
  const key = apiKey();
  if (key) headers.Authorization = `Bearer ${key}`;
  let res;
  try {
    res = await fetch(path, { method, body, headers, signal });
  } catch (err) {
    if (err.name === 'AbortError') throw err;
    throw new ApiError(0, 'network', 'The server cannot be reached.');
  }
  if (!res.ok) {
    let code = '', message = res.statusText;
    try {
      const body = await res.json();
      code = body.error?.code || '';
      message = body.error?.message || message;
    } catch { /* not JSON: keep the status text */ }
    throw new ApiError(res.status, code, message, res.headers.get('Retry-After'));
  }
  return res;
}

// A message a person can act on, per status.
function describe(err) {
  const detail = err.message ? `: ${err.message.replace(/\.$/, '')}` : '';
  switch (err.status) {
    case 0: return 'The server cannot be reached. Check the connection and try again.';
    case 400: case 422: return `This file could not be read as a mesh${detail}.`;
    case 401: return apiKey() ? 'The API key was not accepted: enter a valid key.' : 'This server needs an API key: enter it above.';
    case 403: return `Your API key does not allow this${detail}.`;
    case 404: return `Not found${detail}.`;
    case 409: return `The model lacks what this method needs${detail}. Try another method.`;
    case 413: return 'The file is too large for this server.';
    case 415: return `Unsupported format: use OBJ, glTF/GLB, OFF, PLY, STL or 3MF${detail}.`;
    case 429: return `Too many requests: try again${retryText(err.retryAfter)}.`;
    case 503: return `The server is busy: try again${retryText(err.retryAfter) || ' in a moment'}.`;
    default: return `The request failed: ${err.status}${detail}.`;
  }
}

function retryText(retryAfter) {
  const s = Number(retryAfter);
  return Number.isFinite(s) && s > 0 ? ` in ${Math.ceil(s)} s` : '';
}

// Shows an error; a 401 also opens the key panel and remembers `retry` for after the save.
function fail(err, retry) {
  if (err.name === 'AbortError') return;
  if (!(err instanceof ApiError)) console.warn(err); // a bug or a bad preview, not the server
  const text = err instanceof ApiError ? describe(err) : `Something went wrong: ${err.message}`;
  if (err.status === 401 || err.status === 403) { // another key may do: offer the field
    state.retry = retry;
    showKeyPanel(text, !!apiKey());
    setStatus(text, apiKey() ? 'error' : '');
  } else setStatus(text, 'error');
}

function setStatus(text, kind = '') {
  const el = $('#status');
  el.textContent = text;
  el.className = `status ${kind}`.trim();
}

const enc = encodeURIComponent;

// ---------------------------------------------------------------------------------------------
// API key

function showKeyPanel(message, isError) {
  $('#key-panel').hidden = false;
  const msg = $('#key-message');
  msg.textContent = message || 'The key is kept in this browser tab only (sessionStorage).';
  msg.classList.toggle('error', !!isError);
  $('#api-key').value = apiKey();
  $('#api-key').focus();
}

function saveKey(event) {
  event.preventDefault(); // a form submit would navigate
  const key = $('#api-key').value.trim();
  try {
    if (key) sessionStorage.setItem(KEY_STORAGE, key); else sessionStorage.removeItem(KEY_STORAGE);
  } catch { /* storage disabled: the key lasts until reload only */ }
  $('#key-panel').hidden = true;
  setStatus(key ? 'Key saved.' : 'Key removed.', 'ok');
  const retry = state.retry;
  state.retry = null;
  loadLibrary(state.lib.pages[state.lib.page]);
  if (retry && retry !== libraryRetry) retry();
}

function forgetKey() {
  try { sessionStorage.removeItem(KEY_STORAGE); } catch { /* nothing stored */ }
  $('#api-key').value = '';
  setStatus('Key removed from this tab.', 'ok');
}

// ---------------------------------------------------------------------------------------------
// Thumbnails: fetched with the key, shown through object URLs that the grid owns and revokes
// when it is drawn again.

const gridUrls = new WeakMap();

function resetGrid(grid) {
  for (const url of gridUrls.get(grid) || []) URL.revokeObjectURL(url);
  gridUrls.set(grid, []);
  grid.replaceChildren();
}

// A few at a time, and again after a 503 or 429: a server that renders them on demand may
// be busy with the query's extraction.
const thumbs = { active: 0, waiting: [] };
async function throttled(task) {
  await null; // the task runs after the caller has put its card in the page
  if (thumbs.active >= 4) await new Promise((go) => thumbs.waiting.push(go));
  thumbs.active++;
  try { return await task(); } finally { thumbs.active--; thumbs.waiting.shift()?.(); }
}

async function fetchThumbnail(id) {
  for (let attempt = 0; ; attempt++) {
    try {
      return await (await api(`/v1/models/${enc(id)}/thumbnail.png?size=256&features=true`)).blob();
    } catch (err) {
      if (attempt >= 3 || ![429, 503].includes(err.status)) throw err;
      const wait = Math.min(5, Number(err.retryAfter) || 1);
      await new Promise((go) => setTimeout(go, wait * 1000));
    }
  }
}

async function loadThumbnail(grid, card, img, id) {
  card.dataset.thumb = 'loading';
  try {
    const blob = await throttled(() => (card.isConnected ? fetchThumbnail(id) : null));
    if (!blob || !card.isConnected) return; // the grid was redrawn meanwhile
    const url = URL.createObjectURL(blob);
    gridUrls.get(grid).push(url);
    img.addEventListener('load', () => { card.dataset.thumb = 'loaded'; }, { once: true });
    img.addEventListener('error', () => { card.dataset.thumb = 'failed'; }, { once: true });
    img.src = url;
  } catch {
    card.dataset.thumb = 'failed'; // the card still works without its picture
  }
}

// ---------------------------------------------------------------------------------------------
// Cards

function el(tag, className, text) {
  const e = document.createElement(tag);
  if (className) e.className = className;
  if (text !== undefined) e.textContent = text; // textContent only: names and tags are user data
  return e;
}

// A card for a library model (hit = null) or a search hit.
function card(grid, model, hit) {
  const c = el('article', hit ? 'card result' : 'card model');
  c.dataset.modelId = model.id;
  const name = model.name || model.id;
  const thumb = el('div', 'thumb');
  const img = el('img');
  img.alt = name;
  thumb.append(img);
  c.append(thumb);
  const body = el('div', 'card-body');
  body.append(el('h3', 'name', name));
  const chips = el('div', 'chips');
  if (model.class) chips.append(el('span', 'chip class', model.class));
  for (const tag of model.tags || []) chips.append(el('span', 'chip', tag));
  if (chips.childElementCount) body.append(chips);
  if (hit) {
    c.dataset.rank = String(hit.rank);
    c.tabIndex = 0;
    c.append(el('span', 'rank', `#${hit.rank}`));
    // A part search ranks the models it registered the part into by how far it stays off
    // their surface (residual), the others by their features' fit.
    const registered = typeof hit.residual === 'number';
    const d = el('div', 'distance', registered ? 'residual ' : 'distance ');
    d.append(el('b', '', (registered ? hit.residual : hit.distance).toFixed(3)));
    body.append(d);
  } else {
    body.append(el('div', 'meta', `${model.triangles} triangles · ${model.features} salient features`));
  }
  const actions = el('div', 'actions');
  for (const [cls, text, title] of [['similar', 'Similar', 'Find models similar to this one'],
    ['download', 'Download', 'Download the original file']]) {
    const b = actions.appendChild(el('button', cls, text));
    Object.assign(b, { type: 'button', title });
  }
  body.append(actions);
  c.append(body);
  loadThumbnail(grid, c, img, model.id);
  return c;
}

// One click handler per grid: similar, download, or (results) select.
function onGridClick(event) {
  const c = event.target.closest('.card');
  if (!c) return;
  const id = c.dataset.modelId;
  const label = c.querySelector('.name').textContent;
  if (event.target.closest('.similar')) runQuery({ kind: 'model', id, label });
  else if (event.target.closest('.download')) download(id, event.target.closest('.download'));
  else if (c.classList.contains('result')) selectHit(id);
}

// ---------------------------------------------------------------------------------------------
// Library

function libraryRetry() { loadLibrary(state.lib.pages[state.lib.page]); }

async function loadLibrary(after, page = state.lib.page) {
  const params = new URLSearchParams({ limit: String(PAGE_SIZE) });
  if (after) params.set('after', after);
  const tag = $('#tag').value.trim();
  if (tag) params.set('tag', tag);
  try {
    const data = await (await api(`/v1/models?${params}`)).json();
    state.lib.page = page;
    state.lib.pages[page] = after;
    state.lib.next = data.next;
    const grid = $('#library');
    resetGrid(grid);
    for (const m of data.models) grid.append(card(grid, m, null));
    if (!data.models.length) grid.append(el('p', 'empty', tag ? `No model has the tag “${tag}”.` : 'The library is empty.'));
    $('#lib-page').textContent = `Page ${page + 1}`;
    $('#lib-prev').disabled = page === 0;
    $('#lib-next').disabled = !data.next;
    rememberTags(data.models);
    if (!$('#key-panel').hidden && apiKey()) $('#key-panel').hidden = true;
  } catch (err) {
    fail(err, libraryRetry);
  }
}

function rememberTags(models) {
  const list = $('#tag-list');
  const known = new Set([...list.options].map((o) => o.value));
  for (const tag of models.flatMap((m) => m.tags || [])) {
    if (!known.has(tag)) { known.add(tag); const o = el('option'); o.value = tag; list.append(o); }
  }
}

// ---------------------------------------------------------------------------------------------
// Queries: an upload (POST /v1/search) or a stored model (GET /v1/models/{id}/similar).

const isMesh = (f) => MESH_EXTENSIONS.includes(f.name.split('.').pop().toLowerCase());
const mainFile = (files) => files.find(isMesh) || files[0];

// The mesh as `file`; every other file (a glTF's buffers and images) under its own name.
function meshForm(files) {
  const form = new FormData();
  const main = mainFile(files);
  form.append('file', main, main.name);
  for (const f of files) if (f !== main) form.append(f.name, f, f.name);
  return form;
}

function uploadFiles(files) {
  if (!files.length) return;
  if (!files.some(isMesh)) {
    // The server takes the format from the extension: say so before uploading anything.
    setStatus(`Unsupported format: choose an OBJ, glTF/GLB, OFF, PLY, STL or 3MF file, or a zip of one (not ${files[0].name}).`, 'error');
    return;
  }
  runQuery({ kind: 'upload', files, label: mainFile(files).name });
}

async function runQuery(query) {
  state.controller?.abort();
  state.controller = new AbortController();
  const { signal } = state.controller;
  const run = ++state.run;
  const params = new URLSearchParams({ k: String(K), explain: 'true' });
  const method = $('#method').value, tag = $('#tag').value.trim();
  // A part search has its own score (no method); a stored model is always a whole one.
  if (query.kind === 'upload' && partMode()) params.set('mode', 'partial');
  else if (method) params.set('method', method); // none: the server's default
  if (tag) params.set('tag', tag);
  setStatus(query.kind === 'upload' ? 'Extracting salient features…' : `Searching for models like ${query.label}…`, 'busy');
  $('#results').classList.add('stale');
  const started = performance.now();
  try {
    const res = query.kind === 'upload'
      ? await api(`/v1/search?${params}`, { method: 'POST', body: meshForm(query.files), signal })
      : await api(`/v1/models/${enc(query.id)}/similar?${params}`, { signal });
    const data = await res.json();
    if (run !== state.run) return;
    // The same query again (another method or tag) keeps its preview and, if it is still
    // among the results, the chosen result.
    const keep = state.query === query ? state.selected : null;
    // Only a query that answered becomes the one that method and tag changes run again.
    state.query = query;
    view?.setQuery(query.mesh ?? null, `Query: ${query.label}`);
    showResults(data, query, performance.now() - started);
    if (keep && state.hits.some((h) => h.id === keep)) selectHit(keep);
    if (!query.mesh) await loadQueryPreview(query, signal);
  } catch (err) {
    if (run !== state.run) return;
    $('#results').classList.remove('stale');
    fail(err, () => runQuery(query));
  }
}

function showResults(data, query, elapsed) {
  state.hits = data.results;
  state.partial = data.mode === 'partial';
  state.selected = null;
  const grid = $('#results');
  grid.classList.remove('stale');
  resetGrid(grid);
  for (const hit of data.results) grid.append(card(grid, hit, hit));
  const what = query.kind === 'upload' ? query.label : `models like ${query.label}`;
  if (!data.results.length) grid.append(el('p', 'empty', `Nothing matched ${what}.`));
  const t = data.timings || {};
  $('#results-summary').textContent = `${data.results.length} for ${what} · `
    + (state.partial ? `as a part · ${data.results.filter((h) => h.placement).length} registered`
      : `${METHOD_NAMES[data.method] || data.method} · ${data.evaluated} compared, ${data.pruned} pruned`)
    + ` · ${data.query_features} query features`;
  setStatus(`Found ${data.results.length} models in ${ms(t.total_ms ?? elapsed)}`
    + (t.extract_ms ? ` (extraction ${ms(t.extract_ms)}).` : '.')
    + (data.results.length ? ' Click a result to compare it in 3D.' : ''), 'ok');
  $('#detail').hidden = true;
}

const ms = (v) => (v < 10 ? `${v.toFixed(1)} ms` : `${Math.round(v)} ms`);

// The query's own preview: the server cached the extraction during the search, so it is quick.
async function loadQueryPreview(query, signal) {
  if (!view) return;
  note('Loading the 3D preview…');
  try {
    const res = query.kind === 'upload'
      ? await api('/v1/preview?features=true', { method: 'POST', body: meshForm(query.files), signal })
      : await api(`/v1/models/${enc(query.id)}/preview.glb`, { signal });
    query.mesh = parseGlb(await res.arrayBuffer());
    if (state.query !== query) return;
    view.setQuery(query.mesh, `Query: ${query.label}`);
    note('Drag to rotate, scroll to zoom. Click a result to see the matched regions.');
    if (state.selected) selectHit(state.selected); // chosen while the preview was loading
  } catch (err) {
    if (err.name !== 'AbortError') note(`No 3D preview: ${err instanceof ApiError ? describe(err) : err.message}`);
  }
}

// ---------------------------------------------------------------------------------------------
// A chosen result: its preview beside the query, with the explanation's matches.

const meshCache = new Map(); // id -> Promise of a parsed preview; a few, oldest dropped first

function modelMesh(id) {
  if (!meshCache.has(id)) {
    const p = api(`/v1/models/${enc(id)}/preview.glb`).then((r) => r.arrayBuffer()).then(parseGlb);
    p.catch(() => meshCache.delete(id));
    meshCache.set(id, p);
    if (meshCache.size > 12) meshCache.delete(meshCache.keys().next().value);
  }
  return meshCache.get(id);
}

async function selectHit(id) {
  const hit = state.hits.find((h) => h.id === id);
  if (!hit) return;
  state.selected = id;
  for (const c of document.querySelectorAll('.result')) c.classList.toggle('selected', c.dataset.modelId === id);
  showDetail(hit);
  if (!view) return;
  note(`Loading ${hit.name || id}…`);
  try {
    const mesh = await modelMesh(id);
    if (state.selected !== id) return;
    const label = `Result: ${hit.name || id}`;
    if (hit.placement && state.query?.mesh) view.setPlaced(mesh, label, hit.placement);
    else view.setResult(mesh, label, hit.explanation?.matches || []);
    $('#view').dataset.result = id;
    const n = hit.explanation?.matches?.length || 0;
    note(hit.placement ? 'In orange: the part where it fits in this model.'
      : state.partial ? 'The part was not registered into this model: it ranks by its salient features\' fit.'
        : n ? `${n} matched salient regions: line width and opacity show the matched mass.` : 'No match explanation for this result.');
  } catch (err) {
    if (state.selected === id) note(`No 3D preview: ${err instanceof ApiError ? describe(err) : err.message}`);
  }
}

function showDetail(hit) {
  $('#detail').hidden = false;
  $('#detail-name').textContent = `#${hit.rank} ${hit.name || hit.id}`;
  const d = hit.explanation?.distances || {};
  $('#detail-distances').textContent = state.partial
    ? (typeof hit.residual === 'number'
      ? `registered: residual ${hit.residual.toFixed(4)} of the part's size`
      : `not registered: features' fit ${hit.distance.toFixed(3)}`)
      + (hit.part_scale ? ` · the part ${Math.round(hit.part_scale * 100)}% of the model's size` : '')
    : Object.entries(METHOD_NAMES)
      .map(([k, name]) => `${name} ${typeof d[k] === 'number' ? d[k].toFixed(3) : '—'}`).join(' · ');
  const list = $('#detail-matches');
  list.replaceChildren();
  const matches = [...(hit.explanation?.matches || [])].sort((a, b) => b.mass - a.mass).slice(0, 10);
  for (const m of matches) {
    const li = el('li');
    const sw = el('span', 'swatch');
    sw.style.background = `rgb(${PALETTE[m.query % PALETTE.length].map((c) => Math.round(c * 255)).join(',')})`;
    li.append(sw, `query ${m.query} ↔ result ${m.result} · ${(m.mass * 100).toFixed(0)}%`);
    list.append(li);
  }
  // The compare image needs two stored models: only for "similar" queries.
  $('#detail-compare').hidden = state.query?.kind !== 'model';
  setImage($('#detail-image'), null);
}

async function showCompare() {
  const a = state.query?.id, b = state.selected;
  if (!a || !b) return;
  try {
    const blob = await (await api(`/v1/compare?a=${enc(a)}&b=${enc(b)}`)).blob();
    if (state.selected === b) setImage($('#detail-image'), URL.createObjectURL(blob));
  } catch (err) {
    fail(err, showCompare);
  }
}

function setImage(img, url) {
  if (img.src.startsWith('blob:')) URL.revokeObjectURL(img.src);
  if (url) img.src = url; else img.removeAttribute('src');
  img.hidden = !url;
}

function note(text) { $('#view-note').textContent = text; }

// ---------------------------------------------------------------------------------------------
// Download: fetch (the key is a header) and an object URL; the name from Content-Disposition.

function fileName(disposition, fallback) {
  const star = /filename\*\s*=\s*UTF-8''([^;]+)/i.exec(disposition || '');
  const plain = /filename\s*=\s*"?([^";]+)"?/i.exec(disposition || '');
  let name = fallback;
  try { name = star ? decodeURIComponent(star[1]) : plain ? plain[1] : fallback; } catch { /* keep fallback */ }
  return name.replace(/[/\\]/g, '_');
}

async function download(id, button) {
  button.disabled = true;
  try {
    const res = await api(`/v1/models/${enc(id)}/file`);
    const url = URL.createObjectURL(await res.blob());
    const a = document.body.appendChild(el('a'));
    Object.assign(a, { href: url, download: fileName(res.headers.get('Content-Disposition'), id) });
    a.click();
    a.remove();
    // The download reads the blob after click() returns: revoke a little later.
    setTimeout(() => URL.revokeObjectURL(url), 60_000);
  } catch (err) {
    fail(err, () => download(id, button));
  } finally {
    button.disabled = false;
  }
}

// ---------------------------------------------------------------------------------------------
// Wiring

let view = null;
try {
  view = new View($('#view'), $('#view-labels'));
} catch (err) {
  note(`The 3D view is not available: ${err.message}.`);
}

$('#key-form').addEventListener('submit', saveKey);
$('#key-forget').addEventListener('click', forgetKey);
$('#key-toggle').addEventListener('click', () => {
  if ($('#key-panel').hidden) showKeyPanel(); else $('#key-panel').hidden = true;
});

const input = $('#query-file');
input.addEventListener('change', () => {
  const files = [...input.files];
  input.value = ''; // choosing the same file again must fire change again
  uploadFiles(files);
});
const zone = $('#drop-zone');
zone.addEventListener('dragover', (e) => { e.preventDefault(); zone.classList.add('dragging'); });
zone.addEventListener('dragleave', () => zone.classList.remove('dragging'));
zone.addEventListener('drop', (e) => {
  e.preventDefault();
  zone.classList.remove('dragging');
  uploadFiles([...e.dataTransfer.files]);
});
// A file dropped beside the zone must not make the browser navigate to it.
for (const type of ['dragover', 'drop']) window.addEventListener(type, (e) => e.preventDefault());

// The method applies to whole models only; a part search runs again on the last upload.
function partMode() { return $('#mode').value === 'partial'; }
$('#mode').addEventListener('change', () => {
  $('#method').disabled = partMode();
  if (state.query?.kind === 'upload') runQuery(state.query);
});
$('#method').addEventListener('change', () => { if (state.query) runQuery(state.query); });
$('#tag').addEventListener('change', () => {
  state.lib = { pages: [null], page: 0, next: null };
  loadLibrary(null, 0);
  if (state.query) runQuery(state.query);
});

for (const grid of [$('#results'), $('#library')]) grid.addEventListener('click', onGridClick);
$('#results').addEventListener('keydown', (e) => {
  const c = e.target.closest?.('.result');
  if (c && e.target === c && (e.key === 'Enter' || e.key === ' ')) { e.preventDefault(); selectHit(c.dataset.modelId); }
});
// Pages by `after` cursors: pages[i] is the cursor that gave page i, so "previous" goes back.
$('#lib-next').addEventListener('click', () => state.lib.next && loadLibrary(state.lib.next, state.lib.page + 1));
$('#lib-prev').addEventListener('click', () => state.lib.page > 0
  && loadLibrary(state.lib.pages[state.lib.page - 1], state.lib.page - 1));
$('#view-reset').addEventListener('click', () => view?.resetCamera());
$('#detail-compare').addEventListener('click', showCompare);

// First load: the library's first page; a 401 here opens the key panel.
loadLibrary(null, 0);
