// The viewer of one job: status while it runs, the problem when it fails, and when it has
// succeeded the coverage model (coverage.glb) in 3D with clickable stations, face-class
// toggles, totals, the station list and the coverage curve.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
// coverage.glb is meshopt-compressed (EXT_meshopt_compression): the decoder is WebAssembly
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
import {
  ProblemError, askForKey, authHeaders, basePath, el, fetchOk, fmt, getJSON, problemText,
} from './api.js';

const CLASSES = [
  ['covered', 'covered by the plan', '#31a354'],
  ['coverable_not_covered', 'coverable, not covered', '#f09614'],
  ['not_coverable', 'not coverable from any candidate', '#be1e3c'],
  ['not_target', 'no requirement', '#c8c8c8'],
];
const $ = (id) => document.getElementById(id);
const match = window.location.pathname.match(/\/jobs\/([^/]+)\/viewer\/?$/);
const jobId = match ? decodeURIComponent(match[1]) : '';
const jobPath = `/jobs/${encodeURIComponent(jobId)}`;

// what tests and scripts can ask the page
const hook = { ready: false, status: 'loading', stations: () => [], selected: null };
window.scanplanViewer = hook;

$('job-id').textContent = jobId;

function setStatus(status, message, progress) {
  hook.status = status;
  const badge = $('status-badge');
  badge.textContent = status;
  badge.className = `badge ${status}`;
  $('status-message').textContent = message || '';
  const bar = $('progress');
  bar.hidden = !(status === 'accepted' || status === 'running');
  bar.firstElementChild.style.width = `${Math.max(0, Math.min(100, Number(progress) || 0))}%`;
}

function showProblem(problem, heading) {
  const box = $('problem');
  box.replaceChildren(el('h2', { text: heading || 'The plan failed' }));
  const p = problem && typeof problem === 'object' ? problem : { detail: String(problem) };
  if (p.title) box.append(el('p', {}, el('strong', { text: String(p.title) })));
  if (p.detail) box.append(el('p', { text: String(p.detail) }));
  const extra = [];
  if (p.parameter) extra.push(`parameter: ${p.parameter}`);
  if (p.status) extra.push(`HTTP status ${p.status}`);
  if (p.type && p.type !== 'about:blank') extra.push(`type: ${p.type}`);
  if (extra.length) box.append(el('p', { class: 'muted', text: extra.join(' · ') }));
  box.hidden = false;
}

async function poll() {
  let job;
  try {
    job = await getJSON(jobPath);
  } catch (err) {
    if (err instanceof ProblemError && err.status === 401) {
      setStatus('locked', 'an API key is needed');
      await askForKey($('key'));
      return poll();
    }
    if (err instanceof ProblemError && err.status >= 400 && err.status < 500) {
      setStatus('unknown', '');
      showProblem(err.problem, err.status === 404 ? 'No such job' : 'The job cannot be shown');
      return undefined;
    }
    setStatus('offline', `${err.message}; retrying`);
    window.setTimeout(poll, 3000);
    return undefined;
  }
  const status = String(job.status || 'unknown');
  setStatus(status, job.message, job.progress);
  if (status === 'accepted' || status === 'running') {
    window.setTimeout(poll, 1000);
  } else if (status === 'successful') {
    $('problem').hidden = true;
    await loadResults();
  } else if (status === 'failed') {
    let problem = job.problem;
    if (!problem) {
      try { await getJSON(`${jobPath}/results`); } catch (err) { problem = err.problem; }
    }
    showProblem(problem || { title: 'The plan failed', detail: job.message });
  } else if (status === 'dismissed') {
    showProblem({ title: 'The job was cancelled', detail: job.message }, 'Cancelled');
  }
  return undefined;
}

// --- results ---------------------------------------------------------------------------

let plan = null;

