// Shared by the pages: where the API is, the API key, problem documents (RFC 9457).

// Everything before "/jobs/..." (viewer) or the page itself (job list): works behind a prefix.
export function basePath() {
  const path = window.location.pathname;
  const at = path.lastIndexOf('/jobs/');
  if (at >= 0) return path.slice(0, at);
  return path.replace(/\/(index\.html)?$/, '');
}

const KEY = 'scanplan.apiKey';

export function apiKey() {
  try { return window.sessionStorage.getItem(KEY) || ''; } catch { return ''; }
}

export function setApiKey(value) {
  try { window.sessionStorage.setItem(KEY, value); } catch { /* private mode */ }
}

export function authHeaders() {
  const key = apiKey();
  return key ? { Authorization: `Bearer ${key}` } : {};
}

// An error that carries a problem document (or one made up from the HTTP status).
export class ProblemError extends Error {
  constructor(problem) {
    super(problemText(problem));
    this.problem = problem;
    this.status = Number(problem && problem.status) || 0;
  }
}

export function problemText(problem) {
  if (!problem || typeof problem !== 'object') return String(problem || 'unknown error');
  const parts = [];
  if (problem.title) parts.push(String(problem.title));
  if (problem.detail) parts.push(String(problem.detail));
  if (problem.parameter) parts.push(`(parameter: ${problem.parameter})`);
  if (!parts.length && problem.status) parts.push(`HTTP ${problem.status}`);
  return parts.join(': ') || 'unknown error';
}

export async function problemOf(response) {
  let body = null;
  try { body = await response.json(); } catch { body = null; }
  if (body && typeof body === 'object' && (body.title || body.detail)) {
    return { status: response.status, ...body };
  }
  return { status: response.status, title: response.statusText || `HTTP ${response.status}`,
           detail: `${response.url} answered ${response.status}` };
}

export async function fetchOk(path) {
  let response;
  try {
    response = await fetch(basePath() + path, { headers: authHeaders(), cache: 'no-store' });
  } catch (err) {
    throw new ProblemError({ title: 'The service cannot be reached',
                             detail: `${path}: ${err && err.message ? err.message : err}` });
  }
  if (!response.ok) throw new ProblemError(await problemOf(response));
  return response;
}

export async function getJSON(path) {
  return (await fetchOk(path)).json();
}

// Ask for an API key after a 401; resolves when the user has entered one.
export function askForKey(container) {
  return new Promise((resolve) => {
    container.replaceChildren();
    const form = document.createElement('form');
    form.className = 'keyform';
    form.innerHTML = '<label>This service needs an API key: <input type="password" ' +
      'autocomplete="off" name="key"></label> <button type="submit">Use key</button>';
    form.addEventListener('submit', (event) => {
      event.preventDefault();
      setApiKey(form.elements.key.value.trim());
      container.replaceChildren();
      resolve();
    });
    container.append(form);
  });
}

export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) {
    if (name === 'class') node.className = value;
    else if (name === 'text') node.textContent = value;
    else node.setAttribute(name, value);
  }
  for (const child of children) node.append(child);
  return node;
}

export function fmt(value, digits = 2) {
  const n = Number(value);
  return Number.isFinite(n) ? n.toFixed(digits) : '–';
}
