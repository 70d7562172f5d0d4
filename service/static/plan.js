// The form to plan: upload a model (drag and drop or the file picker), set the main
// parameters in fields generated from GET /processes/scan-plan, start the plan and watch it.
// The same API as any client: POST /meshes, POST /processes/scan-plan/execution, GET /jobs/{id}.
import { ProblemError, authHeaders, basePath, el, getJSON, problemOf, problemText }
  from './api.js';

// the parameters a surveyor sets most often; the others keep the process's defaults
const MAIN = ['method', 'coverage_goal', 'min_density_pts_m2', 'dof_min_m', 'dof_max_m',
  'min_incidence_deg', 'grid_spacing_m', 'scanner_height_m', 'max_edge_m', 'unit_scale'];

const form = document.getElementById('plan-form');
const drop = document.getElementById('drop');
const fileInput = document.getElementById('file');
const dropText = document.getElementById('drop-text');
const fieldset = document.getElementById('parameters');
const start = document.getElementById('start');
const planState = document.getElementById('plan-state');
let chosen = null;
let schema = {};

async function send(path, options) {
  let response;
  try {
    response = await fetch(basePath() + path,
      { ...options, headers: { ...authHeaders(), ...(options.headers || {}) } });
  } catch (err) {
    throw new ProblemError({ title: 'The service cannot be reached', detail: String(err) });
  }
  if (!response.ok) throw new ProblemError(await problemOf(response));
  return response.json();
}

// the number part of a property (nullable numbers are anyOf [number, null])
function numberSchema(property) {
  const options = property.anyOf || [property];
  return options.find((s) => s.type === 'number' || s.type === 'integer') || null;
}

function field(name, property) {
  const label = el('label', { title: property.description || '' },
    el('span', { text: `${name}${property.description ? ` — ${property.description}` : ''}` }));
  let input;
  if (Array.isArray(property.enum)) {
    input = el('select', { name });
    for (const value of property.enum) input.append(el('option', { value, text: value }));
    input.value = property.default;
  } else {
    const number = numberSchema(property) || {};
    input = el('input', { name, type: 'number', step: 'any' });
    for (const [key, attribute] of [['minimum', 'min'], ['maximum', 'max']]) {
      if (number[key] !== undefined) input.setAttribute(attribute, number[key]);
    }
    if (property.default !== null && property.default !== undefined) {
      input.value = property.default;
    }
    input.placeholder = property.default === null ? 'empty: none' : String(property.default);
    if ((property.anyOf || []).some((s) => s.type === 'null')) input.dataset.nullable = '1';
  }
  label.append(input);
  return label;
}

async function describe() {
  try {
    const process = await getJSON('/processes/scan-plan');
    const parameters = process.inputs.parameters.schema;
    schema = parameters.properties || {};
    fieldset.replaceChildren(el('legend', { text: 'Parameters' }));
    for (const name of MAIN) if (schema[name]) fieldset.append(field(name, schema[name]));
    start.disabled = chosen === null;
  } catch (err) {
    fieldset.replaceChildren(el('p', { class: 'problem', text: err.message }));
  }
}

// only what differs from the defaults is sent, so the plan is the CLI's with the same file
function changedParameters() {
  const changed = {};
  for (const input of fieldset.querySelectorAll('input, select')) {
    const property = schema[input.name];
    let value = input.value;
    if (input.tagName === 'INPUT') {
      if (value === '') value = input.dataset.nullable ? null : property.default;
      else value = Number(value);
    }
    if (value !== property.default) changed[input.name] = value;
  }
  return changed;
}

function choose(file) {
  chosen = file || null;
  dropText.textContent = chosen ? `${chosen.name} (${(chosen.size / 1e6).toFixed(2)} MB)`
    : 'Drop a model here or click to choose one';
  start.disabled = chosen === null || !Object.keys(schema).length;
}

function showProblem(err) {
  const problem = err.problem || { title: 'Error', detail: err.message };
  planState.replaceChildren(el('div', { class: 'problem', text: problemText(problem) }));
}

async function watch(jobId) {
  const bar = el('div', { class: 'bar' }, el('div', { style: 'width:0%' }));
  const text = el('span', { class: 'muted' });
  const viewer = el('a', { href: `jobs/${encodeURIComponent(jobId)}/viewer`,
    text: 'open the viewer' });
  planState.replaceChildren(el('p', {}, `Job ${jobId}: `, text), bar, el('p', {}, viewer));
  for (;;) {
    const status = await getJSON(`/jobs/${encodeURIComponent(jobId)}`);
    bar.firstChild.style.width = `${status.progress}%`;
    text.textContent = `${status.status}, ${status.progress} % — ${status.message}`;
    planState.dataset.status = status.status;
    if (['successful', 'failed', 'dismissed'].includes(status.status)) {
      if (status.status === 'failed' && status.problem) {
        planState.append(el('div', { class: 'problem', text: problemText(status.problem) }));
      }
      return;
    }
    await new Promise((resolve) => { window.setTimeout(resolve, 700); });
  }
}

form.addEventListener('submit', async (event) => {
  event.preventDefault();
  if (!chosen) return;
  start.disabled = true;
  try {
    planState.replaceChildren(el('p', { text: `Uploading ${chosen.name}…` }));
    const mesh = await send(`/meshes?filename=${encodeURIComponent(chosen.name)}`, {
      method: 'POST', body: chosen, headers: { 'Content-Type': 'application/octet-stream' } });
    const job = await send('/processes/scan-plan/execution', {
      method: 'POST', headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ inputs: { mesh: mesh.id, parameters: changedParameters() } }) });
    await watch(job.jobID);
  } catch (err) {
    showProblem(err);
  } finally {
    start.disabled = chosen === null;
  }
});

fileInput.addEventListener('change', () => choose(fileInput.files[0]));
for (const name of ['dragenter', 'dragover']) {
  drop.addEventListener(name, (event) => { event.preventDefault(); drop.classList.add('over'); });
}
for (const name of ['dragleave', 'drop']) {
  drop.addEventListener(name, () => drop.classList.remove('over'));
}
drop.addEventListener('drop', (event) => {
  event.preventDefault();
  if (event.dataTransfer && event.dataTransfer.files.length) choose(event.dataTransfer.files[0]);
});

describe();