async function loadResults() {
  try {
    plan = await getJSON(`${jobPath}/results/plan.json`);
    showTotals(plan);
    showStationTable(plan.stations || []);
  } catch (err) {
    showProblem(err.problem, 'The plan document cannot be read');
  }
  showFiles();
  showCurve();
  try {
    await loadModel();
  } catch (err) {
    showProblem(err.problem || { title: 'The 3D model cannot be shown',
                                 detail: String(err && err.message ? err.message : err) },
                'No 3D view');
  }
  hook.ready = true;
}

function showTotals(doc) {
  const t = doc.totals || {};
  const goal = Number(doc.coverage_goal);
  const rows = [
    ['stations', `${t.stations ?? '–'} (${String(doc.method || '').replace('_', ' ')})`],
    ['covered', `${fmt(t.covered_area_m2, 1)} m²`],
    ['of coverable', `${fmt(100 * Number(t.coverage_fraction), 1)} %`],
    ['goal', `${fmt(100 * goal, 0)} % ${doc.goal_reached ? '(reached)' : '(not reached)'}`],
    ['coverable area', `${fmt(t.max_achievable_area_m2, 1)} m²`],
    ['model area', `${fmt(t.total_area_m2, 1)} m²`],
    ['candidates', String(t.candidates ?? '–')],
    ['faces', String(t.faces ?? '–')],
  ];
  if (doc.optimal) rows.push(['optimal (MILP)', `${doc.optimal.stations}, proven ≥ ${doc.optimal.lower_bound}`]);
  const dl = el('dl');
  for (const [name, value] of rows) dl.append(el('dt', { text: name }), el('dd', { text: value }));
  $('totals').replaceChildren(el('h2', { text: 'Totals' }), dl);
  $('totals').hidden = false;
}

function showStationTable(stations) {
  const body = $('stations').querySelector('tbody');
  body.replaceChildren(...stations.map((s) => {
    const p = s.position || [];
    const tr = el('tr', { 'data-order': String(s.id) },
      el('td', { text: String(s.id) }), el('td', { text: fmt(p[0]) }),
      el('td', { text: fmt(p[1]) }), el('td', { text: fmt(p[2]) }),
      el('td', { text: fmt(s.new_area_m2, 1) }),
      el('td', { text: fmt(100 * Number(s.coverage_fraction), 1) }));
    tr.addEventListener('click', () => selectStation(Number(s.id)));
    return tr;
  }));
  $('stations').hidden = stations.length === 0;
}

function showFiles() {
  const p = $('files').querySelector('p');
  p.replaceChildren();
  for (const name of ['preview.png', 'curve.png', 'coverage.glb', 'plan.json', 'stations.csv',
    'faces.npz']) {
    p.append(el('a', { href: `${basePath()}${jobPath}/results/${name}`, text: name }), ' ');
  }
  $('files').hidden = false;
}

async function showCurve() {
  const box = $('curve');
  try {
    const blob = await (await fetchOk(`${jobPath}/results/curve.png`)).blob();
    box.append(el('img', { src: URL.createObjectURL(blob), alt: 'coverage curve' }));
  } catch {
    const curve = plan && plan.curve;
    if (!curve || !Array.isArray(curve.goals)) return;
    const table = el('table', {}, el('tr', {}, el('th', { text: 'goal %' }),
      el('th', { text: 'greedy' }), el('th', { text: 'weighted' })));
    curve.goals.forEach((g, i) => table.append(el('tr', {}, el('td', { text: fmt(100 * g, 0) }),
      el('td', { text: String((curve.greedy || [])[i] ?? '–') }),
      el('td', { text: String((curve.weighted_greedy || [])[i] ?? '–') }))));
    box.append(table);
  }
  box.hidden = false;
}

// --- 3D ------------------------------------------------------------------------------------

const canvas = $('canvas');
let renderer = null;
let camera = null;
let controls = null;
const scene3d = new THREE.Scene();
const stations = new Map(); // order -> {node, label, extras}
const cutPlane = new THREE.Plane(new THREE.Vector3(0, -1, 0), 1e9);

