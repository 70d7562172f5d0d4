// The viewer of one job: status while it runs, the problem when it fails, and when it has
// succeeded the coverage model (coverage.glb) in 3D with clickable stations, face-class
// toggles, the walking route and the registration overlap edges, totals, the field time,
// the station list (with the visit order) and the coverage curve. A plan with a
// verification (verify parameter, or scanplan verify) can be coloured by what the
// simulated scan delivered, from the verified arrays of faces.npz.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
// coverage.glb is meshopt-compressed (EXT_meshopt_compression): the decoder is WebAssembly
import { MeshoptDecoder } from 'three/addons/libs/meshopt_decoder.module.js';
import {
  ProblemError, askForKey, authHeaders, basePath, el, fetchOk, fmt, getJSON, problemText,
} from './api.js';
import { readNpz } from './npz.js';

const CLASSES = [
  ['covered', 'covered by the plan', '#31a354'],
  ['coverable_not_covered', 'coverable, not covered', '#f09614'],
  ['not_coverable', 'not coverable from any candidate', '#be1e3c'],
  ['not_target', 'no requirement', '#c8c8c8'],
];
// the delivered colouring: a target face by its promise (plan: covered) and the simulated
// scan (faces.npz verified_delivered); faces without a requirement stay grey
const DELIVERED = [
  ['delivered', 'promised and delivered', '#31a354'],
  ['promised_not_delivered', 'promised, not delivered', '#d7191c'],
  ['delivered_not_promised', 'delivered, not promised', '#2c7bb6'],
  ['not_delivered', 'not promised, not delivered', '#f09614'],
  ['not_target', 'no requirement', '#c8c8c8'],
];
const ROUTE_COLOUR = '#7b3294';
const EDGE_COLOURS = { ok: '#0a9396', weak: '#d7191c' };
const $ = (id) => document.getElementById(id);
const match = window.location.pathname.match(/\/jobs\/([^/]+)\/viewer\/?$/);
const jobId = match ? decodeURIComponent(match[1]) : '';
const jobPath = `/jobs/${encodeURIComponent(jobId)}`;

// what tests and scripts can ask the page
const hook = {
  ready: false, status: 'loading', stations: () => [], selected: null, colouring: 'coverage',
  frames: 0,  // frames drawn so far: it stays put while nothing changes
  overlays: () => ({ legs: [], edges: [], stations: {} }), faceColours: () => ({}),
};
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
let outputs = new Set(); // names of the job's output files
let verification = null; // verification.json, when the plan was verified

async function loadResults() {
  try {
    // the results document: plan.json inline and every output file by name
    const results = await getJSON(`${jobPath}/results`);
    plan = results.plan;
    outputs = new Set(Object.keys(results).filter((name) => name !== 'plan'));
    showTotals(plan);
    showFieldTime(plan);
    showStationTable(plan.stations || []);
  } catch (err) {
    showProblem(err.problem, 'The plan document cannot be read');
  }
  if (outputs.has('verification.json')) {
    try {
      verification = await getJSON(`${jobPath}/results/verification.json`);
    } catch (err) {
      verification = null;
      $('delivered-note').textContent = `verification.json cannot be read: ${err.message}`;
    }
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
  const tol = doc.tolerance;
  if (tol) {
    const critical = tol.critical_stations || [];
    rows.push([`set up ${fmt(tol.placement_tolerance_m, 2)} m off`,
      `goal ${tol.goal_holds ? 'holds' : 'may break'} (≥ ${fmt(tol.worst_case_covered_area_m2, 1)} m²), ` +
      `network ${tol.network_holds ? 'holds' : 'may break'}` +
      (critical.length ? `; critical: ${critical.join(', ')}` : '')]);
  }
  const dl = el('dl');
  for (const [name, value] of rows) dl.append(el('dt', { text: name }), el('dd', { text: value }));
  $('totals').replaceChildren(el('h2', { text: 'Totals' }), dl);
  $('totals').hidden = false;
}

// 75 s -> "1 min 15 s", 4000 s -> "1 h 07 min"; null -> "unknown"
function duration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(Number(seconds))) {
    return 'unknown';
  }
  const s = Math.round(Number(seconds));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, '0')} s`;
  const m = Math.round(s / 60);
  return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, '0')} min`;
}

