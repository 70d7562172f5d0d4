// The job list: polls GET /jobs and shows each job with a link to its viewer.
import { ProblemError, askForKey, el, getJSON, problemText } from './api.js';

const state = document.getElementById('state');
const table = document.getElementById('jobs');
const body = table.querySelector('tbody');
const keyBox = document.getElementById('key');

function row(job) {
  const id = String(job.jobID || job.id || '');
  const status = String(job.status || 'unknown');
  const progress = Math.max(0, Math.min(100, Number(job.progress) || 0));
  const viewer = el('a', { href: `jobs/${encodeURIComponent(id)}/viewer`, text: id });
  const bar = el('div', { class: 'bar' }, el('div', { style: `width:${progress}%` }));
  const message = status === 'failed' && job.problem ? problemText(job.problem)
    : String(job.message || '');
  const results = el('td');
  if (status === 'successful') {
    for (const name of ['preview.png', 'plan.json', 'coverage.glb']) {
      results.append(el('a', { href: `jobs/${encodeURIComponent(id)}/results/${name}`,
                               text: name }), ' ');
    }
  }
  return el('tr', { class: `status-${status}` },
    el('td', {}, viewer), el('td', {}, el('span', { class: 'badge', text: status })),
    el('td', {}, bar, el('span', { class: 'muted', text: ` ${progress} %` })),
    el('td', { text: message }), el('td', { text: String(job.created || '') }), results);
}

async function poll() {
  try {
    const data = await getJSON('/jobs?limit=100');
    const jobs = Array.isArray(data) ? data : (Array.isArray(data.jobs) ? data.jobs : []);
    body.replaceChildren(...jobs.map(row));
    table.hidden = jobs.length === 0;
    state.textContent = jobs.length ? `${jobs.length} job(s), updated ${new Date().toLocaleTimeString()}`
      : 'No jobs yet.';
  } catch (err) {
    if (err instanceof ProblemError && err.status === 401) {
      state.textContent = 'The service needs an API key.';
      await askForKey(keyBox);
    } else {
      state.textContent = `Cannot list the jobs: ${err.message}`;
    }
  }
  window.setTimeout(poll, 2000);
}

poll();