function labelSprite(text) {
  const size = 128;
  const c = document.createElement('canvas');
  c.width = size;
  c.height = size;
  const g = c.getContext('2d');
  g.fillStyle = '#143ca0';
  g.beginPath();
  g.arc(size / 2, size / 2, size / 2 - 6, 0, 2 * Math.PI);
  g.fill();
  g.lineWidth = 8;
  g.strokeStyle = '#ffffff';
  g.stroke();
  g.fillStyle = '#ffffff';
  g.font = `bold ${text.length > 2 ? 44 : 60}px sans-serif`;
  g.textAlign = 'center';
  g.textBaseline = 'middle';
  g.fillText(text, size / 2, size / 2 + 3);
  const texture = new THREE.CanvasTexture(c);
  texture.colorSpace = THREE.SRGBColorSpace;
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: texture, depthTest: false }));
  sprite.renderOrder = 10;
  return sprite;
}

function resize() {
  const { clientWidth: w, clientHeight: h } = canvas.parentElement;
  if (!renderer || w === 0 || h === 0) return;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}

async function loadModel() {
  renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  renderer.setClearColor(0xf4f5f7, 1);
  renderer.clippingPlanes = [cutPlane];
  camera = new THREE.PerspectiveCamera(45, 1, 0.05, 5000);
  controls = new OrbitControls(camera, canvas);
  scene3d.add(new THREE.HemisphereLight(0xffffff, 0x8a8a8a, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.4);
  sun.position.set(0.5, 1.0, 0.8);
  scene3d.add(sun);

  const loader = new GLTFLoader();
  loader.setRequestHeader(authHeaders());
  loader.setMeshoptDecoder(MeshoptDecoder);
  let gltf;
  try {
    gltf = await loader.loadAsync(`${basePath()}${jobPath}/results/coverage.glb`);
  } catch (err) {
    throw new ProblemError({ title: 'coverage.glb cannot be loaded',
                             detail: String(err && err.message ? err.message : err) });
  }
  const root = gltf.scene;
  scene3d.add(root);
  const info = (gltf.scene.userData && gltf.scene.userData.scanplan) || {};
  const classNodes = new Map();
  const box = new THREE.Box3();
  root.updateMatrixWorld(true);
  root.traverse((object) => {
    const data = object.userData || {};
    // the file's seven-segment numbers are for other viewers; this page draws labels
    if (/^station[ _]\d+[ _]number$/.test(object.name)) object.visible = false;
    if (data.face_class) {
      classNodes.set(data.face_class, { node: object, faces: data.faces });
      box.expandByObject(object);
    }
    if (Number.isInteger(data.order) && Number.isInteger(data.station)) {
      const label = labelSprite(String(data.order));
      const world = new THREE.Vector3();
      object.getWorldPosition(world);
      label.position.copy(world).add(new THREE.Vector3(0, 0.75, 0));
      label.userData.order = data.order;
      stations.set(data.order, { node: object, label, extras: data, world });
    }
  });
  for (const { label } of stations.values()) scene3d.add(label);
  if (box.isEmpty()) box.setFromObject(root);
  const size = box.getSize(new THREE.Vector3());
  const centre = box.getCenter(new THREE.Vector3());
  const span = Math.max(size.x, size.y, size.z, 1);
  for (const { label } of stations.values()) label.scale.setScalar(Math.max(0.3, span * 0.045));
  camera.near = span / 500;
  camera.far = span * 50;
  camera.position.copy(centre).add(new THREE.Vector3(0.35 * span, 1.0 * span, 0.9 * span));
  controls.target.copy(centre);
  controls.update();
  setupToggles(classNodes, info);
  setupCut(box);
  new ResizeObserver(resize).observe(canvas.parentElement);
  resize();
  $('hint').hidden = false;
  setupPicking();
  renderer.setAnimationLoop(() => {
    controls.update();
    renderer.render(scene3d, camera);
  });
  hook.stations = () => stationScreenPositions();
}

function setupToggles(classNodes, info) {
  const box = $('class-toggles');
  box.replaceChildren();
  const known = (info.face_classes) || {};
  for (const [name, label, fallback] of CLASSES) {
    const entry = classNodes.get(name);
    const rgb = known[name] && Array.isArray(known[name].srgb) ? `rgb(${known[name].srgb.join(',')})`
      : fallback;
    const input = el('input', { type: 'checkbox', 'data-class': name });
    input.checked = Boolean(entry);
    input.disabled = !entry;
    input.addEventListener('change', () => { if (entry) entry.node.visible = input.checked; });
    const count = entry ? ` (${entry.faces ?? '?'} faces)` : ' (none)';
    box.append(el('label', {}, input, el('span', { class: 'swatch', style: `background:${rgb}` }),
      `${label}${count}`));
  }
  $('classes').hidden = false;
}

function setupCut(box) {
  const slider = $('cut');
  const lo = box.min.y;
  const hi = box.max.y + 0.01;
  let highest = -Infinity;
  for (const { world } of stations.values()) highest = Math.max(highest, world.y);
  const start = Number.isFinite(highest) ? Math.min(hi, highest + 1.0) : hi;
  slider.min = String(lo);
  slider.max = String(hi);
  slider.value = String(start);
  const apply = () => {
    cutPlane.constant = Number(slider.value);
    $('cut-value').textContent = `${fmt(slider.value)} m`;
  };
  slider.addEventListener('input', apply);
  apply();
}

function stationScreenPositions() {
  const rect = canvas.getBoundingClientRect();
  const out = [];
  for (const [order, { label }] of stations) {
    const p = label.position.clone().project(camera);
    out.push({ order, x: rect.left + (p.x + 1) / 2 * rect.width,
               y: rect.top + (1 - p.y) / 2 * rect.height });
  }
  return out;
}

function setupPicking() {
  const raycaster = new THREE.Raycaster();
  let down = null;
  canvas.addEventListener('pointerdown', (event) => { down = [event.clientX, event.clientY]; });
  canvas.addEventListener('pointerup', (event) => {
    if (!down || Math.hypot(event.clientX - down[0], event.clientY - down[1]) > 5) return;
    const rect = canvas.getBoundingClientRect();
    const pointer = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
                                      -((event.clientY - rect.top) / rect.height) * 2 + 1);
    raycaster.setFromCamera(pointer, camera);
    const targets = [];
    for (const { node, label } of stations.values()) targets.push(label, node);
    const hit = raycaster.intersectObjects(targets, true)[0];
    let object = hit ? hit.object : null;
    while (object && !Number.isInteger(object.userData.order)) object = object.parent;
    if (object) selectStation(object.userData.order);
  });
}