// why plan.json has no scan time (field_time.scan_s null)
function scanUnknownReason(doc) {
  const ft = doc.field_time || {};
  if (ft.scan_unknown_reason) return ft.scan_unknown_reason;
  if (!ft.scanner) {
    return 'no scanner was given (parameter scanner: a preset or an object with ' +
      'measurement_rate_pts_s), so the scan duration of a station is not known';
  }
  return `the scanner ${ft.scanner} gives no measurement rate or scan durations`;
}

function showFieldTime(doc) {
  const box = $('fieldtime');
  const ft = doc.field_time;
  if (!ft) { box.hidden = true; return; }
  const route = doc.route || {};
  const n = (doc.stations || []).length;
  const speed = (doc.parameters || {}).walking_speed_m_s;
  const scanKnown = ft.scan_s !== null && ft.scan_s !== undefined;
  const rows = [
    ['total', scanKnown ? duration(ft.total_s)
      : `unknown (setup and walk ${duration(Number(ft.setup_s) + Number(ft.walk_s))})`],
    ['setup', `${duration(ft.setup_s)} (${n} station${n === 1 ? '' : 's'})`],
    ['scan', scanKnown ? duration(ft.scan_s) : 'unknown'],
    ['walk', `${duration(ft.walk_s)} (${fmt(route.length_m, 1)} m` +
      `${speed ? ` at ${fmt(speed, 1)} m/s` : ''})`],
    ['scanner', ft.scanner || 'none chosen'],
  ];
  const dl = el('dl');
  for (const [name, value] of rows) {
    dl.append(el('dt', { text: name }), el('dd', { text: value, 'data-time': name }));
  }
  box.replaceChildren(el('h2', { text: 'Field time' }), dl);
  if (!scanKnown) {
    box.append(el('p', { class: 'muted', 'data-note': 'scan',
                         text: `scan time unknown: ${scanUnknownReason(doc)}` }));
  }
  const unreachable = Array.isArray(route.unreachable) ? route.unreachable : [];
  box.append(el('p', { 'data-note': 'unreachable', class: unreachable.length ? 'warn' : 'muted',
    text: unreachable.length
      ? `not reachable on foot, left off the route: station${unreachable.length === 1 ? '' : 's'} ` +
        `${unreachable.join(', ')}`
      : 'every station is on the walking route' }));
  const steps = Array.isArray(route.steps_between_parts) ? route.steps_between_parts : [];
  if (steps.length) {
    box.append(el('p', { 'data-note': 'parts', class: 'warn',
      text: `the model joins the stations in ${steps.length + 1} parts; walk on site from ` +
        steps.map((s) => `${s.from === null ? 'the start' : `station ${s.from}`} to station ${s.to}`)
          .join(', ') + ' (no stair or way in the model)' }));
  }
  box.hidden = false;
}

function showStationTable(stations) {
  const body = $('stations').querySelector('tbody');
  // with a scanner, plan.json gives each station's setting and scan time
  const scans = stations.some((s) => 'scan_s' in s);
  const head = $('stations').querySelector('thead tr');
  for (const th of head.querySelectorAll('th.scan')) th.remove();
  if (scans) {
    head.append(el('th', { text: 'setting', class: 'scan' }),
      el('th', { text: 'scan', class: 'scan' }));
  }
  body.replaceChildren(...stations.map((s) => {
    const p = s.position || [];
    const onRoute = s.visit !== null && s.visit !== undefined;
    const visit = el('td', { text: onRoute ? String(s.visit) : '–', class: 'visit' });
    if (!onRoute && 'visit' in s) visit.title = 'not reachable on foot';
    const tr = el('tr', { 'data-order': String(s.id), class: isCritical(s) ? 'critical' : '' },
      el('td', { text: String(s.id) }), visit, el('td', { text: fmt(p[0]) }),
      el('td', { text: fmt(p[1]) }), el('td', { text: fmt(p[2]) }),
      el('td', { text: fmt(s.new_area_m2, 1) }),
      el('td', { text: fmt(100 * Number(s.coverage_fraction), 1) }));
    if (scans) {
      tr.append(el('td', { text: s.setting ?? 'plan step', 'data-col': 'setting' }),
        el('td', { text: s.scan_s === null || s.scan_s === undefined ? 'unknown'
          : duration(s.scan_s), 'data-col': 'scan' }));
    }
    if (isCritical(s)) tr.title = 'critical: the goal breaks if this station is set up ' +
      `${fmt(s.tolerance.worst_offset_m[0], 2)}, ${fmt(s.tolerance.worst_offset_m[1], 2)} m off`;
    tr.addEventListener('click', () => selectStation(Number(s.id)));
    return tr;
  }));
  $('stations').hidden = stations.length === 0;
}