function selectStation(order) {
  const entry = stations.get(order);
  const fromPlan = plan && Array.isArray(plan.stations)
    ? plan.stations.find((s) => Number(s.id) === order) : null;
  const data = fromPlan || (entry && entry.extras);
  if (!data) return;
  const p = data.position || [];
  const box = $('station');
  box.replaceChildren(
    el('h2', { text: `Station ${order}` }),
    el('p', { text: `scan order ${order} of ${stations.size || (plan && plan.stations.length)}` }),
    el('p', { text: `position x ${fmt(p[0])} m, y ${fmt(p[1])} m, z ${fmt(p[2])} m` }),
    el('p', { text: `new area ${fmt(data.new_area_m2)} m²` }),
    el('p', { text: `covered after it ${fmt(data.covered_area_m2)} m² ` +
                    `(${fmt(100 * Number(data.coverage_fraction), 1)} % of coverable)` }),
    el('p', { class: 'muted', text: `candidate ${data.candidate_index ?? '–'}` }));
  box.hidden = false;
  box.dataset.order = String(order);
  hook.selected = order;
  for (const tr of $('stations').querySelectorAll('tbody tr')) {
    tr.classList.toggle('selected', tr.dataset.order === String(order));
  }
  for (const [o, { label }] of stations) label.material.color.set(o === order ? 0xffd21f : 0xffffff);
}

if (jobId) {
  poll();
} else {
  setStatus('unknown', '');
  showProblem({ title: 'No job in the address', detail: window.location.pathname });
}

export { problemText };