// the plan in the formats of BIM and CAD programs, each linked when the job wrote it
const BIM_FILES = {
  'plan.ifc': 'the input model with a survey annotation per station (IFC input only)',
  'plan.bcf': 'BCF 3.0 topics: a viewpoint per station, uncoverable elements',
  'plan.dxf': 'CAD drawing in metres, a layer set per storey',
  'plan.pdf': 'print set: A3 sheets per storey at 1:50, 1:100 or 1:200',
};

// the goal breaks when this station alone lands at its worst setup (plan.json tolerance)
function isCritical(station) {
  return Boolean(station && station.tolerance && station.tolerance.critical);
}

function criticalOrder(order) {
  return Boolean(plan && Array.isArray(plan.stations)
    && isCritical(plan.stations.find((s) => Number(s.id) === order)));
}

function showFiles() {
  const [p, bim] = [$('files').querySelector('p'), $('bim-files')];
  p.replaceChildren();
  bim.replaceChildren();
  const first = ['preview.png', 'curve.png', 'coverage.glb', 'plan.json', 'stations.csv',
    'faces.npz', 'verification.json'];
  const names = outputs.size ? [...first.filter((n) => outputs.has(n)),
    ...[...outputs].filter((n) => !first.includes(n) && !(n in BIM_FILES)).sort()]
    : first.slice(0, -1);
  const link = (name, title = '') => el('a', {
    href: `${basePath()}${jobPath}/results/${name}`, text: name, ...(title ? { title } : {}) });
  for (const name of names) p.append(link(name), ' ');
  const present = Object.keys(BIM_FILES).filter((n) => outputs.has(n));
  if (present.length) {
    bim.append('For BIM and CAD programs: ');
    for (const name of present) bim.append(link(name, BIM_FILES[name]), ' ');
    if (!outputs.has('plan.ifc') && plan && plan.scene && plan.scene.format !== 'ifc') {
      bim.append(el('span', { class: 'muted', text: '(no plan.ifc: the model was not IFC)' }));
    }
  }
  bim.hidden = present.length === 0;
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
const stations = new Map(); // order -> {node, label, extras, world}
const classNodes = new Map(); // face class -> {node, faces}
const routeLegs = []; // THREE.Line per leg of the walking route, in visit order
const overlapEdges = []; // THREE.Line per registration edge
const overlayGroups = { route: new THREE.Group(), registration: new THREE.Group() };
const cutPlane = new THREE.Plane(new THREE.Vector3(0, -1, 0), 1e9);

// a number in a disc (stations) or in a square (route legs), always drawn on top
function labelSprite(text, fill = '#143ca0', square = false) {
  const size = 128;
  const c = document.createElement('canvas');
  c.width = size;
  c.height = size;
  const g = c.getContext('2d');
  g.fillStyle = fill;
  g.beginPath();
  if (square) g.rect(8, 8, size - 16, size - 16);
  else g.arc(size / 2, size / 2, size / 2 - 6, 0, 2 * Math.PI);
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
  requestRender();
}

// Frames are drawn on demand, not in a loop: a still view costs no CPU or GPU (a site
// laptop's battery, a headless browser's software WebGL). Whatever changes the picture (the
// camera, a toggle, the cut, a colouring, a selection) asks for one frame.
let frameRequested = false;
function requestRender() {
  if (frameRequested || !renderer) return;
  frameRequested = true;
  requestAnimationFrame(() => {
    frameRequested = false;
    renderer.render(scene3d, camera);
    hook.frames += 1;
  });
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
  featureRows = await readFeatureRows(gltf);
  const root = gltf.scene;
  scene3d.add(root);
  const info = (gltf.scene.userData && gltf.scene.userData.scanplan) || {};
  classNodes.clear();
  const box = new THREE.Box3();
  // the root node "scanplan" holds the plan frame (Z up) and turns it into the model's own
  // frame; a model whose up is not +Z (up_axis) would lie on its side, so turn the plan's up
  // to the viewer's Y (labels, the cut and the camera assume Y up)
  const frame = root.getObjectByName('scanplan') || root;
  root.updateMatrixWorld(true);
  const up = new THREE.Vector3(0, 0, 1)
    .applyQuaternion(frame.getWorldQuaternion(new THREE.Quaternion()));
  const yUp = new THREE.Vector3(0, 1, 0);
  if (up.dot(yUp) < 1 - 1e-9) {
    root.quaternion.premultiply(new THREE.Quaternion().setFromUnitVectors(up, yUp));
  }
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
      const label = labelSprite(String(data.order), criticalOrder(data.order) ? '#c81e1e' : undefined);
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
  setupOverlays(frame, span);
  setupColouring();
  setupCut(box);
  new ResizeObserver(resize).observe(canvas.parentElement);
  resize();
  $('hint').hidden = false;
  setupPicking();
  controls.addEventListener('change', requestRender);
  // the page's inputs (class and overlay toggles, the cut slider, the colouring) change the
  // scene in their own handlers; this listener runs first and the frame after them
  for (const type of ['input', 'change']) document.addEventListener(type, requestRender, true);
  requestRender();
  hook.stations = () => stationScreenPositions();
  hook.overlays = overlayState;
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

// --- route and registration overlap edges -------------------------------------------------

// plan.json holds model coordinates; the glb's root node ("scanplan") holds the plan frame
// (the model levelled to Z-up, plan = R @ model, R in plan.scene.orientation.rotation) and
// turns it into the viewer's Y-up world, where the station markers are
function modelToWorld(frame) {
  const rows = plan && plan.scene && plan.scene.orientation && plan.scene.orientation.rotation;
  return (point) => {
    const [x, y, z] = (point || []).map(Number);
    const local = Array.isArray(rows)
      ? new THREE.Vector3(...rows.map((r) => r[0] * x + r[1] * y + r[2] * z))
      : new THREE.Vector3(x, y, z);
    return frame.localToWorld(local);
  };
}

function overlayLine(points, colour) {
  const material = new THREE.LineBasicMaterial({ color: colour, depthTest: false,
                                                 transparent: true, opacity: 0.95 });
  const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints(points), material);
  line.renderOrder = 5; // over the faces: a route behind a machine stays visible
  return line;
}

function setupOverlays(frame, span) {
  const box = $('overlay-toggles');
  box.replaceChildren();
  routeLegs.length = 0;
  overlapEdges.length = 0;
  const route = plan && plan.route;
  const registration = plan && plan.registration;
  if (!route && !registration) { $('overlays').hidden = true; return; }
  const toWorld = modelToWorld(frame);
  const position = new Map((plan.stations || []).map((s) => [Number(s.id), s.position]));
  for (const group of Object.values(overlayGroups)) {
    group.clear();
    scene3d.add(group);
  }
  const legs = (route && Array.isArray(route.legs)) ? route.legs : [];
  legs.forEach((leg, i) => {
    const path = Array.isArray(leg.path) && leg.path.length >= 2 ? leg.path
      : [position.get(Number(leg.from)), position.get(Number(leg.to))];
    const points = path.map(toWorld);
    const line = overlayLine(points, ROUTE_COLOUR);
    line.name = `route leg ${i + 1}`;
    line.userData = { leg: i + 1, from: leg.from, to: leg.to, length_m: leg.length_m };
    const label = labelSprite(String(i + 1), ROUTE_COLOUR, true);
    label.position.copy(points[Math.floor((points.length - 1) / 2)])
      .lerp(points[Math.ceil((points.length - 1) / 2)], 0.5);
    label.scale.setScalar(Math.max(0.2, span * 0.03));
    overlayGroups.route.add(line, label);
    routeLegs.push(line);
  });
  const edges = (registration && Array.isArray(registration.edges)) ? registration.edges : [];
  for (const edge of edges) {
    const a = position.get(Number(edge.a));
    const b = position.get(Number(edge.b));
    if (!a || !b) continue;
    const line = overlayLine([toWorld(a), toWorld(b)], edge.ok ? EDGE_COLOURS.ok
      : EDGE_COLOURS.weak);
    line.name = `overlap ${edge.a}-${edge.b}`;
    line.userData = { ...edge };
    overlayGroups.registration.add(line);
    overlapEdges.push(line);
  }
  const unreachable = route && Array.isArray(route.unreachable) ? route.unreachable.length : 0;
  const weak = edges.filter((e) => !e.ok).length;
  const toggles = [
    ['route', ROUTE_COLOUR, route ? `walking route: ${legs.length} leg${legs.length === 1 ? '' : 's'}, ` +
      `${fmt(route.length_m, 1)} m, leg k from visit k to k + 1` +
      (unreachable ? `; ${unreachable} station${unreachable === 1 ? '' : 's'} unreachable` : '')
      : null],
    ['registration', EDGE_COLOURS.ok, registration ? `registration overlaps: ${edges.length} ` +
      `edge${edges.length === 1 ? '' : 's'}${weak ? `, ${weak} too weak (red)` : ''}` +
      `${registration.connected === false ? '; not connected' : ''}` : null],
  ];
  for (const [name, colour, text] of toggles) {
    if (!text) continue;
    const input = el('input', { type: 'checkbox', 'data-overlay': name });
    input.checked = true;
    input.addEventListener('change', () => { overlayGroups[name].visible = input.checked; });
    box.append(el('label', {}, input, el('span', { class: 'swatch', style: `background:${colour}` }),
      text));
  }
  const body = $('edges').querySelector('tbody');
  body.replaceChildren(...edges.map((e) => el('tr', { class: e.ok ? '' : 'weak' },
    el('td', { text: `${e.a}–${e.b}` }), el('td', { text: fmt(e.overlap_m2, 1) }),
    el('td', { text: fmt(e.constraint, 3) }), el('td', { text: e.ok ? 'yes' : 'no' }))));
  $('edges').hidden = edges.length === 0;
  $('overlays').hidden = false;
}

function overlayState() {
  const ends = (line) => {
    const p = line.geometry.getAttribute('position');
    const at = (i) => line.localToWorld(new THREE.Vector3().fromBufferAttribute(p, i)).toArray();
    return { start: at(0), end: at(p.count - 1), points: p.count };
  };
  const shown = (line) => line.visible && line.parent !== null && line.parent.visible;
  return {
    legs: routeLegs.map((l) => ({ ...l.userData, ...ends(l), visible: shown(l) })),
    edges: overlapEdges.map((l) => ({ ...l.userData, ...ends(l), visible: shown(l) })),
    stations: Object.fromEntries([...stations].map(([o, { world }]) => [o, world.toArray()])),
  };
}

// --- colouring: plan coverage or delivered (verification) ---------------------------------

let deliveredArrays = null; // {covered, verified_delivered} from faces.npz
// the rows of faces.npz each feature of coverage.glb draws: {values, offsets} (feature f
// holds values[offsets[f]..offsets[f + 1]]), read from the property table's 'faces' column;
// null for a file without it, whose feature id is the row itself
let featureRows = null;

async function readFeatureRows(gltf) {
  const metadata = (gltf.parser.json.extensions || {}).EXT_structural_metadata;
  const table = metadata && metadata.propertyTables && metadata.propertyTables[0];
  const column = table && table.properties && table.properties.faces;
  if (!column || column.arrayOffsets === undefined) return null;
  // the loader's meshopt plugin decodes compressed views
  const [values, offsets] = await Promise.all([column.values, column.arrayOffsets].map(
    (index) => gltf.parser.getDependency('bufferView', index)));
  return { values: new Uint32Array(values, 0, values.byteLength / 4),
           offsets: new Uint32Array(offsets, 0, table.count + 1) };
}

// the rows of faces.npz feature f draws
function rowsOf(f) {
  if (!featureRows) return [f];
  return featureRows.values.subarray(featureRows.offsets[f], featureRows.offsets[f + 1]);
}

function linearBytes(css) {
  const c = new THREE.Color(css); // sRGB in, linear (three's working space) out
  return [c.r, c.g, c.b].map((v) => Math.round(v * 255));
}

// every class mesh: its feature ids (_FEATURE_ID_0, a triangle = 3 vertices; a feature's
// triangles one after the other) and its COLOR_0
function faceMeshes() {
  const out = [];
  for (const [name, { node }] of classNodes) {
    node.traverse((object) => {
      const g = object.isMesh ? object.geometry : null;
      if (g && g.getAttribute('color') && g.getAttribute('_feature_id_0')) {
        out.push({ name, mesh: object, ids: g.getAttribute('_feature_id_0'),
                   colour: g.getAttribute('color') });
      }
    });
  }
  return out;
}

// a feature's faces share the plan's class, so they are all promised or all not; where the
// simulated scan differs among them the feature shows the exception: promised but not
// delivered, or delivered but not promised
const KIND_RANK = [2, 0, 1, 3, 4]; // by index of DELIVERED: the lower rank is shown

function featureKind(kindOf, name, f) {
  let kind = -1;
  for (const row of rowsOf(f)) {
    const k = kindOf(name, row);
    if (kind < 0 || KIND_RANK[k] < KIND_RANK[kind]) kind = k;
  }
  return kind;
}

// colour every feature by kindOf(class, row) (null: the plan's colours); the faces of each
// kind, counted face by face (a feature whose faces differ is drawn in its featureKind)
function paint(kindOf) {
  const bytes = DELIVERED.map(([, , css]) => linearBytes(css));
  const counts = Object.fromEntries(DELIVERED.map(([kind]) => [kind, 0]));
  // a feature's triangles follow one another, on into the class's next primitive
  let last = -1;
  let k = 0;
  for (const { name, mesh, ids, colour } of faceMeshes()) {
    if (!mesh.userData.planColours) mesh.userData.planColours = colour.array.slice();
    if (!kindOf) {
      colour.array.set(mesh.userData.planColours);
    } else {
      for (let v = 0; v + 2 < ids.count; v += 3) {
        const f = Math.round(ids.getX(v));
        if (f !== last) {
          k = featureKind(kindOf, name, f);
          for (const row of rowsOf(f)) counts[DELIVERED[kindOf(name, row)][0]] += 1;
          last = f;
        }
        for (let j = v; j < v + 3; j += 1) {
          colour.setXYZW(j, bytes[k][0] / 255, bytes[k][1] / 255, bytes[k][2] / 255, 1);
        }
      }
    }
    colour.needsUpdate = true;
  }
  requestRender();
  return counts;
}

function deliveredKind(className, face) {
  if (className === 'not_target') return 4;
  const promised = deliveredArrays.covered[face] !== 0;
  const delivered = deliveredArrays.verified_delivered[face] !== 0;
  if (promised) return delivered ? 0 : 1;
  return delivered ? 2 : 3;
}

// faces per delivered kind, read back from the colours the meshes now hold (a feature's
// faces counted once, in the colour it is drawn in)
function faceColours() {
  const bytes = DELIVERED.map(([, , css]) => linearBytes(css).join(','));
  const counts = { other: 0 };
  for (const [kind] of DELIVERED) counts[kind] = 0;
  let last = -1; // a feature's triangles follow one another, across primitives too
  for (const { colour, ids } of faceMeshes()) {
    for (let v = 0; v + 2 < ids.count; v += 3) {
      const f = Math.round(ids.getX(v));
      if (f === last) continue;
      last = f;
      const rgb = [colour.getX(v), colour.getY(v), colour.getZ(v)]
        .map((x) => Math.round(x * 255)).join(',');
      const k = bytes.indexOf(rgb);
      counts[k >= 0 ? DELIVERED[k][0] : 'other'] += rowsOf(f).length;
    }
  }
  return counts;
}

function setupColouring() {
  const radios = document.querySelectorAll('#colouring input[name="colouring"]');
  const deliveredRadio = document.querySelector('#colouring input[value="delivered"]');
  const note = $('delivered-note');
  const available = verification !== null && outputs.has('faces.npz');
  deliveredRadio.disabled = !available;
  deliveredRadio.parentElement.hidden = !available;
  if (!available) {
    if (!note.textContent) {
      note.textContent = 'No verification for this plan: plan with the parameter verify ' +
        '(or run scanplan verify PLAN_DIR --scene MODEL) to colour the faces by what a ' +
        'simulated scan delivers.';
    }
  } else {
    const t = verification.totals || {};
    note.textContent = `simulated scan: promised ${fmt(t.promised_area_m2, 1)} m², delivered ` +
      `${fmt(t.delivered_area_m2, 1)} m², promised but not delivered ` +
      `${fmt(t.promised_not_delivered_area_m2, 2)} m² (${t.promised_not_delivered_faces} faces), ` +
      `delivered but not promised ${fmt(t.delivered_not_promised_area_m2, 2)} m² ` +
      `(${t.delivered_not_promised_faces} faces), holes ${fmt(t.hole_area_m2, 2)} m²`;
  }
  for (const radio of radios) {
    radio.addEventListener('change', () => { if (radio.checked) setColouring(radio.value); });
  }
  hook.faceColours = faceColours;
}

async function setColouring(mode) {
  const legend = $('delivered-legend');
  if (mode !== 'delivered') {
    paint(null);
    legend.hidden = true;
    hook.colouring = 'coverage';
    return;
  }
  hook.colouring = 'loading';
  try {
    if (!deliveredArrays) {
      legend.replaceChildren(el('p', { class: 'muted', text: 'reading faces.npz…' }));
      legend.hidden = false;
      const buffer = await (await fetchOk(`${jobPath}/results/faces.npz`)).arrayBuffer();
      const arrays = await readNpz(buffer, ['covered', 'verified_delivered']);
      if (!arrays.covered || !arrays.verified_delivered) {
        throw new Error('faces.npz has no verified_delivered array');
      }
      deliveredArrays = arrays;
    }
  } catch (err) {
    legend.replaceChildren(el('p', { class: 'warn',
                                     text: `The delivered colouring failed: ${err.message}` }));
    legend.hidden = false;
    hook.colouring = 'failed';
    return;
  }
  const counts = paint(deliveredKind);
  legend.replaceChildren(el('h3', { text: 'Delivered by the simulated scan' }),
    ...DELIVERED.map(([kind, label, css]) => el('p', { 'data-kind': kind },
      el('span', { class: 'swatch', style: `background:${css}` }),
      `${label}: `, el('span', { class: 'count', text: String(counts[kind]) }), ' faces')));
  legend.hidden = false;
  hook.colouring = 'delivered';
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
    el('p', { text: visitText(data) }),
    el('p', { text: `position x ${fmt(p[0])} m, y ${fmt(p[1])} m, z ${fmt(p[2])} m` }),
    el('p', { text: `new area ${fmt(data.new_area_m2)} m²` }),
    ...(data.scanner_height_m !== undefined
      ? [el('p', { text: `instrument height ${fmt(data.scanner_height_m, 2)} m` })] : []),
    ...(data.tolerance ? [el('p', {
      class: data.tolerance.critical ? 'critical' : '',
      text: `set up off by up to ${fmt(plan.tolerance.placement_tolerance_m, 2)} m: loses at most ` +
            `${fmt(data.tolerance.worst_loss_m2, 2)} m² (worst offset ` +
            `${fmt(data.tolerance.worst_offset_m[0], 2)}, ${fmt(data.tolerance.worst_offset_m[1], 2)} m)` +
            (data.tolerance.critical ? '; critical: the goal breaks' : '') })] : []),
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
  requestRender();
}

function visitText(station) {
  if (!plan || !plan.route) return 'no walking route in this plan';
  const total = Array.isArray(plan.route.visits) ? plan.route.visits.length : 0;
  if (station.visit === null || station.visit === undefined) {
    return 'not reachable on foot: not on the walking route';
  }
  return `visit ${station.visit} of ${total} on the walking route`;
}

if (jobId) {
  poll();
} else {
  setStatus('unknown', '');
  showProblem({ title: 'No job in the address', detail: window.location.pathname });
}

export { problemText };
